"""The paper's figures from a bench run, as PNG files (matplotlib, no display needed).

- ``fig4_curvature.png``: raw curvature, smoothed curvature and NSC along s (paper Fig. 4).
- ``fig5_speed_vs_s.png``: speed along s of each method over the NSC as background (Fig. 5a).
- ``fig6_trajectories.png``: driven paths on the track coloured by speed, a panel per method
  (Fig. 6).
- ``fig7_laps.png``: lap time and mean speed of every lap (Fig. 7).
- ``fig8_solve_time.png``: solve-time histogram with the cumulative share and p95 (Fig. 8).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from shared.curvature import CurvatureProfile
from shared.evaluation.results import MethodRun
from shared.track import Track


def _plt():
    import matplotlib

    matplotlib.use("Agg", force=True)
    import matplotlib.pyplot as plt

    return plt


def fig_curvature(profile: CurvatureProfile, path: Path) -> None:
    """Paper Fig. 4: curvature, its moving average, and the NSC along s."""
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
    a.legend(loc="upper right")
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
    b.legend(loc="upper right")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def fig_speed_vs_s(profile: CurvatureProfile, runs: list[MethodRun], path: Path) -> None:
    """Paper Fig. 5a: measured speed along s of each method over the NSC as background."""
    plt = _plt()
    fig, ax = plt.subplots(figsize=(10, 4.5))
    extent = (0.0, profile.length_m, 0.0, 1.0)
    ax.imshow(
        profile.nsc[None, :],
        aspect="auto",
        cmap="Greys",
        alpha=0.45,
        extent=extent,
        transform=ax.get_xaxis_transform(),
        vmin=0,
        vmax=1,
        origin="lower",
    )
    for i, run in enumerate(runs):
        tr = run.trace.arrays()
        timed = tr["lap"] >= 1
        if not timed.any():
            continue
        s, v, lap = tr["s_m"][timed], tr["speed_mps"][timed], tr["lap"][timed]
        for k, lap_no in enumerate(np.unique(lap)):
            sel = lap == lap_no
            order = np.argsort(s[sel])
            ax.plot(
                s[sel][order],
                v[sel][order],
                color=f"C{i}",
                lw=0.7,
                alpha=0.35,
                label=run.name if k == 0 else None,
            )
    ax.set_xlim(0, profile.length_m)
    ax.set_xlabel("s [m] (background: NSC, darker = sharper)")
    ax.set_ylabel("speed [m/s]")
    ax.legend(loc="lower right")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def fig_trajectories(track: Track, runs: list[MethodRun], path: Path) -> None:
    """Paper Fig. 6: driven trajectories coloured by speed, one panel per method."""
    plt = _plt()
    n = max(1, len(runs))
    fig, axes = plt.subplots(1, n, figsize=(5.2 * n, 5), squeeze=False)
    speeds = [run.trace.arrays()["speed_mps"] for run in runs]
    vmax = max((float(v.max()) for v in speeds if v.size), default=1.0)
    sc = None
    for ax, run in zip(axes[0], runs, strict=False):
        tr = run.trace.arrays()
        for b in (track.left_boundary, track.right_boundary):
            closed = np.vstack([b, b[:1]])
            ax.plot(closed[:, 0], closed[:, 1], color="k", lw=0.8)
        timed = tr["lap"] >= 1
        sc = ax.scatter(
            tr["x_m"][timed],
            tr["y_m"][timed],
            c=tr["speed_mps"][timed],
            s=1.5,
            cmap="turbo",
            vmin=0,
            vmax=vmax,
        )
        ax.set_title(f"{run.name}: {run.completed_laps} laps")
        ax.set_aspect("equal")
        ax.set_xlabel("x [m]")
        ax.set_ylabel("y [m]")
    if sc is not None:
        fig.colorbar(sc, ax=axes[0].tolist(), label="speed [m/s]", shrink=0.85)
    fig.savefig(path, dpi=110)
    plt.close(fig)


def fig_laps(runs: list[MethodRun], path: Path) -> None:
    """Paper Fig. 7: lap time and mean speed of each lap, with each method's mean."""
    plt = _plt()
    fig, (a, b) = plt.subplots(2, 1, figsize=(9, 6), sharex=True)
    for i, run in enumerate(runs):
        if not run.laps:
            continue
        k = np.arange(1, len(run.laps) + 1)
        t = [lap.lap_time_s for lap in run.laps]
        v = [lap.mean_speed_mps for lap in run.laps]
        off = [lap.off_track_events > 0 for lap in run.laps]
        a.plot(k, t, "o-", color=f"C{i}", label=f"{run.name} (MLT {np.mean(t):.3f} s)")
        a.axhline(np.mean(t), color=f"C{i}", ls=":", lw=1)
        b.plot(k, v, "s-", color=f"C{i}", label=run.name)
        if any(off):
            a.scatter(
                k[np.array(off)],
                np.array(t)[np.array(off)],
                marker="x",
                s=80,
                color="red",
                zorder=5,
                label=f"{run.name}: off track",
            )
    a.set_ylabel("lap time [s]")
    a.legend(fontsize=8)
    b.set_ylabel("mean speed [m/s]")
    b.set_xlabel("lap")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def fig_solve_time(runs: list[MethodRun], path: Path) -> None:
    """Paper Fig. 8: histogram of solve times with the cumulative share and p95 marked."""
    plt = _plt()
    fig, ax = plt.subplots(figsize=(8, 4.5))
    ax2 = ax.twinx()
    all_t = np.concatenate(
        [np.asarray(r.solve_times_ms) for r in runs if r.solve_times_ms] or [np.zeros(1)]
    )
    bins = np.linspace(0, max(float(np.percentile(all_t, 99.9)) * 1.1, 1e-3), 60)
    for i, run in enumerate(runs):
        t = np.asarray(run.solve_times_ms)
        if t.size == 0:
            continue
        ax.hist(np.clip(t, 0, bins[-1]), bins=bins, alpha=0.45, color=f"C{i}", label=run.name)
        ts = np.sort(t)
        ax2.plot(ts, np.arange(1, ts.size + 1) / ts.size, color=f"C{i}")
        p95 = float(np.percentile(t, 95))
        ax.axvline(p95, color=f"C{i}", ls="--", lw=1)
        ax2.annotate(
            f"p95 {p95:.2f} ms",
            (p95, 0.95),
            color=f"C{i}",
            fontsize=8,
            xytext=(4, -12 - 10 * i),
            textcoords="offset points",
        )
    ax.set_xlabel("solve time [ms]")
    ax.set_ylabel("count")
    ax2.set_ylabel("share of solves below")
    ax2.set_ylim(0, 1.02)
    ax.legend(loc="center right")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def write_figures(
    out_dir: Path, track: Track, profile: CurvatureProfile, runs: list[MethodRun]
) -> list[Path]:
    """Write all five figures into `out_dir`; returns their paths."""
    paths = {
        "fig4_curvature.png": lambda p: fig_curvature(profile, p),
        "fig5_speed_vs_s.png": lambda p: fig_speed_vs_s(profile, runs, p),
        "fig6_trajectories.png": lambda p: fig_trajectories(track, runs, p),
        "fig7_laps.png": lambda p: fig_laps(runs, p),
        "fig8_solve_time.png": lambda p: fig_solve_time(runs, p),
    }
    out = []
    for name, draw in paths.items():
        path = out_dir / name
        draw(path)
        out.append(path)
    return out
