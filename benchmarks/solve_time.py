"""Solve-time benchmark of the planner over a closed loop (issue 2's figure).

Closes the planner with its own model (the problem's RK4 step at the planner's step) for `--steps`
ticks and prints the solver-call wall time: median, p95, p99, max, plus the success rate,
laps driven and the largest contour error. Run from the project root:

    .venv/bin/python -m benchmarks.solve_time --track ../shared/tracks/map416 --steps 2000

Targets on the 2-core machines for N = 10: median <= 1 ms, p99 <= 2 ms.

``--method cimpcc-line`` solves its minimum-time line first (once per track, then cached);
its own model is the kinematic bicycle with tyre slip, so the loop measures the solver, not
the method's tracking of the real car (``racestack bench`` does that).
"""

from __future__ import annotations

import argparse
import sys
import time

import numpy as np

from services.bench import ModelPlant, race
from services.planner import Planner
from shared.config.planner import PlannerSettings, SolverSettings
from shared.track import TrackError, load_track


def run(
    track_spec: str, steps: int, method: str, compile_: bool, backend: str, beta_mode: str
) -> dict:
    """Run the closed loop; return the figures (times in ms)."""
    track = load_track(track_spec)
    settings = PlannerSettings(
        method=method,
        beta_mode=beta_mode,
        solver=SolverSettings(compile=compile_, backend=backend),
    )
    t0 = time.perf_counter()
    planner = Planner(track, settings)
    setup_s = time.perf_counter() - t0
    # the planner's own model (cimpcc, mpcc: the paper's)
    # its state: the pose and progress, and (cimpcc-line) the car's speed, from standstill
    x0 = np.zeros(len(planner.problem.model_index))
    x0[:3] = (*track.xy[0], track.heading_rad[0])
    plant = ModelPlant(track, planner.problem.step, x0)
    got = race(planner, plant, None, max_ticks=steps)
    t = np.asarray(got.solve_times_s) * 1e3
    return {
        "track": track.name,
        "method": method,
        "steps": steps,
        "compiled": planner.solver.compiled,
        "cache_hit": planner.solver.cache_hit,
        "setup_s": setup_s,
        "median_ms": float(np.median(t)),
        "p95_ms": float(np.percentile(t, 95)),
        "p99_ms": float(np.percentile(t, 99)),
        "max_ms": float(t.max()),
        "success": got.solved / steps,
        "laps": plant.progress_m / track.length_m,
        "max_abs_e_con_m": got.max_abs_e_con_m,
    }


def main(argv: list[str] | None = None) -> int:
    """Command line entry point."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--track", default="../shared/tracks/map416")
    ap.add_argument("--steps", type=int, default=2000)
    ap.add_argument("--method", choices=["cimpcc", "mpcc", "cimpcc-line"], default="cimpcc")
    ap.add_argument("--backend", choices=["fatrop", "ipopt"], default="fatrop")
    ap.add_argument("--beta-mode", choices=["current", "per_stage"], default="current")
    ap.add_argument("--no-compile", action="store_true")
    args = ap.parse_args(argv)
    try:
        r = run(
            args.track, args.steps, args.method, not args.no_compile, args.backend, args.beta_mode
        )
    except TrackError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    print(
        f"track {r['track']}  method {r['method']}  backend {args.backend}  "
        f"compiled {r['compiled']} (cache hit {r['cache_hit']}, set-up {r['setup_s']:.2f} s)"
    )
    print(
        f"{r['steps']} closed-loop steps, {r['laps']:.1f} laps, success {100 * r['success']:.1f} %,"
        f" max |e_con| {r['max_abs_e_con_m']:.3f} m"
    )
    print(
        f"solve time [ms]: median {r['median_ms']:.3f}  p95 {r['p95_ms']:.3f}  "
        f"p99 {r['p99_ms']:.3f}  max {r['max_ms']:.3f}"
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
