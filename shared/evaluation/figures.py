"""The paper's figures from a bench run or a recording, as PNG files (matplotlib, no display).

- ``fig4_curvature.png``: raw curvature, smoothed curvature and NSC along s (paper Fig. 4).
- ``fig5_speed_vs_s.png``: speed along s of each method over the NSC as background (Fig. 5a).
- ``fig6_trajectories.png``: driven paths on the track coloured by speed, a panel per method
  (Fig. 6), with the start line and the driving direction.
- ``fig7_laps.png``: lap time and mean speed of every lap (Fig. 7).
- ``fig8_solve_time.png``: compute time per tick: histogram, cumulative share, p95 (Fig. 8).

Every figure has a title. The minimum-time line (``ReferenceLine``, passed in as data: this
package imports no service) is drawn beside the methods: its speed along s in Fig. 5, its
own panel in Fig. 6 and its lap time in Fig. 7.

The data-level choices are plain functions, tested without pixels: ``break_gaps`` (a gap
in s is a gap in the line, not a straight segment), ``compute_time_axis_ms`` (Fig. 8's axis
is set by the p99 of the samples, not by one outlier), ``no_solver`` (the raceline's tracker
has a compute time, not a solve time: it runs no optimiser per tick).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from shared.config.methods import METHODS
from shared.curvature import CurvatureProfile
from shared.evaluation.results import MethodRun
from shared.track import Track

#: Resolution of the PNG files [dots per inch].
DPI = 110
#: Fig. 8's axis ends at this many times the largest per-method p99 [-].
AXIS_P99_FACTOR = 1.25
#: A jump in s larger than this share of the lap (or than ``GAP_MIN_M``) is a gap [-].
GAP_SHARE = 0.02
#: ... and never less than this [m].
GAP_MIN_M = 0.5
#: Methods that run no optimisation per tick (their "solve time" is a compute time).
NO_SOLVER_PREFIXES = (*(n for n, s in METHODS.items() if s.kind != "mpc"), "rdm")


@dataclass(frozen=True)
class ReferenceLine:
    """The minimum-time lap of the simulated car, as the figures need it.

    Attributes:
        lap_time_s: its lap time [s].
        x_m, y_m: (N,) its path [m].
        s_m: (N,) progress of each point along the track's centreline [m], in [0, L).
        v_mps: (N,) its speed [m/s].
        name: the legend label.
    """

    lap_time_s: float
    x_m: np.ndarray
    y_m: np.ndarray
    s_m: np.ndarray
    v_mps: np.ndarray
    name: str = "minimum-time line"


def plural(n: int, word: str) -> str:
    """``"1 lap"``, ``"3 laps"``."""
    return f"{n} {word}" if n == 1 else f"{n} {word}s"


def no_solver(name: str) -> bool:
    """True for a method without an optimiser (a tracker on a raceline): what Fig. 8
    shows for it is the wall time of its tick's computation, no solve."""
    return name.lower().startswith(NO_SOLVER_PREFIXES)


def break_gaps(
    s: np.ndarray, values: np.ndarray, gap_m: float
) -> tuple[np.ndarray, np.ndarray]:
    """Sort (s, values) by s and put a NaN between neighbours more than `gap_m` apart.

    A line drawn through the result stops at a gap in the data (a lap recorded only in
    part, a stretch where nothing was recorded) instead of joining its ends straight.

    Args:
        s: (N,) progress [m]; values: (N,) the plotted quantity.
        gap_m: the largest step in s that is still drawn [m].

    Returns:
        (s', values'), each (N + gaps,), sorted by s, NaN at the gaps.
    """
    s = np.asarray(s, dtype=float)
    v = np.asarray(values, dtype=float)
    order = np.argsort(s, kind="stable")
    s, v = s[order], v[order]
    cut = np.flatnonzero(np.diff(s) > gap_m) + 1
    return np.insert(s, cut, np.nan), np.insert(v, cut, np.nan)


def gap_for(length_m: float) -> float:
    """The gap threshold of `break_gaps` on a lap of `length_m` [m]."""
    return max(GAP_MIN_M, GAP_SHARE * length_m)


def compute_time_axis_ms(samples: Sequence[Sequence[float]]) -> float:
    """The end of Fig. 8's axis [ms]: ``AXIS_P99_FACTOR`` x the largest per-method p99.

    One slow solve (a cold start, the machine busy) sets no axis: solves beyond it are
    counted in the last bin and said on the figure.
    """
    p99 = [float(np.percentile(np.asarray(t, dtype=float), 99)) for t in samples if len(t)]
    return max(max(p99, default=0.0) * AXIS_P99_FACTOR, 1e-3)


