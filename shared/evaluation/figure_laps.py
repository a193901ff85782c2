"""Paper Fig. 7: the lap times (``draw_laps``).

Left, one column per method: every lap's time as a point (spread across the column), the
method's mean as a bar with its value and its gap to the minimum-time lap written above, so
methods within 0.1 s of each other stay apart and readable; the minimum-time lap is a grey
band. The right-hand axis reads the same lap times as mean speed, the centreline length
over the lap time (the paper's "velocity" of a lap; not the car's mean speed along its own,
shorter, line). With more than one lap, a second panel shows the laps in order, each
method's markers shifted a little along x so close methods do not hide each other.
Off-track laps are red crosses. A one-lap run has the first panel alone.
"""

from __future__ import annotations

import numpy as np

from shared.evaluation.plotting import (
    LIMIT_STYLE,
    OFF_TRACK_STYLE,
    ReferenceLine,
    legend_row,
    method_style,
    new_figure,
    plural,
)
from shared.evaluation.results import MethodRun

#: Each method's markers in the laps panel are shifted by this much per method [laps].
LAP_OFFSET = 0.07


def lap_length_m(runs: list[MethodRun]) -> float | None:
    """The lap length the runs' mean speeds were computed with (mean speed x lap time:
    ``LapRecord.mean_speed_mps`` is the centreline length over the lap time) [m], or None
    without laps."""
    d = [lap.mean_speed_mps * lap.lap_time_s for r in runs for lap in r.laps
         if lap.lap_time_s > 0 and np.isfinite(lap.mean_speed_mps)]
    return float(np.median(d)) if d else None


def draw_laps(runs: list[MethodRun], reference: ReferenceLine | None = None, title: str = "",
              length_m: float | None = None):
    """Paper Fig. 7: lap time of every lap per method, its mean and gap to the limit, the
    mean speed (`length_m` / lap time, the centreline length; default from the laps) on
    the right-hand axis, and with more than one lap the laps in order; the figure."""
    from matplotlib.lines import Line2D

    multi = any(len(r.laps) > 1 for r in runs)
    fig, body = new_figure((11.5, 5.0) if multi else (8.0, 5.0))
    if multi:
        ax, bx = body.subplots(1, 2, sharey=True, width_ratios=(1.0, 1.5))
    else:
        ax, bx = body.subplots(1, 1), None
    L = length_m or lap_length_m(runs)
    ref_t = reference.lap_time_s if reference is not None else None
    handles, labels = [], []
    raced = [(i, r) for i, r in enumerate(runs) if r.laps]
    off_any = False
    every = [lap.lap_time_s for _, r in raced for lap in r.laps] + ([ref_t] if ref_t else [])
    lo, hi = (min(every), max(every)) if every else (0.0, 1.0)
    pad = max(0.05, 0.12 * (hi - lo))
    for pos, (i, run) in enumerate(raced):
        st = method_style(i)
        t = np.array([lap.lap_time_s for lap in run.laps])
        off = np.array([lap.off_track_events > 0 for lap in run.laps])
        x = pos + (np.linspace(-0.22, 0.22, t.size) if t.size > 1 else np.zeros(1))
        ax.scatter(x, t, marker=st["marker"], s=30, facecolors="white",
                   edgecolors=st["color"], linewidths=1.3, zorder=4)
        mean = float(np.mean(t))
        ax.hlines(mean, pos - 0.32, pos + 0.32, color=st["color"], lw=2.2, zorder=3)
        note = f"{mean:.3f} s"
        if ref_t:
            gap = 100.0 * (mean / ref_t - 1.0)  # two decimals near the limit
            note += f"\n{gap:+.2f} % vs limit" if abs(gap) < 1.0 else f"\n{gap:+.1f} % vs limit"
        if t.size > 1:
            note += f"\n{plural(t.size, 'lap')}, sd {1e3 * float(np.std(t)):.0f} ms"
        ax.annotate(note, (pos, float(t.max())), xytext=(0, 6), textcoords="offset points",
                    ha="center", va="bottom", fontsize=8, color=st["color"], zorder=5)
        if off.any():
            off_any = True
            ax.scatter(x[off], t[off], **OFF_TRACK_STYLE)
        if bx is not None:
            k = np.arange(1, t.size + 1) + (i - (len(runs) - 1) / 2) * LAP_OFFSET
            bx.plot(k, t, color=st["color"], ls=st["ls"], lw=1.2, marker=st["marker"],
                    ms=5, mfc="white", mew=1.3, zorder=3 + i)
            if off.any():
                bx.scatter(k[off], t[off], **OFF_TRACK_STYLE)
        handles.append(Line2D([], [], color=st["color"], ls=st["ls"], marker=st["marker"],
                              mfc="white", mew=1.3))
        labels.append(f"{run.name} (mean {mean:.3f} s)")
    for a in (ax, bx):
        if a is not None and ref_t:
            a.axhline(ref_t, zorder=2, **LIMIT_STYLE)
    if ref_t:
        handles.append(Line2D([], [], **LIMIT_STYLE))
        labels.append(f"{reference.name} ({ref_t:.3f} s)")
    if off_any:
        handles.append(Line2D([], [], ls="none", marker=OFF_TRACK_STYLE["marker"],
                              color=OFF_TRACK_STYLE["color"], mec="k", ms=8))
        labels.append("lap with an off-track event")
    ax.set_xticks(range(len(raced)), [r.name for _, r in raced],
                  rotation=20 if len(raced) > 3 else 0)
    ax.set_xlim(-0.6, max(len(raced), 1) - 0.4)
    ax.set_ylim(lo - pad, hi + 2.2 * pad)  # room for the notes above the columns
    ax.set_ylabel("lap time [s]")
    ax.set_title("per method: every lap (points) and the mean (bar)", fontsize=10)
    right = ax
    if bx is not None:
        n_max = max(len(r.laps) for r in runs)
        step = int(np.ceil(n_max / 15))  # whole laps only, at most ~15 ticks
        bx.set_xticks(np.arange(1, n_max + 1, step))
        bx.set_xlim(0.5, n_max + 0.5)
        bx.set_xlabel("lap")
        bx.set_title("the laps in order (markers shifted per method)", fontsize=10)
        right = bx
    if L:
        def speed(t):  # lap time [s] -> mean speed [m/s] and back (its own inverse)
            return L / np.maximum(np.asarray(t, dtype=float), 1e-9)

        sec = right.secondary_yaxis("right", functions=(speed, speed))
        sec.set_ylabel(f"mean speed [m/s]\n= centreline length ({L:.1f} m) / lap time")
    legend_row(body, handles, labels, max_cols=4)
    fig.suptitle(title or "Lap times")
    return fig
