"""Solve-time benchmark of the planner over a closed loop (issue 2's figure).

Closes the planner for `--steps` ticks and prints the solver-call wall time: median, p95, p99,
max, plus the iterations, the success rate, laps driven and the largest contour error. Run from
the project root:

    .venv/bin/python -m benchmarks.solve_time --track ../shared/tracks/map416 --steps 2000

Targets on the 2-core machines for N = 10: median <= 1 ms, p99 <= 2 ms.

``--plant model`` (default) closes the loop on the planner's own model (the problem's RK4 step
at the planner's step); ``--plant sim`` on the bench's simulator (the dynamic car at its
limit, the bench's 2 ms compute delay), where the solver meets what it meets in a race.
``--config FILE`` takes the planner settings from a configuration file or overlay (e.g.
``config/cimpcc-line-speed.toml``). ``--repeat K`` runs the loop K times and quotes the
figures of all ticks together, each run's median and p99 too.

``--method cimpcc-line`` solves its minimum-time line first (once per track, then cached).

``--pause-ms P`` waits P ms before each tick, as the service does between its states (20 Hz:
about 48 ms), sleeping or (``--pause-spin``) busy-waiting: the solve after a pause is slower
than back to back (the caches went cold meanwhile; README, "what the quiet latency is made
of"). The pause is not in the solve time.

    .venv/bin/python -m benchmarks.solve_time --track builtin:paperlike --steps 600 --pause-ms 50
"""

from __future__ import annotations

import argparse
import sys
import time

import numpy as np

from services.planner import Planner, ensure_artefacts
from services.tools.bench import LoopOptions, ModelPlant, race
from services.tools.bench.closed_loop import SimulatorPlant
from shared.config import ConfigError, RacestackConfig, load_config
from shared.config.methods import CIMPCC, METHODS, planner_methods
from shared.track import TrackError, load_track


def run(
    track_spec: str,
    steps: int,
    method: str,
    compile_: bool,
    backend: str,
    beta_mode: str,
    cfg: RacestackConfig | None = None,
    plant_kind: str = "model",
    pause_s: float = 0.0,
    pause_spin: bool = False,
) -> dict:
    """Run the closed loop; return the figures (times in ms); `pause_s` [s] before each tick
    (slept, or busy-waited with `pause_spin`)."""
    track = load_track(track_spec)
    cfg = cfg or RacestackConfig()
    settings = cfg.planner.model_copy(
        update={
            "method": method,
            "beta_mode": beta_mode,
            "solver": cfg.planner.solver.model_copy(
                update={"compile": compile_, "backend": backend}
            ),
        }
    )
    ensure_artefacts(method, track, settings, cfg.vehicle)  # cimpcc-line's line
    t0 = time.perf_counter()
    planner = Planner(track, settings, cfg.curvature, vehicle=cfg.vehicle)
    setup_s = time.perf_counter() - t0
    iterations: list[int] = []
    step = planner.step

    def counted(*args, **kwargs):  # type: ignore[no-untyped-def]
        if pause_s > 0.0:
            if pause_spin:
                end = time.perf_counter() + pause_s
                while time.perf_counter() < end:
                    pass
            else:
                time.sleep(pause_s)
        result = step(*args, **kwargs)
        iterations.append(result.iterations)
        return result

    planner.step = counted  # type: ignore[method-assign]
    if plant_kind == "sim":
        plant = SimulatorPlant(track, cfg.simulator, LoopOptions(laps=10**6), None)
        got = race(planner, plant, None, max_ticks=steps, reset=False)
    else:
        # the planner's own model (cimpcc, mpcc: the paper's)
        # its state: the pose and progress, and (cimpcc-line) the car's speed, from standstill
        x0 = np.zeros(len(planner.problem.model_index))
        x0[:3] = (*track.xy[0], track.heading_rad[0])
        model_plant = ModelPlant(track, planner.problem.step, x0)
        got = race(planner, model_plant, None, max_ticks=steps)
    t = np.asarray(got.solve_times_s) * 1e3
    it = np.asarray(iterations, dtype=float)
    laps = got.laps if plant_kind == "sim" else model_plant.progress_m / track.length_m
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
        "success": got.solved / max(got.ticks, 1),
        "laps": laps,
        "max_abs_e_con_m": got.max_abs_e_con_m,
        "iter_median": float(np.median(it)),
        "iter_p99": float(np.percentile(it, 99)),
        "iter_max": int(it.max()),
        "times_ms": t,
    }


def main(argv: list[str] | None = None) -> int:
    """Command line entry point."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--track", default="../shared/tracks/map416")
    ap.add_argument("--steps", type=int, default=2000)
    ap.add_argument(
        "--method",
        choices=[n for n in planner_methods() if METHODS[n].kind == "mpc"],
        default=CIMPCC,
    )
    ap.add_argument("--backend", choices=["fatrop", "ipopt"], default="fatrop")
    ap.add_argument("--beta-mode", choices=["current", "per_stage"], default="current")
    ap.add_argument("--no-compile", action="store_true")
    ap.add_argument("--config", default=None, help="configuration file or overlay (TOML)")
    ap.add_argument("--plant", choices=["model", "sim"], default="model")
    ap.add_argument("--repeat", type=int, default=1, help="run the loop this many times")
    ap.add_argument("--pause-ms", type=float, default=0.0,
                    help="wait this long before each tick [ms] (default 0: back to back)")
    ap.add_argument("--pause-spin", action="store_true",
                    help="busy-wait the pause instead of sleeping")
    args = ap.parse_args(argv)
    runs = []
    try:
        cfg = load_config(args.config)
        for _ in range(max(args.repeat, 1)):
            runs.append(run(
                args.track, args.steps, args.method, not args.no_compile, args.backend,
                args.beta_mode, cfg, args.plant, args.pause_ms / 1e3, args.pause_spin,
            ))
    except (TrackError, ConfigError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    r = runs[0]
    if len(runs) > 1:
        t = np.concatenate([x["times_ms"] for x in runs])
        for i, x in enumerate(runs):
            print(f"run {i + 1}: median {x['median_ms']:.3f}  p99 {x['p99_ms']:.3f} ms, "
                  f"iterations median {x['iter_median']:.0f} p99 {x['iter_p99']:.0f}")
        r = {**r, "steps": len(t), "median_ms": float(np.median(t)),
             "p95_ms": float(np.percentile(t, 95)), "p99_ms": float(np.percentile(t, 99)),
             "max_ms": float(t.max())}
    print(
        f"track {r['track']}  method {r['method']}  backend {args.backend}  "
        f"compiled {r['compiled']} (cache hit {r['cache_hit']}, set-up {r['setup_s']:.2f} s)"
    )
    print(
        f"{r['steps']} closed-loop steps, {r['laps']:.1f} laps, success {100 * r['success']:.1f} %,"
        f" max |e_con| {r['max_abs_e_con_m']:.3f} m  (plant {args.plant}"
        + (f", {args.pause_ms:g} ms {'busy-waited' if args.pause_spin else 'slept'} before "
           "each tick)" if args.pause_ms > 0 else ")")
    )
    print(
        f"iterations: median {r['iter_median']:.0f}  p99 {r['iter_p99']:.0f}  "
        f"max {r['iter_max']}"
    )
    print(
        f"solve time [ms]: median {r['median_ms']:.3f}  p95 {r['p95_ms']:.3f}  "
        f"p99 {r['p99_ms']:.3f}  max {r['max_ms']:.3f}"
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