def _plt():
    import matplotlib

    matplotlib.use("Agg", force=True)
    import matplotlib.pyplot as plt

    return plt


def _save(fig, path: Path) -> None:
    fig.savefig(path, dpi=DPI, bbox_inches="tight", pad_inches=0.08)
    _plt().close(fig)


def draw_curvature(profile: CurvatureProfile, title: str = ""):
    """Paper Fig. 4: curvature, its moving average, and the NSC along s; the figure."""
    plt = _plt()
    fig, (a, b) = plt.subplots(2, 1, figsize=(9, 5.5), sharex=True)
    a.plot(profile.s_m, profile.kappa, lw=0.8, color="0.6", label="curvature $\\kappa$")
    a.plot(
        profile.s_m,
        profile.smoothed,
        lw=1.6,
        color="C3",
        label=f"smoothed $K$ (window {profile.window} points)",
    )
    a.set_ylabel("curvature [1/m]")
    a.legend(loc="upper right", fontsize=8)
    b.plot(profile.s_m, profile.nsc, color="C0", label="NSC $K^n$")
    b.plot(
        profile.s_m,
        profile.beta,
        color="C2",
        ls="--",
        label=f"$\\beta = g(K^n)$, $\\alpha$ = {profile.alpha:g}",
    )
    b.set_ylabel("[-]")
    b.set_xlabel("s [m]")
    b.set_ylim(-0.05, 1.05)
    b.set_xlim(0, profile.length_m)
    b.legend(loc="center right", fontsize=8, framealpha=0.9)  # beta ~1, NSC ~0: free there
    fig.suptitle(title or "Fig. 4: curvature and normalised smoothed curvature (NSC) along s")
    fig.tight_layout()
    return fig


def fig_curvature(profile: CurvatureProfile, path: Path, title: str = "") -> None:
    """Write Fig. 4 to `path`."""
    _save(draw_curvature(profile, title), path)


def draw_speed_vs_s(
    profile: CurvatureProfile,
    runs: list[MethodRun],
    reference: ReferenceLine | None = None,
    title: str = "",
):
    """Paper Fig. 5a: speed along s of each method (every timed lap, gaps left open) over
    the NSC as background, with the minimum-time line's speed; the figure."""
    plt = _plt()
    fig, ax = plt.subplots(figsize=(10, 4.5))
    L = profile.length_m
    ax.imshow(
        profile.nsc[None, :],
        aspect="auto",
        cmap="Greys",
        alpha=0.3,
        extent=(0.0, L, 0.0, 1.0),
        transform=ax.get_xaxis_transform(),
        vmin=0,
        vmax=1,
        origin="lower",
    )
    gap = gap_for(L)
    for i, run in enumerate(runs):
        tr = run.trace.arrays()
        timed = tr["lap"] >= 1
        if not timed.any():
            continue
        s, v, lap = tr["s_m"][timed], tr["speed_mps"][timed], tr["lap"][timed]
        laps = np.unique(lap)
        for k, lap_no in enumerate(laps):
            sel = (lap == lap_no) & np.isfinite(s) & np.isfinite(v)
            if not sel.any():
                continue
            s_k, v_k = break_gaps(s[sel], v[sel], gap)
            ax.plot(
                s_k,
                v_k,
                color=f"C{i}",
                lw=1.6,
                alpha=max(0.5, 1.0 - 0.04 * len(laps)),
                label=f"{run.name} ({plural(len(run.laps), 'lap')})" if k == 0 else None,
            )
    if reference is not None:
        s_r, v_r = break_gaps(np.mod(reference.s_m, L), reference.v_mps, gap)
        ax.plot(s_r, v_r, color="k", lw=1.4, ls="--",
                label=f"{reference.name} ({reference.lap_time_s:.2f} s)")
    ax.set_xlim(0, L)
    drawn = np.concatenate([np.asarray(ln.get_ydata(), float) for ln in ax.get_lines()]
                           or [np.zeros(0)])
    drawn = drawn[np.isfinite(drawn)]
    if drawn.size:  # the speeds, not 0 (the NSC image would pull the axis down to 0)
        lo, hi = float(drawn.min()), float(drawn.max())
        pad = max(0.1, 0.08 * (hi - lo))
        ax.set_ylim(max(0.0, lo - pad), hi + pad)
    ax.set_xlabel("s [m] (background: NSC, darker = sharper turn)")
    ax.set_ylabel("speed [m/s]")
    if ax.get_legend_handles_labels()[0]:  # beside the plot: it covers no curve
        ax.legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize=8, borderaxespad=0.0)
    ax.set_title(title or "Fig. 5: speed along the track")
    fig.tight_layout()
    return fig


