"""Paper Fig. 6: the driven paths on the track (``draw_trajectories``).

A panel per method (and one for the minimum-time line) shows its timed laps coloured by
speed, the start line, the driving direction and its off-track events (red crosses, counted
in the panel's title). The grid has no empty cell: the cells after the methods' panels
(``grid_shape``: at least one, two on a long track) zoom where the paths lie furthest
apart, else on the sharpest turns (``zoom_windows``), with every path overlaid in its
method's colour and dash, so paths a few centimetres apart on a 400 m track can be told
apart; the zoomed windows are framed and lettered in every method's panel.
"""

from __future__ import annotations

import math
import string
from collections.abc import Sequence

import numpy as np

from shared.curvature import smooth, window_points
from shared.evaluation.plotting import (
    LIMIT_STYLE,
    OFF_TRACK_STYLE,
    ReferenceLine,
    gap_for,
    legend_row,
    method_style,
    new_figure,
    plural,
)
from shared.evaluation.results import MethodRun
from shared.track import Track

#: A track whose drawing spans more than this [m] is long: two zooms at least.
LONG_TRACK_SPAN_M = 40.0


def grid_shape(n_panels: int, min_zooms: int = 1) -> tuple[int, int, int]:
    """(rows, columns, zooms) of Fig. 6's grid: `n_panels` panels and zoom panels filling
    every other cell, at least `min_zooms`; one row up to four cells, else three or four
    columns, whichever needs fewer extra zooms (three on a tie).

    >>> grid_shape(5, 1)
    (2, 3, 1)
    """
    total = max(1, n_panels + max(0, min_zooms))
    if total <= 4:
        return 1, total, total - n_panels
    best = min((math.ceil(total / c) * c - total, c) for c in (3, 4))
    cols = best[1]
    rows = math.ceil(total / cols)
    return rows, cols, rows * cols - n_panels


