"""The paper's figures from a bench run or a recording, each as vector PDF and SVG beside a
300 dpi PNG (``plotting.save_figure``; matplotlib, no display). The figure number is in the
file name and the caption (``CAPTIONS``, also written as ``captions.md``), not in the title.

- ``fig4_curvature``: raw and smoothed curvature, then the NSC and the weight beta along s
  (paper Fig. 4). The raw curvature is a thin translucent line under the smoothed one, and
  the axis is set by the smoothed curvature (the raw one's sawtooth is clipped, said so).
- ``fig5_speed_vs_s``: speed along s of each method over the NSC as background (Fig. 5a),
  each method with its own colour, dash and markers over the minimum-time line (a grey band
  drawn first); below it, each method's speed minus the minimum-time line's, which parts
  methods that drive the same line.
- ``fig6_trajectories`` (``figure_paths``): a panel per method (and the minimum-time line)
  coloured by speed, off-track events marked; the grid's remaining cells (at least one, two
  on a long track) zoom where the paths part most, every path overlaid.
- ``fig7_laps`` (``figure_laps``): lap time of every lap per method (points, the mean, its
  gap to the limit), with the mean speed (centreline length / lap time) on the right-hand
  axis; beside it, with more than one lap, the laps in order.
- ``fig8_solve_time``: compute time per planner cycle (one cycle per planner period):
  step histograms as the share of each method's cycles, and the cumulative share with p95.

Legends are rows above the axes, inside the figure (``plotting.legend_row``), or inside
the axes; none widens a figure. The minimum-time line (``ReferenceLine``, passed in as data:
this package imports no service) is drawn beside the methods in Figs. 5, 6 and 7.

The data-level choices are plain functions, tested without pixels: ``break_gaps`` (a gap
in s is a gap in the line, not a straight segment), ``compute_time_axis_ms`` (Fig. 8's axis
is set by the p99 of the samples, not by one outlier), ``no_solver`` (the raceline's tracker
has a compute time, not a solve time: it runs no optimiser per tick), ``grid_shape`` and
``zoom_windows`` (Fig. 6).
"""

from __future__ import annotations

import textwrap
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from shared.config.methods import METHODS
from shared.curvature import CurvatureProfile
from shared.evaluation.figure_laps import draw_laps
from shared.evaluation.figure_paths import draw_trajectories, grid_shape, zoom_windows
from shared.evaluation.plotting import (
    DPI,
    FORMATS,
    LIMIT_STYLE,
    ReferenceLine,
    break_gaps,
    gap_for,
    legend_row,
    method_style,
    new_figure,
    parse_formats,
    plural,
    save_figure,
)
from shared.evaluation.results import MethodRun
from shared.track import Track

__all__ = [
    "CAPTIONS",
    "DPI",
    "FORMATS",
    "ReferenceLine",
    "break_gaps",
    "compute_time_axis_ms",
    "draw_curvature",
    "draw_laps",
    "draw_solve_time",
    "draw_speed_vs_s",
    "draw_trajectories",
    "gap_for",
    "grid_shape",
    "no_solver",
    "parse_formats",
    "plural",
    "save_figure",
    "write_figures",
    "zoom_windows",
]

#: Fig. 8's axis ends at this many times the largest per-method p99 [-].
AXIS_P99_FACTOR = 1.25
#: Methods that run no optimisation per tick (their "solve time" is a compute time).
NO_SOLVER_PREFIXES = (*(n for n, s in METHODS.items() if s.kind != "mpc"), "rdm")
#: Fig. 4's curvature axis ends at this many times the smoothed curvature's maximum [-].
CURVATURE_AXIS_FACTOR = 1.35
#: The figures' file stems and captions (the figure number lives here, not in the titles).
CAPTIONS: dict[str, str] = {
    "fig4_curvature": "Fig. 4: curvature of the centreline (raw and smoothed), and the "
                      "normalised smoothed curvature (NSC) with the weight beta along s.",
    "fig5_speed_vs_s": "Fig. 5: speed along s of each method over the NSC, and each "
                       "method's speed minus the minimum-time line's.",
    "fig6_trajectories": "Fig. 6: driven paths coloured by speed, off-track events "
                         "marked, and zooms where the paths part, with every path.",
    "fig7_laps": "Fig. 7: lap time of every lap per method with the mean speed "
                 "(centreline length / lap time), and the laps in order.",
    "fig8_solve_time": "Fig. 8: planner compute time per planner cycle: histogram and "
                       "cumulative share with p95.",
}