def fig_speed_vs_s(
    profile: CurvatureProfile,
    runs: list[MethodRun],
    path: Path,
    reference: ReferenceLine | None = None,
    title: str = "",
) -> None:
    """Write Fig. 5 to `path`."""
    _save(draw_speed_vs_s(profile, runs, reference, title), path)


def _path_segments(x: np.ndarray, y: np.ndarray, gap_m: float) -> np.ndarray:
    """(M, 2, 2) segments between consecutive points, leaving out jumps over `gap_m` [m]."""
    p = np.stack([x, y], axis=1)
    seg = np.stack([p[:-1], p[1:]], axis=1)
    ok = np.isfinite(seg).all(axis=(1, 2)) & (np.linalg.norm(p[1:] - p[:-1], axis=1) <= gap_m)
    return seg[ok]


def _draw_track(ax, track: Track) -> None:
    """The track as a light band with thin edges, the start line and direction arrows."""
    left = np.vstack([track.left_boundary, track.left_boundary[:1]])
    right = np.vstack([track.right_boundary, track.right_boundary[:1]])
    band = np.vstack([left, right[::-1]])
    ax.fill(band[:, 0], band[:, 1], color="0.9", lw=0, zorder=0)
    for b in (left, right):
        ax.plot(b[:, 0], b[:, 1], color="0.6", lw=0.4, zorder=1)
    xy = track.xy
    L = track.length_m
    span = float(np.ptp(xy, axis=0).max())
    # start line across the track at s = 0, and a marker
    ax.plot([track.left_boundary[0, 0], track.right_boundary[0, 0]],
            [track.left_boundary[0, 1], track.right_boundary[0, 1]], color="k", lw=2.0,
            zorder=4)
    ax.plot(*xy[0], marker="o", ms=5, color="k", zorder=5)
    ax.annotate("start", xy[0], xytext=(6, 6), textcoords="offset points", fontsize=8,
                zorder=5)
    # driving direction: arrows along the centreline at a few places
    s = np.asarray(track.s_m, dtype=float)
    for frac in (0.0, 0.25, 0.5, 0.75):
        k = int(np.searchsorted(s, frac * L + 0.02 * L))
        k = min(k, len(xy) - 2)
        d = xy[k + 1] - xy[k]
        d = d / max(float(np.linalg.norm(d)), 1e-9) * 0.07 * span
        ax.annotate("", xy=xy[k] + d, xytext=xy[k], zorder=5,
                    arrowprops={"arrowstyle": "-|>", "color": "k", "lw": 1.4,
                                "mutation_scale": 14})


