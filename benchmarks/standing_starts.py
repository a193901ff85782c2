"""Standing starts anywhere on the track: does a planner join its line cleanly (issue #21)?

A car put down at rest on the centreline at a seeded random station (a grid slot, a reset,
a marshal's restart) races ``--seconds`` under ``--method`` (default ``raceline``) in the
bench's closed loop (20 Hz, 2 ms compute delay, the simulator's delays). Per track it
prints the starts that left the track, the off-track events, the car's top speed and the
ticks it spent over the 4.18 m/s cap by more than 1 %; then the totals. The stations are
``numpy.random.default_rng(seed).uniform(0, length)``, so a run is the same on every
machine.

    .venv/bin/python -m benchmarks.standing_starts --tracks map416,paperlike,gen:1 --starts 20
    .venv/bin/python -m benchmarks.standing_starts --config identified.toml --seed 13
    .venv/bin/python -m benchmarks.standing_starts --method cimpcc-line
"""

from __future__ import annotations

import argparse
import math
import sys
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from services.planner import for_pose_source
from services.planner.interface import PlannerLike
from services.planner.mintime.store import ensure_artefacts
from services.planner.registry import PlannerPool
from services.simulator import Command
from services.tools.bench.head_to_head import SimCar
from shared.config import RacestackConfig, load_config
from shared.config.methods import RACELINE
from shared.track import Track, load_track

#: The paper's speed cap and the share over it that counts as an excursion.
CAP_MPS = 4.18
CAP_TOLERANCE = 0.01
#: Compute delay of the bench's loop [s].
COMPUTE_DELAY_S = 0.002


@dataclass
class StartsResult:
    """Standing starts on one track."""

    track: str
    starts: int
    off_starts: list[float]  #: stations [m] of the starts that left the track
    off_events: int
    top_speed_mps: float
    over_cap_ticks: int
    step_ms: list[float] = field(default_factory=list)  #: each tick's step time [ms]


def race_from(
    planner: PlannerLike,
    track: Track,
    cfg: RacestackConfig,
    s0_m: float,
    seconds: float,
    step_ms: list[float] | None = None,
) -> tuple[int, float, int]:
    """(off-track events, top speed [m/s], ticks over the cap) of one start at `s0_m`;
    each tick's step time [ms] (the planner's own timer) appended to `step_ms`."""
    car = SimCar(track, cfg.simulator, s0_m)
    planner.reset()
    period, step = planner.settings.dt_s, cfg.simulator.integration_step_s
    top, over = 0.0, 0
    for _ in range(round(seconds / period)):
        res = planner.step(*car.rear_pose())
        if step_ms is not None:
            step_ms.append(res.solve_time_s * 1e3)
        new = Command(res.command.speed_mps, res.command.steering_rad)
        car.step(car.cmd, COMPUTE_DELAY_S)
        n = max(1, math.ceil((period - COMPUTE_DELAY_S) / step - 1e-9))
        for _ in range(n):
            car.step(new, (period - COMPUTE_DELAY_S) / n)
        car.cmd = new
        v = car.sim.state.v_mps
        top = max(top, v)
        over += v > CAP_MPS * (1.0 + CAP_TOLERANCE)
    return car.off, top, over


def run_track(
    spec: str,
    cfg: RacestackConfig,
    starts: int,
    seed: int,
    seconds: float,
    method: str = RACELINE,
) -> StartsResult:
    """`starts` seeded standing starts of `method` on the track `spec`."""
    track = load_track(spec)
    settings = for_pose_source(cfg.planner, "truth")  # the bench's: the true pose's tube
    ensure_artefacts(method, track, settings, cfg.vehicle, progress=None)
    planner = PlannerPool(track, cfg.vehicle).planner(settings, method, cfg.curvature)
    rng = np.random.default_rng(seed)
    res = StartsResult(track.name, starts, [], 0, 0.0, 0)
    for _ in range(starts):
        s0 = float(rng.uniform(0.0, track.length_m))
        off, top, over = race_from(planner, track, cfg, s0, seconds, res.step_ms)
        res.off_events += off
        if off:
            res.off_starts.append(round(s0, 2))
        res.top_speed_mps = max(res.top_speed_mps, top)
        res.over_cap_ticks += over
    return res


def _step(ms: list[float]) -> str:
    """Median / p99 [ms] of step times."""
    if not ms:
        return "-"
    return f"{np.median(ms):.2f}/{np.percentile(ms, 99):.2f}"


def _track_spec(name: str, tracks_dir: Path) -> str:
    return str(tracks_dir / name) if (tracks_dir / name).is_dir() else name


def main(argv: Sequence[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--tracks", default="map416,paperlike,gen:1,gen:2",
                    help="comma list of tracks (a name under --tracks-dir, a built-in, gen:SEED)")
    ap.add_argument("--method", default=RACELINE, help="a registry method (default raceline)")
    ap.add_argument("--starts", type=int, default=20, help="starts per track")
    ap.add_argument("--seed", type=int, default=11, help="seed of the start stations")
    ap.add_argument("--seconds", type=float, default=6.0, help="time raced from each start")
    ap.add_argument("--config", default=None, help="a racestack TOML (e.g. another [vehicle])")
    ap.add_argument("--tracks-dir", type=Path,
                    default=Path(__file__).resolve().parents[2] / "shared" / "tracks")
    args = ap.parse_args(argv)
    cfg = load_config(args.config)
    total = StartsResult("all", 0, [], 0, 0.0, 0)
    print(f"{'track':<12} {'starts':>6} {'left':>5} {'off':>4} {'top m/s':>8} {'>cap':>5}"
          f" {'step ms':>11}  stations that left [m]")
    for name in [t for t in args.tracks.split(",") if t]:
        r = run_track(_track_spec(name, args.tracks_dir), cfg, args.starts, args.seed,
                      args.seconds, args.method)
        print(f"{r.track:<12} {r.starts:>6} {len(r.off_starts):>5} {r.off_events:>4} "
              f"{r.top_speed_mps:>8.3f} {r.over_cap_ticks:>5} {_step(r.step_ms):>11}  "
              f"{r.off_starts}")
        total.starts += r.starts
        total.off_starts += r.off_starts
        total.off_events += r.off_events
        total.top_speed_mps = max(total.top_speed_mps, r.top_speed_mps)
        total.over_cap_ticks += r.over_cap_ticks
        total.step_ms += r.step_ms
    print(f"{args.method} standing starts: {total.starts}, left the track {len(total.off_starts)} "
          f"({total.off_events} off-track events), top speed {total.top_speed_mps:.3f} m/s, "
          f"{total.over_cap_ticks} ticks over the cap (+{CAP_TOLERANCE:.0%}), step median / "
          f"p99 {_step(total.step_ms)} ms (wall)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