def no_solver(name: str) -> bool:
    """True for a method without an optimiser (a tracker on a raceline): what Fig. 8
    shows for it is the wall time of its tick's computation, no solve."""
    return name.lower().startswith(NO_SOLVER_PREFIXES)


def compute_time_axis_ms(samples: Sequence[Sequence[float]]) -> float:
    """The end of Fig. 8's axis [ms]: ``AXIS_P99_FACTOR`` x the largest per-method p99.

    One slow solve (a cold start, the machine busy) sets no axis: solves beyond it are
    counted in the last bin and said on the figure.
    """
    p99 = [float(np.percentile(np.asarray(t, dtype=float), 99)) for t in samples if len(t)]
    return max(max(p99, default=0.0) * AXIS_P99_FACTOR, 1e-3)


def _nsc_background(ax, profile: CurvatureProfile) -> None:
    """The NSC as a grey band behind a plot along s (darker = sharper turn)."""
    ax.imshow(profile.nsc[None, :], aspect="auto", cmap="Greys", alpha=0.3,
              extent=(0.0, profile.length_m, 0.0, 1.0), transform=ax.get_xaxis_transform(),
              vmin=0, vmax=1, origin="lower", zorder=0)


def draw_curvature(profile: CurvatureProfile, title: str = ""):
    """Paper Fig. 4: curvature and its moving average, then the NSC and beta along s; the
    figure. The raw curvature is thin and translucent under the smoothed one, and the
    axis ends at ``CURVATURE_AXIS_FACTOR`` x the smoothed maximum (raw peaks above it are
    clipped, said in its legend entry)."""
    fig, body = new_figure((9, 5.5))
    a, b = body.subplots(2, 1, sharex=True)
    k_max = float(np.max(profile.smoothed)) if profile.smoothed.size else 1.0
    top = max(k_max * CURVATURE_AXIS_FACTOR, 1e-6)
    clipped = bool(np.any(profile.kappa > top))
    a.plot(profile.s_m, profile.kappa, lw=0.5, color="0.45", alpha=0.55, zorder=2,
           label="raw curvature $\\kappa$" + (" (peaks clipped)" if clipped else ""))
    a.plot(profile.s_m, profile.smoothed, lw=1.8, color="C3", zorder=3,
           label=f"smoothed curvature $K$ (moving average, {profile.window} points)")
    a.set_ylim(min(0.0, float(np.min(profile.smoothed))) - 0.03 * top, top)
    a.set_ylabel("curvature [1/m]")
    a.legend(loc="lower left", bbox_to_anchor=(0.0, 1.0), ncol=2, fontsize=8,
             frameon=False, borderaxespad=0.2)
    b.plot(profile.s_m, profile.nsc, color="C0", lw=1.6,
           label="NSC $K^n = (K - K_{min}) / (K_{max} - K_{min})$")
    b.plot(profile.s_m, profile.beta, color="C2", lw=1.6, ls="--",
           label=f"weight $\\beta = e^{{-\\alpha (K^n)^2}}$, $\\alpha$ = {profile.alpha:g}")
    b.set_ylabel("NSC $K^n$, weight $\\beta$ [1]")
    b.set_xlabel("s: distance along the centreline [m]")
    b.set_ylim(-0.05, 1.05)
    b.set_xlim(0, profile.length_m)
    b.legend(loc="lower left", bbox_to_anchor=(0.0, 1.0), ncol=2, fontsize=8,
             frameon=False, borderaxespad=0.2)
    fig.suptitle(title or "Curvature and normalised smoothed curvature (NSC) along s")
    return fig


def _laps_of(run: MethodRun, gap_m: float):
    """(s, v) of each timed lap of `run`, gaps open (``break_gaps``)."""
    tr = run.trace.arrays()
    if not len(tr["lap"]):
        return
    timed = tr["lap"] >= 1
    s, v, lap = tr["s_m"][timed], tr["speed_mps"][timed], tr["lap"][timed]
    for lap_no in np.unique(lap):
        sel = (lap == lap_no) & np.isfinite(s) & np.isfinite(v)
        if sel.any():
            yield break_gaps(s[sel], v[sel], gap_m)