def draw_trajectories(
    track: Track,
    runs: list[MethodRun],
    reference: ReferenceLine | None = None,
    title: str = "",
):
    """Paper Fig. 6: driven paths (timed laps) coloured by speed, one panel per method (and
    one for the minimum-time line), start line and driving direction marked; the figure."""
    from matplotlib.collections import LineCollection

    plt = _plt()
    panels: list[tuple[str, np.ndarray, np.ndarray, np.ndarray]] = []
    for run in runs:
        tr = run.trace.arrays()
        timed = tr["lap"] >= 1
        panels.append((f"{run.name}: {plural(run.completed_laps, 'lap')}",
                       tr["x_m"][timed], tr["y_m"][timed], tr["speed_mps"][timed]))
    if reference is not None:
        panels.append((f"{reference.name}: {reference.lap_time_s:.2f} s",
                       np.asarray(reference.x_m), np.asarray(reference.y_m),
                       np.asarray(reference.v_mps)))
    n = max(1, len(panels))
    lo, hi = track.xy.min(axis=0), track.xy.max(axis=0)
    w_max = float(max(np.max(track.w_left_m), np.max(track.w_right_m)))
    lo, hi = lo - w_max - 0.2, hi + w_max + 0.2
    aspect = float((hi[1] - lo[1]) / max(hi[0] - lo[0], 1e-9))
    panel_w = 4.8
    cols = n if n <= 4 else 3  # one row up to four panels
    panel_w = panel_w if cols <= 3 else 4.0
    rows = int(np.ceil(n / cols))
    fig, axes = plt.subplots(rows, cols, figsize=(panel_w * cols + 1.0,
                                                  panel_w * aspect * rows + 0.8),
                             squeeze=False, layout="constrained")
    speeds = np.concatenate([v[np.isfinite(v)] for _, _, _, v in panels] or [np.ones(1)])
    if not speeds.size:
        speeds = np.ones(1)
    vmax = float(speeds.max())
    vmin = max(0.0, np.floor(2.0 * float(np.percentile(speeds, 1))) / 2.0)
    vmin = min(vmin, max(vmax - 0.5, 0.0))  # a range of at least 0.5 m/s
    span = float(np.ptp(track.xy, axis=0).max())
    lw = float(np.clip(150.0 / max(span, 1.0), 1.6, 3.0))  # thinner on a long track
    coloured = None
    for ax, (label, x, y, v) in zip(axes.flat, panels, strict=False):
        _draw_track(ax, track)
        seg = _path_segments(np.asarray(x, float), np.asarray(y, float), gap_for(span))
        if len(seg):
            p = np.stack([x, y], axis=1)
            ok = np.isfinite(p).all(axis=1)
            vv = np.asarray(v, float)
            mid = 0.5 * (vv[:-1] + vv[1:])
            dist = np.linalg.norm(p[1:] - p[:-1], axis=1)
            keep = ok[:-1] & ok[1:] & (dist <= gap_for(span))
            coll = LineCollection(seg, cmap="turbo", linewidths=lw, zorder=3)
            coll.set_array(mid[keep])
            coll.set_clim(vmin, vmax)
            ax.add_collection(coll)
            coloured = coll
        ax.set_title(label, fontsize=10)
        ax.set_aspect("equal")
        ax.set_xlim(lo[0], hi[0])
        ax.set_ylim(lo[1], hi[1])
        ax.set_xlabel("x [m]")
        ax.set_ylabel("y [m]")
    for ax in list(axes.flat)[len(panels):]:
        ax.set_visible(False)
    if coloured is not None:
        fig.colorbar(coloured, ax=axes.ravel().tolist(), label="speed [m/s]",
                     shrink=0.8 if aspect * rows <= 1.2 else 0.55, pad=0.02)
    fig.suptitle(title or f"Fig. 6: driven paths on {track.name}, coloured by speed")
    return fig


def fig_trajectories(
    track: Track,
    runs: list[MethodRun],
    path: Path,
    reference: ReferenceLine | None = None,
    title: str = "",
) -> None:
    """Write Fig. 6 to `path`."""
    _save(draw_trajectories(track, runs, reference, title), path)


def draw_laps(runs: list[MethodRun], reference: ReferenceLine | None = None, title: str = ""):
    """Paper Fig. 7: lap time and mean speed of each lap with each method's mean, the
    minimum-time lap as a line; whole-number lap ticks, the legend beside the plots."""
    plt = _plt()
    fig, (a, b) = plt.subplots(2, 1, figsize=(10, 6), sharex=True)
    n_max = 1
    for i, run in enumerate(runs):
        if not run.laps:
            continue
        k = np.arange(1, len(run.laps) + 1)
        n_max = max(n_max, len(run.laps))
        t = np.array([lap.lap_time_s for lap in run.laps])
        v = np.array([lap.mean_speed_mps for lap in run.laps])
        off = np.array([lap.off_track_events > 0 for lap in run.laps])
        a.plot(k, t, "o-", color=f"C{i}", label=f"{run.name} (mean {np.mean(t):.3f} s)")
        a.axhline(np.mean(t), color=f"C{i}", ls=":", lw=1)
        b.plot(k, v, "s-", color=f"C{i}", label=run.name)
        if off.any():
            a.scatter(k[off], t[off], marker="x", s=80, color="red", zorder=5,
                      label=f"{run.name}: off track")
    if reference is not None:
        a.axhline(reference.lap_time_s, color="k", ls="--", lw=1.2,
                  label=f"{reference.name} ({reference.lap_time_s:.3f} s)")
    a.set_ylabel("lap time [s]")
    b.set_ylabel("mean speed [m/s]")
    b.set_xlabel("lap")
    step = int(np.ceil(n_max / 15))  # whole laps only, at most ~15 ticks
    b.set_xticks(np.arange(1, n_max + 1, step))
    b.set_xlim(0.5, n_max + 0.5)
    handles, labels = a.get_legend_handles_labels()
    if handles:  # beside the plots: it covers no point
        a.legend(handles, labels, loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize=8,
                 borderaxespad=0.0)
    a.set_title(title or "Fig. 7: lap time and mean speed of every lap")
    fig.tight_layout()
    return fig