def zoom_windows(
    track: Track,
    count: int,
    half_m: float,
    offsets: Sequence[tuple[np.ndarray, np.ndarray]] = (),
) -> list[tuple[float, float, float]]:
    """The `count` places of `track` worth a zoom that are apart: (s [m], x [m], y [m]) of
    each window's centre on the centreline, best first.

    With two paths or more (`offsets`: each path's (s [m], lateral offset [m]) samples),
    the best places are where the paths lie furthest apart across the track (the spread
    of their mean offsets in bins of `half_m` along s), so a zoom shows what tells them
    apart; else (or where they never part) the sharpest turns (|curvature| smoothed over
    about 1 m). A place closer than 4 `half_m` along the track, or 2 `half_m` in the
    plane, to one already chosen is left out (one window per turn).
    """
    if count <= 0:
        return []
    k = np.abs(track.signed_curvature())
    k = smooth(k, min(window_points(1.0, track.spacing_m), 2 * (len(k) // 2) - 1))
    s = np.asarray(track.s_m, dtype=float)
    L = track.length_m
    score = k / max(float(k.max()), 1e-12)  # in [0, 1]
    spread = path_spread(offsets, L, half_m)
    if spread is not None:
        n_bins = spread.size
        at = np.minimum((s / L * n_bins).astype(int), n_bins - 1)
        score = spread[at] + 1e-3 * score  # the turn breaks ties (paths that never part)
    chosen: list[tuple[float, float, float]] = []
    for i in np.argsort(-score, kind="stable"):
        x, y = (float(v) for v in track.xy[i])
        along = [min(abs(s[i] - c[0]), L - abs(s[i] - c[0])) for c in chosen]
        plane = [math.hypot(x - c[1], y - c[2]) for c in chosen]
        if all(a > 4 * half_m for a in along) and all(p > 2 * half_m for p in plane):
            chosen.append((float(s[i]), x, y))
            if len(chosen) == count:
                break
    return chosen


def path_spread(
    offsets: Sequence[tuple[np.ndarray, np.ndarray]], length_m: float, bin_m: float
) -> np.ndarray | None:
    """(bins,) how far apart the paths lie across the track in each bin of about `bin_m`
    along s [m]: the largest minus the smallest of the paths' mean lateral offsets there
    (0 where fewer than two paths have samples), or None with fewer than two paths.

    Args:
        offsets: each path's (s [m] in [0, length_m), lateral offset [m]) samples.
    """
    paths = [(np.asarray(sv, float), np.asarray(ev, float)) for sv, ev in offsets]
    paths = [(sv[ok], ev[ok]) for sv, ev in paths
             if (ok := np.isfinite(sv) & np.isfinite(ev)).any()]
    if len(paths) < 2:
        return None
    n_bins = max(1, round(length_m / max(bin_m, 1e-6)))
    means = np.full((len(paths), n_bins), np.nan)
    for j, (sv, ev) in enumerate(paths):
        b = np.clip((np.mod(sv, length_m) / length_m * n_bins).astype(int), 0, n_bins - 1)
        total = np.bincount(b, ev, n_bins)
        count = np.bincount(b, minlength=n_bins)
        means[j] = np.where(count > 0, total / np.maximum(count, 1), np.nan)
    ok = np.isfinite(means)
    hi = np.max(np.where(ok, means, -np.inf), axis=0)
    lo = np.min(np.where(ok, means, np.inf), axis=0)
    return np.where(ok.sum(axis=0) >= 2, hi - lo, 0.0)


def _path_segments(x: np.ndarray, y: np.ndarray, gap_m: float) -> tuple[np.ndarray, np.ndarray]:
    """((M, 2, 2) segments between consecutive points, (N-1,) mask of the kept ones),
    leaving out jumps over `gap_m` [m] and non-finite points."""
    p = np.stack([x, y], axis=1)
    seg = np.stack([p[:-1], p[1:]], axis=1)
    ok = np.isfinite(seg).all(axis=(1, 2)) & (np.linalg.norm(p[1:] - p[:-1], axis=1) <= gap_m)
    return seg[ok], ok


def _broken_path(x: np.ndarray, y: np.ndarray, gap_m: float) -> tuple[np.ndarray, np.ndarray]:
    """(x, y) with a NaN at every jump over `gap_m` [m]: one polyline whose dashes run on."""
    x, y = np.asarray(x, float), np.asarray(y, float)
    if x.size < 2:
        return x, y
    cut = np.flatnonzero(np.hypot(np.diff(x), np.diff(y)) > gap_m) + 1
    return np.insert(x, cut, np.nan), np.insert(y, cut, np.nan)


def _crop(x: np.ndarray, y: np.ndarray, cx: float, cy: float, hx: float, hy: float
          ) -> tuple[np.ndarray, np.ndarray]:
    """The points of a path within the box (cx +- hx, cy +- hy) [m] and their neighbours
    (a line leaves the box at its edge), a NaN where a part was left out."""
    x, y = np.asarray(x, float), np.asarray(y, float)
    inside = (np.abs(x - cx) <= hx) & (np.abs(y - cy) <= hy)
    keep = inside.copy()
    keep[:-1] |= inside[1:]
    keep[1:] |= inside[:-1]
    idx = np.flatnonzero(keep)
    cut = np.flatnonzero(np.diff(idx) > 1) + 1  # a part left out: a NaN, no straight join
    return np.insert(x[idx], cut, np.nan), np.insert(y[idx], cut, np.nan)


def _inside(c: float, lo: float, hi: float, half: float) -> float:
    """`c` moved so that [c - half, c + half] lies in [lo, hi] (centred if it cannot)."""
    if hi - lo <= 2 * half:
        return 0.5 * (lo + hi)
    return float(np.clip(c, lo + half, hi - half))


def _draw_track(ax, track: Track, arrow_m: float) -> None:
    """The track as a light band with thin edges, the start line and direction arrows."""
    left = np.vstack([track.left_boundary, track.left_boundary[:1]])
    right = np.vstack([track.right_boundary, track.right_boundary[:1]])
    band = np.vstack([left, right[::-1]])
    ax.fill(band[:, 0], band[:, 1], color="0.9", lw=0, zorder=0)
    for b in (left, right):
        ax.plot(b[:, 0], b[:, 1], color="0.6", lw=0.4, zorder=1)
    xy = track.xy
    L = track.length_m
    ax.plot([track.left_boundary[0, 0], track.right_boundary[0, 0]],
            [track.left_boundary[0, 1], track.right_boundary[0, 1]], color="k", lw=2.0,
            zorder=4)
    ax.plot(*xy[0], marker="o", ms=5, color="k", zorder=5)
    ax.annotate("start", xy[0], xytext=(6, 6), textcoords="offset points", fontsize=8,
                zorder=5, annotation_clip=True)
    s = np.asarray(track.s_m, dtype=float)
    for frac in (0.0, 0.25, 0.5, 0.75):  # driving direction
        k = min(int(np.searchsorted(s, frac * L + 0.02 * L)), len(xy) - 2)
        d = xy[k + 1] - xy[k]
        d = d / max(float(np.linalg.norm(d)), 1e-9) * arrow_m
        ax.annotate("", xy=xy[k] + d, xytext=xy[k], zorder=5, annotation_clip=True,
                    arrowprops={"arrowstyle": "-|>", "color": "k", "lw": 1.4,
                                "mutation_scale": 14})


def _off_track(ax, run: MethodRun) -> int:
    """Mark `run`'s off-track events (where the car was when its footprint left the
    track); returns how many."""
    xy = np.asarray(run.off_track_xy, dtype=float).reshape(-1, 2)
    if len(xy):
        ax.scatter(xy[:, 0], xy[:, 1], **OFF_TRACK_STYLE)
    return len(xy)


def draw_trajectories(
    track: Track,
    runs: list[MethodRun],
    reference: ReferenceLine | None = None,
    title: str = "",
):
    """Paper Fig. 6: driven paths (timed laps) coloured by speed, one panel per method (and
    one for the minimum-time line), start line, driving direction and off-track events
    marked; the remaining cells zoom where the paths part, with every path; the figure."""
    from matplotlib.collections import LineCollection
    from matplotlib.lines import Line2D
    from matplotlib.patches import Rectangle

    paths: list[tuple[str, np.ndarray, np.ndarray, np.ndarray]] = []
    for run in runs:
        tr = run.trace.arrays()
        timed = tr["lap"] >= 1 if len(tr["lap"]) else np.zeros(0, bool)
        paths.append((run.name, tr["x_m"][timed], tr["y_m"][timed], tr["speed_mps"][timed]))
    if reference is not None:
        paths.append((reference.name, np.asarray(reference.x_m), np.asarray(reference.y_m),
                      np.asarray(reference.v_mps)))
    lo, hi = track.xy.min(axis=0), track.xy.max(axis=0)
    w_max = float(max(np.max(track.w_left_m), np.max(track.w_right_m)))
    lo, hi = lo - w_max - 0.2, hi + w_max + 0.2
    aspect = float((hi[1] - lo[1]) / max(hi[0] - lo[0], 1e-9))
    span = float(np.ptp(track.xy, axis=0).max())
    long_track = span > LONG_TRACK_SPAN_M
    rows, cols, n_zoom = grid_shape(len(paths), 2 if long_track else 1)
    panel_w = 4.8 if cols <= 3 else 4.0
    fig, body = new_figure((panel_w * cols + 1.0, panel_w * min(aspect, 1.6) * rows + 1.3))
    axes = body.subplots(rows, cols, squeeze=False)
    width = float(np.max(track.w_left_m + track.w_right_m))
    half_x = float(np.clip(1.5 * width, 1.5, 0.25 * span))  # a zoom's half width [m]
    half_y = half_x * min(aspect, 1.6)
    offsets = []  # each path's (s, lateral offset): where the paths part
    for run in runs:
        tr = run.trace.arrays()
        if len(tr["e_con_m"]) == len(tr["s_m"]) == len(tr["lap"]):
            offsets.append((tr["s_m"][tr["lap"] >= 1], tr["e_con_m"][tr["lap"] >= 1]))
    if reference is not None and len(offsets) == len(runs) and len(reference.x_m):
        offsets.append(track.project(np.stack([reference.x_m, reference.y_m], axis=1)))
    windows = zoom_windows(track, n_zoom, max(half_x, half_y), offsets)
    while len(windows) < n_zoom:  # a track with fewer separate turns: the wider view
        windows.append(windows[-1] if windows else (0.0, *map(float, track.xy[0])))
    # each window inside the drawing (a turn at the edge: the window moves inwards)
    windows = [(s_c, _inside(cx, lo[0], hi[0], half_x), _inside(cy, lo[1], hi[1], half_y))
               for s_c, cx, cy in windows]
    letters = string.ascii_uppercase
    speeds = np.concatenate([v[np.isfinite(v)] for *_, v in paths] or [np.ones(1)])
    speeds = speeds if speeds.size else np.ones(1)
    vmax = float(speeds.max())
    vmin = max(0.0, np.floor(2.0 * float(np.percentile(speeds, 1))) / 2.0)
    vmin = min(vmin, max(vmax - 0.5, 0.0))  # a range of at least 0.5 m/s
    lw = float(np.clip(150.0 / max(span, 1.0), 1.2, 3.0))  # thinner on a long track
    gap = gap_for(span)
    coloured = None
    flat = list(axes.flat)
    for k, (name, x, y, v) in enumerate(paths):
        ax = flat[k]
        _draw_track(ax, track, 0.07 * span)
        seg, keep = _path_segments(np.asarray(x, float), np.asarray(y, float), gap)
        if len(seg):
            vv = np.asarray(v, float)
            coll = LineCollection(seg, cmap="turbo", linewidths=lw, zorder=3)
            coll.set_array((0.5 * (vv[:-1] + vv[1:]))[keep])
            coll.set_clim(vmin, vmax)
            ax.add_collection(coll)
            coloured = coll
        label = (f"{name}: {reference.lap_time_s:.2f} s" if k >= len(runs) and reference
                 else f"{name}: {plural(runs[k].completed_laps, 'lap')}")
        if k < len(runs) and (off := _off_track(ax, runs[k])):
            label += f", {off} off track (x)"
        for j, (_, cx, cy) in enumerate(windows):
            ax.add_patch(Rectangle((cx - half_x, cy - half_y), 2 * half_x, 2 * half_y,
                                   fill=False, ec="k", lw=0.8, ls="--", zorder=6))
            ax.annotate(letters[j], (cx - half_x, cy + half_y), xytext=(2, -2),
                        textcoords="offset points", ha="left", va="top", fontsize=8,
                        fontweight="bold", zorder=6)
        ax.set_title(label, fontsize=10)
        ax.set_aspect("equal")
        ax.set_xlim(lo[0], hi[0])
        ax.set_ylim(lo[1], hi[1])
        ax.set_xlabel("x [m]")
        ax.set_ylabel("y [m]")
    handles, labels = [], []
    for j, (s_c, cx, cy) in enumerate(windows):
        ax = flat[len(paths) + j]
        _draw_track(ax, track, 0.25 * half_x)
        for i, (name, x, y, _) in enumerate(paths):
            bx, by = _broken_path(*_crop(x, y, cx, cy, 1.2 * half_x, 1.2 * half_y), gap)
            if i >= len(runs):
                (h,) = ax.plot(bx, by, zorder=2, **LIMIT_STYLE)
            else:
                st = method_style(i)
                (h,) = ax.plot(bx, by, color=st["color"], ls=st["ls"], lw=1.6, zorder=3 + i)
                _off_track(ax, runs[i])
            if j == 0:
                handles.append(h)
                labels.append(name)
        ax.set_aspect("equal")
        ax.set_xlim(cx - half_x, cx + half_x)
        ax.set_ylim(cy - half_y, cy + half_y)
        ax.set_title(f"zoom {letters[j]} (s = {s_c:.0f} m): every path", fontsize=10)
        ax.set_xlabel("x [m]")
        ax.set_ylabel("y [m]")
    if any(len(r.off_track_xy) for r in runs):
        handles.append(Line2D([], [], ls="none", marker=OFF_TRACK_STYLE["marker"],
                              color=OFF_TRACK_STYLE["color"], mec="k", ms=8))
        labels.append("off track (where the footprint left the track)")
    legend_row(body, handles, labels, max_cols=6)
    if coloured is not None:
        body.colorbar(coloured, ax=flat, label="speed [m/s] (path panels)",
                     shrink=0.8 if aspect * rows <= 1.2 else 0.55, pad=0.02)
    fig.suptitle(title or f"Driven paths on {track.name}, coloured by speed; zooms: every "
                 "path in its method's colour")
    return fig