def draw_speed_vs_s(
    profile: CurvatureProfile,
    runs: list[MethodRun],
    reference: ReferenceLine | None = None,
    title: str = "",
):
    """Paper Fig. 5a: speed along s of each method (every timed lap, gaps left open) over
    the NSC as background, with the minimum-time line's speed; the figure.

    The minimum-time line is a grey band drawn first; each method has its colour, dash and
    markers (spaced along s, shifted per method), so lines on the same path stay apart.
    With a reference, a second panel shows each method's speed minus the minimum-time
    line's at the same s (0 = the limit)."""
    L = profile.length_m
    fig, body = new_figure((10, 6.2 if reference is not None else 4.6))
    if reference is not None:
        ax, dax = body.subplots(2, 1, sharex=True, height_ratios=(2.2, 1.0))
    else:
        ax, dax = body.subplots(1, 1), None
    for a in (ax, dax):
        if a is not None:
            _nsc_background(a, profile)
    gap = gap_for(L)
    handles, labels = [], []
    v_ref = None
    if reference is not None:
        s_r, v_r = break_gaps(np.mod(reference.s_m, L), reference.v_mps, gap)
        (h,) = ax.plot(s_r, v_r, zorder=2, **LIMIT_STYLE)
        handles.append(h)
        labels.append(f"{reference.name} ({reference.lap_time_s:.2f} s)")
        ok = np.isfinite(s_r) & np.isfinite(v_r)
        s_c, v_c = s_r[ok], v_r[ok]

        def v_ref(s: np.ndarray) -> np.ndarray:  # the limit's speed at s (periodic)
            return np.interp(np.mod(s, L), s_c, v_c, period=L)

        dax.axhline(0.0, zorder=2, **LIMIT_STYLE)
    n = max(1, len(runs))
    for i, run in enumerate(runs):
        st = method_style(i)
        first = True
        for s_k, v_k in _laps_of(run, gap):
            kw = {"color": st["color"], "ls": st["ls"], "lw": 1.6, "zorder": 3 + i,
                  "marker": st["marker"] if first else None, "ms": 4.5, "mfc": "white",
                  "mew": 1.2, "markevery": _markevery(s_k, L, i, n) if first else None}
            (h,) = ax.plot(s_k, v_k, **kw)
            if v_ref is not None:
                dax.plot(s_k, v_k - v_ref(s_k), **kw)
            if first:
                handles.append(h)
                labels.append(f"{run.name} ({plural(len(run.laps), 'lap')})")
                first = False
    ax.set_xlim(0, L)
    _fit_y(ax, floor_zero=True)
    ax.set_ylabel("speed [m/s]")
    last = dax if dax is not None else ax
    last.set_xlabel("s: distance along the centreline [m] (background: NSC, darker = "
                    "sharper turn)")
    if dax is not None:
        _fit_y(dax, floor_zero=False)
        dax.set_ylabel("speed - min-time\nline's [m/s]")
    legend_row(body, handles, labels, max_cols=5)
    fig.suptitle(title or "Speed along the track")
    return fig


def _markevery(s: np.ndarray, L: float, i: int, n: int) -> list[int]:
    """Indices of a line's markers: every 1/12 of the lap, method `i` of `n` shifted by
    i/n of that step (markers of methods on the same line do not sit on each other)."""
    step = L / 12.0
    ok = np.isfinite(s)
    if not ok.any():
        return []
    targets = np.arange(step * i / n, L, step)
    idx = np.flatnonzero(ok)
    k = np.searchsorted(s[idx], targets)
    k = np.clip(k, 0, idx.size - 1)
    near = np.abs(s[idx][k] - targets) <= step / 4
    return sorted(set(idx[k[near]].tolist()))


def _fit_y(ax, floor_zero: bool) -> None:
    """The y axis set by the drawn lines (not by the NSC image's 0..1); never below 0
    with `floor_zero` (speeds)."""
    drawn = [np.asarray(ln.get_ydata(), float) for ln in ax.get_lines()]
    ys = np.concatenate(drawn) if drawn else np.zeros(0)
    ys = ys[np.isfinite(ys)]
    if not ys.size:
        return
    lo, hi = float(ys.min()), float(ys.max())
    pad = max(0.1, 0.08 * (hi - lo))
    ax.set_ylim(max(0.0, lo - pad) if floor_zero else lo - pad, hi + pad)