def fig_laps(
    runs: list[MethodRun], path: Path, reference: ReferenceLine | None = None, title: str = ""
) -> None:
    """Write Fig. 7 to `path`."""
    _save(draw_laps(runs, reference, title), path)


def draw_solve_time(runs: list[MethodRun], title: str = ""):
    """Paper Fig. 8: histogram of each method's compute time per tick, its cumulative share
    and p95 (in the legend); the axis ends at ``compute_time_axis_ms`` (slower ticks are
    counted in the last bin and said on the figure). The MPC methods' time is the solver's
    wall time; a method without a solver (``no_solver``) shows its tick's compute time."""
    plt = _plt()
    fig, ax = plt.subplots(figsize=(9, 4.8))
    ax2 = ax.twinx()
    samples = [np.asarray(r.solve_times_ms, dtype=float) for r in runs]
    x_max = compute_time_axis_ms([t for t in samples if t.size])
    bins = np.linspace(0, x_max, 60)
    beyond = []
    for i, (run, t) in enumerate(zip(runs, samples, strict=True)):
        if t.size == 0:
            continue
        p95 = float(np.percentile(t, 95))
        what = "compute time, no solver" if no_solver(run.name) else "solve time"
        ax.hist(np.clip(t, 0, x_max), bins=bins, alpha=0.45, color=f"C{i}",
                label=f"{run.name} ({what}), p95 {p95:.2f} ms")
        ts = np.sort(t)
        ax2.plot(ts, np.arange(1, ts.size + 1) / ts.size, color=f"C{i}", lw=1.4)
        ax.axvline(p95, color=f"C{i}", ls="--", lw=1)
        over = int(np.count_nonzero(t > x_max))
        if over:
            beyond.append(f"{run.name} {over} (max {t.max():.1f} ms)")
    ax.set_xlim(0, x_max)
    ax2.set_xlim(0, x_max)
    label = "compute time per planner tick [ms] (dashed: p95)"
    if beyond:  # said under the axis, over no bar
        label += (f"\naxis ends at {AXIS_P99_FACTOR:g} x the largest p99; ticks beyond it "
                  f"(counted in the last bin): {', '.join(beyond)}")
    ax.set_xlabel(label)
    ax.set_ylabel("ticks")
    ax2.set_ylabel("share of ticks below")
    ax2.set_ylim(0, 1.02)
    ax.legend(loc="center right", fontsize=8, framealpha=0.9)
    ax.set_title(title or "Fig. 8: planner compute time per tick")
    fig.tight_layout()
    return fig


def fig_solve_time(runs: list[MethodRun], path: Path, title: str = "") -> None:
    """Write Fig. 8 to `path`."""
    _save(draw_solve_time(runs, title), path)


def write_figures(
    out_dir: Path,
    track: Track,
    profile: CurvatureProfile,
    runs: list[MethodRun],
    reference: ReferenceLine | None = None,
) -> list[Path]:
    """Write all five figures into `out_dir`; returns their paths.

    Args:
        reference: the minimum-time line to draw beside the methods (None: none).
    """
    name = track.name
    paths = {
        "fig4_curvature.png": lambda p: fig_curvature(
            profile, p, f"Fig. 4: curvature and NSC along s on {name}"),
        "fig5_speed_vs_s.png": lambda p: fig_speed_vs_s(
            profile, runs, p, reference, f"Fig. 5: speed along s on {name}"),
        "fig6_trajectories.png": lambda p: fig_trajectories(track, runs, p, reference),
        "fig7_laps.png": lambda p: fig_laps(
            runs, p, reference, f"Fig. 7: lap time and mean speed of every lap on {name}"),
        "fig8_solve_time.png": lambda p: fig_solve_time(
            runs, p, f"Fig. 8: planner compute time per tick on {name}"),
    }
    out = []
    for fname, draw in paths.items():
        path = out_dir / fname
        draw(path)
        out.append(path)
    return out
