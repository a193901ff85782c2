"""Solve time of the raceline planner with two opponents in its horizon (issue #24).

    .venv/bin/python -m benchmarks.overtake [--track ../shared/tracks/map416] [--ticks 600]

The ``raceline`` planner (``[planner.raceline]``, the minimum-time line from the cache) is
stepped from ``--ticks`` poses along its line (every ``--step`` m, a fresh planner state is
not needed: the hint follows), each tick with two opponents predicted over its horizon: one
1.2-2.0 m ahead on the line at 85 % of the line's speed and one 3-5 m ahead 0.3 m off it
(seeded). Printed: median / p99 / max of the wall time of ``step`` [ms] (what the planner
reports as ``solve_time_s``) and of its process CPU time (less sensitive to other processes
on a shared machine), of the plan around the opponents alone, and the same ``step`` without
opponents; the shares of the ticks in each mode (pass / follow / line).
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from collections import Counter

import numpy as np

from services.planner import PlannerPool, ensure_artefacts
from services.planner.opponents import OpponentEstimate
from shared.config import load_config
from shared.config.methods import RACELINE
from shared.track import load_track


def _opponent(line, ref, s: float, e: float, share: float, oid: int) -> OpponentEstimate:
    x, y = (float(v) for v in line.point_at(s))
    h = float(line.heading_at(s))
    x, y = x + e * math.sin(h), y - e * math.cos(h)  # e right +
    v = share * float(ref.at("v", s))
    return OpponentEstimate(oid, x, y, v * math.cos(h), v * math.sin(h), h)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--track", default="../shared/tracks/map416",
                    help="track spec (default ../shared/tracks/map416)")
    ap.add_argument("--ticks", type=int, default=600, help="ticks (default 600)")
    ap.add_argument("--step", type=float, default=0.2, help="metres between poses (0.2)")
    ap.add_argument("--seed", type=int, default=0, help="seed (default 0)")
    a = ap.parse_args(argv)
    cfg = load_config(None)
    track = load_track(a.track)
    ensure_artefacts(RACELINE, track, cfg.planner, cfg.vehicle)
    planner = PlannerPool(track, cfg.vehicle).planner(cfg.planner, RACELINE, cfg.curvature)
    line = planner.raceline.track
    ref = planner.raceline.reference
    lr = cfg.vehicle.lr_m
    rng = np.random.default_rng(a.seed)
    with_ms, alone_ms, plan_ms, cpu_ms = [], [], [], []
    modes: Counter[str] = Counter()
    orig = planner._plan_around

    def timed(*args):  # the plan alone
        t0 = time.perf_counter()
        out = orig(*args)
        plan_ms.append(1e3 * (time.perf_counter() - t0))
        return out
    planner._plan_around = timed
    for k in range(a.ticks):
        s = (k * a.step) % line.length_m
        x, y = (float(v) for v in line.point_at(s))
        yaw = float(line.heading_at(s))
        rx, ry = x - lr * math.cos(yaw), y - lr * math.sin(yaw)  # the rear axle
        opps = [
            _opponent(line, ref, s + rng.uniform(1.2, 2.0), 0.0, 0.85, 1),
            _opponent(line, ref, s + rng.uniform(3.0, 5.0), 0.3 * rng.choice([-1, 1]), 0.85, 2),
        ]
        planner.set_opponents(opps)
        c0 = time.process_time()
        r = planner.step(rx, ry, yaw)
        cpu_ms.append(1e3 * (time.process_time() - c0))
        with_ms.append(1e3 * r.solve_time_s)
        modes[planner.plan.mode] += 1
        planner.set_opponents([])
        alone_ms.append(1e3 * planner.step(rx, ry, yaw).solve_time_s)

    def fig(v: list[float]) -> str:
        return (f"median {np.median(v):.3f} ms, p99 {np.percentile(v, 99):.3f} ms, "
                f"max {np.max(v):.3f} ms")

    print(f"raceline on {track.name}, {a.ticks} ticks, two opponents in the horizon")
    print(f"  step with two opponents: {fig(with_ms)}")
    print(f"  step with two opponents, process CPU time: {fig(cpu_ms)}")
    print(f"  the plan around them alone: {fig(plan_ms[:len(with_ms)])}")
    print(f"  step without opponents: {fig(alone_ms)}")
    print("  modes: " + ", ".join(f"{m} {100 * n / a.ticks:.0f} %" for m, n in modes.items()))
    return 0


if __name__ == "__main__":
    sys.exit(main())
