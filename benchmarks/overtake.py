"""Overtaking (issue #24): the raceline planner's solve time with two opponents in its
horizon, and (``--race``) head-to-head races over seeded starts on several tracks.

    .venv/bin/python -m benchmarks.overtake [--track ../shared/tracks/map416] [--ticks 600]
    .venv/bin/python -m benchmarks.overtake --race [--tracks T1,T2,...] [--seeds 20]
        [--first-seed 0] [--laps 2] [--opponent raceline:0.85] [--source truth|lidar]
        [--aware]
    .venv/bin/python -m benchmarks.overtake --race --aware --opponent raceline:1.0 --laps 10
        (two near-limit cars together: each plans around the other)

Races (``--race``): ``raceline`` (the ego) against ``--opponent`` on each track, over the
seeded starts of the bench (``services.tools.bench.head_to_head``: both from standstill, the
opponent a random 2-6 m ahead), ``--laps`` laps each (``--stop-lead M``: a start ends once
the ego has passed and leads by M m; the rest would be its solo lap). Printed per track:
the bench's table, then the acceptance lines of #24 (passed within the laps in >= 90 % of
the starts, 0 contacts, 0 off-track events of the ego) and, with ``--source lidar``, the
tracker's id switches per overtake (times the id of the track matched to the opponent
within 5 m changed, over the overtakes). ``--aware``: the opponent also plans around the
ego (two near-limit cars racing together); the acceptance line is then 0 contacts and 0
off-track events of either car over every start.

Solve time (default):
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
from services.tools.bench.head_to_head import (
    HeadToHeadOptions,
    OpponentSpec,
    format_head_to_head,
    run_head_to_head,
)
from shared.config import load_config
from shared.config.methods import RACELINE
from shared.track import load_track

#: The tracks of ``--race`` by default: the two narrow ones and two F1TENTH maps (2.2 m).
RACE_TRACKS = (
    "../shared/tracks/map416",
    "builtin:paperlike",
    "../shared/tracks/f1tenth/Oschersleben",
    "../shared/tracks/f1tenth/Spielberg",
)


def _opponent(line, ref, s: float, e: float, share: float, oid: int) -> OpponentEstimate:
    x, y = (float(v) for v in line.point_at(s))
    h = float(line.heading_at(s))
    x, y = x + e * math.sin(h), y - e * math.cos(h)  # e right +
    v = share * float(ref.at("v", s))
    return OpponentEstimate(oid, x, y, v * math.cos(h), v * math.sin(h), h)


def race(a: argparse.Namespace) -> int:
    """``--race``: the head-to-head races of every track (module docstring)."""
    cfg = load_config(None)
    spec = OpponentSpec.parse(a.opponent)
    opts = HeadToHeadOptions(laps=a.laps, seeds=a.seeds, first_seed=a.first_seed,
                             source=a.source, stop_lead_m=a.stop_lead,
                             opponent_aware=a.aware)
    ok = True
    for name in a.tracks.split(","):
        track = load_track(name.strip())
        t0 = time.perf_counter()
        doc = run_head_to_head(cfg, track, [RACELINE], spec, opts,
                               progress=print if a.verbose else None)
        m = doc[RACELINE]
        print(format_head_to_head(track.name, spec, doc, a.laps))
        passed = m["overtake_rate"] >= 0.9
        clean = m["contacts"] == 0 and m["off_track_ego"] == 0
        if a.aware:  # two cars racing together: clean is the target, passing is not
            both = clean and m["off_track_opponent"] == 0
            ok &= both
            print(f"  {track.name}: two cars racing together ({spec.method} x "
                  f"{spec.speed_scale:g} aware of the ego), {a.laps} laps x {m['seeds']} "
                  f"starts: contacts {m['contacts']}, off-track ego / opponent "
                  f"{m['off_track_ego']} / {m['off_track_opponent']}, aborted "
                  f"{m['aborted']} (target 0 contacts, 0 off-track: "
                  f"{'met' if both else 'NOT met'})")
        else:
            ok &= passed and clean
        print(f"  {track.name}: passed within {a.laps} laps in {m['overtaken_within_laps']}/"
              f"{m['seeds']} starts ({100 * m['overtake_rate']:.1f} %, target >= 90 %: "
              f"{'met' if passed else 'NOT met'}); contacts {m['contacts']} (struck by the "
              f"ego {m['contacts_struck_by_ego']}), off-track ego / opponent "
              f"{m['off_track_ego']} / {m['off_track_opponent']} (target 0 / -: "
              f"{'met' if clean else 'NOT met'}); aborted {m['aborted']}; seeds "
              f"{a.first_seed}-{a.first_seed + a.seeds - 1}"
              + ("" if a.stop_lead is None else f", each ended {a.stop_lead:g} m ahead")
              + f"; wall {time.perf_counter() - t0:.0f} s")
        if m["tracker_id_changes"] is not None:
            per = m["tracker_id_changes"] / max(m["overtakes"], 1)
            print(f"  {track.name}: tracker id switches {m['tracker_id_changes']} over "
                  f"{m['overtakes']} overtakes ({per:.2f} per overtake)")
        failed = [r["seed"] for r in m["per_seed"]
                  if r["first_overtake_laps"] is None or r["contacts"] or r["ego_off_track"]]
        if failed:
            print(f"  {track.name}: starts not passed or not clean: {failed}")
    return 0 if ok else 1


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--track", default="../shared/tracks/map416",
                    help="track spec (default ../shared/tracks/map416)")
    ap.add_argument("--ticks", type=int, default=600, help="ticks (default 600)")
    ap.add_argument("--step", type=float, default=0.2, help="metres between poses (0.2)")
    ap.add_argument("--seed", type=int, default=0, help="seed (default 0)")
    ap.add_argument("--race", action="store_true",
                    help="race head to head instead of timing the solve (default off)")
    ap.add_argument("--tracks", default=",".join(RACE_TRACKS),
                    help=f"--race: comma-separated track specs (default {','.join(RACE_TRACKS)})")
    ap.add_argument("--seeds", type=int, default=20, help="--race: seeded starts (default 20)")
    ap.add_argument("--first-seed", type=int, default=0,
                    help="--race: the first seed (default 0)")
    ap.add_argument("--laps", type=int, default=2, help="--race: laps per start (default 2)")
    ap.add_argument("--opponent", default=f"{RACELINE}:0.85",
                    help=f"--race: METHOD[:SPEED_SCALE] (default {RACELINE}:0.85)")
    ap.add_argument("--source", choices=("truth", "lidar"), default="truth",
                    help="--race: the ego sees the opponent from (default truth)")
    ap.add_argument("--stop-lead", type=float, default=None,
                    help="--race: end a start once the ego has passed and leads by this many "
                    "metres (default: race all the laps)")
    ap.add_argument("--aware", action="store_true",
                    help="--race: the opponent plans around the ego too (default off)")
    ap.add_argument("--verbose", action="store_true",
                    help="--race: a line per start (default off)")
    a = ap.parse_args(argv)
    if a.race:
        return race(a)
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