def draw_solve_time(runs: list[MethodRun], title: str = "",
                    planner_period_s: float | None = None):
    """Paper Fig. 8: each method's compute time per planner cycle (one cycle = one planner
    period, `planner_period_s`, said on the figure when given): step histograms of the
    share of its cycles per bin (left) and the cumulative share with p95 (right, and in
    the legend); the figure. The axis ends at ``compute_time_axis_ms`` (slower cycles are
    counted in the last bin and said under the axis). The MPC methods' time is the
    solver's wall time; a method without a solver (``no_solver``) shows its cycle's compute
    time."""
    fig, body = new_figure((10, 4.8))
    ax, cax = body.subplots(1, 2, sharex=True)
    samples = [np.asarray(r.solve_times_ms, dtype=float) for r in runs]
    x_max = compute_time_axis_ms([t for t in samples if t.size])
    bins = np.linspace(0, x_max, 60)
    beyond = []
    handles, labels = [], []
    for i, (run, t) in enumerate(zip(runs, samples, strict=True)):
        if t.size == 0:
            continue
        st = method_style(i)
        p95 = float(np.percentile(t, 95))
        what = "compute time, no solver" if no_solver(run.name) else "solve time"
        weights = np.full(t.size, 100.0 / t.size)
        ax.hist(np.clip(t, 0, x_max), bins=bins, weights=weights, histtype="step",
                lw=1.6, color=st["color"], ls=st["ls"], zorder=3 + i)
        ts = np.sort(t)
        (h,) = cax.plot(ts, 100.0 * np.arange(1, ts.size + 1) / ts.size, color=st["color"],
                        ls=st["ls"], lw=1.6, zorder=3 + i)
        cax.plot([p95], [95.0], marker=st["marker"], color=st["color"], ms=7, mfc="white",
                 mew=1.5, zorder=10)
        handles.append(h)
        labels.append(f"{run.name} ({what}), p95 {p95:.2f} ms")
        over = int(np.count_nonzero(t > x_max))
        if over:
            beyond.append(f"{run.name} {over} (max {t.max():.1f} ms)")
    ax.set_xlim(0, x_max)
    cax.axhline(95.0, color="0.5", lw=0.8, ls=":", zorder=1)
    cax.annotate("95 %", (0.01, 95.0), xycoords=("axes fraction", "data"),
                 xytext=(0, 3), textcoords="offset points", fontsize=8, color="0.4")
    for a in (ax, cax):
        a.set_xlabel("compute time per planner cycle [ms]")
    if beyond:  # said under the axes, over no bar
        note = (f"axis ends at {AXIS_P99_FACTOR:g} x the largest p99; cycles beyond it "
                f"(counted in the last bin): {', '.join(beyond)}")
        body.supxlabel(textwrap.fill(note, 150), fontsize=8)
    ax.set_ylabel("share of the method's cycles per bin [%]")
    cax.set_ylabel("planner cycles at or below [%]")
    cax.set_ylim(0, 102)
    ax.set_ylim(bottom=0)
    ax.set_title("histogram", fontsize=10)
    cax.set_title("cumulative share (marker: p95)", fontsize=10)
    legend_row(body, handles, labels, max_cols=2)
    cycle = ""
    if planner_period_s:
        cycle = (f" (one cycle = one planner period, {1e3 * planner_period_s:g} ms, "
                 f"{1.0 / planner_period_s:g} Hz)")
    fig.suptitle((title or "Planner compute time per cycle") + cycle)
    return fig


def write_figures(
    out_dir: Path,
    track: Track,
    profile: CurvatureProfile,
    runs: list[MethodRun],
    reference: ReferenceLine | None = None,
    formats: Sequence[str] = FORMATS,
    planner_period_s: float | None = None,
) -> list[Path]:
    """Write all five figures into `out_dir`, each in every one of `formats`, and their
    captions (``captions.md``); returns the figures' paths (figure by figure, in the
    order of `formats`).

    Args:
        reference: the minimum-time line to draw beside the methods (None: none).
        formats: some of ``FORMATS`` (default all: pdf, svg, png).
        planner_period_s: the planner's period [s] (Fig. 8 says what one cycle is).
    """
    out_dir = Path(out_dir)
    name = track.name
    draws = {
        "fig4_curvature": lambda: draw_curvature(
            profile, f"Curvature and NSC along s on {name}"),
        "fig5_speed_vs_s": lambda: draw_speed_vs_s(
            profile, runs, reference, f"Speed along s on {name}"),
        "fig6_trajectories": lambda: draw_trajectories(track, runs, reference),
        "fig7_laps": lambda: draw_laps(
            runs, reference, f"Lap times on {name}", length_m=track.length_m),
        "fig8_solve_time": lambda: draw_solve_time(
            runs, f"Planner compute time per cycle on {name}", planner_period_s),
    }
    out: list[Path] = []
    for stem, draw in draws.items():
        out += save_figure(draw(), out_dir / stem, formats)
    exts = ",".join(parse_formats(formats))
    lines = [f"# Figures on {name}", ""]
    lines += [f"- `{stem}.{{{exts}}}`: {CAPTIONS[stem]}" for stem in draws]
    (out_dir / "captions.md").write_text("\n".join(lines) + "\n", encoding="utf-8")
    return out
