"""The minimum-time lap driven in the project's simulator: replayed lap vs the OCP's time.

    .venv/bin/python -m benchmarks.mintime_replay                         # map416, 4.18 m/s
    .venv/bin/python -m benchmarks.mintime_replay --track paperlike
    .venv/bin/python -m benchmarks.mintime_replay --track paperlike --v-max 10
    .venv/bin/python -m benchmarks.mintime_replay --preset real_car_identified --rate 20 \
        --slip-fraction 0.8 --ellipse-fraction 0.95      # the identified car, its reserves

Solves (or loads from the cache) the minimum-time lap, feeds its line and speeds forward
into ``services.simulator.Simulator`` (default settings) with the small feedback of
``services.tools.bench.replay``, times flying laps with the bench's ``LapTimer`` and prints each
lap, its difference from the OCP's time, the off-track events and the largest distance
from the optimal line. Prints figures only.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from services.planner.mintime.ocp import MinTimeSettings
from services.planner.mintime.store import make_min_time_lap
from services.tools.bench.replay import ReplayOptions, replay_min_time
from shared.config import load_config
from shared.config.vehicle import VEHICLE_PRESETS, vehicle_preset
from shared.track import load_track

MAP416 = Path(__file__).resolve().parents[1].parent / "shared" / "tracks" / "map416"


def main(argv: list[str] | None = None) -> int:
    """Solve or load, replay, print."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--track", default=str(MAP416), help="track (default ../shared map416)")
    ap.add_argument("--v-max", type=float, default=4.18, help="top speed of the OCP [m/s]")
    ap.add_argument("--laps", type=int, default=3, help="flying laps to time")
    ap.add_argument("--preset", default=None, choices=sorted(VEHICLE_PRESETS),
                    help="the car (simulated and planned); default the configuration's")
    ap.add_argument("--rate", type=float, default=200.0, help="tracker rate [Hz] (200)")
    ap.add_argument("--slip-fraction", type=float, default=1.0,
                    help="the lap's Pacejka slip reserve (MinTimeSettings; 1: none)")
    ap.add_argument("--ellipse-fraction", type=float, default=1.0,
                    help="the lap's Pacejka friction-ellipse reserve (1: none)")
    args = ap.parse_args(argv)
    cfg = load_config(None)
    sim = cfg.simulator
    if args.preset is not None:
        sim = sim.model_copy(update={"vehicle": vehicle_preset(args.preset)})
    track = load_track(args.track)
    settings = MinTimeSettings(v_max_mps=args.v_max, slip_fraction=args.slip_fraction,
                               ellipse_fraction=args.ellipse_fraction)
    lap = make_min_time_lap(track, sim.vehicle, settings)
    opts = ReplayOptions(laps=args.laps, control_dt_s=1.0 / args.rate)
    res = replay_min_time(lap, track, sim, opts)
    print(f"{track.name} ({track.length_m:.2f} m), v_max {args.v_max:g} m/s: OCP lap "
          f"{lap.lap_time_s:.4f} s ({'cached' if lap.cache_hit else 'solved'})")
    for i, t in enumerate(res.lap_times_s, start=1):
        print(f"  replayed flying lap {i}: {t:.4f} s ({100 * (t / lap.lap_time_s - 1):+.3f} %)")
    print(f"  mean {100 * res.relative_error:+.3f} % against the OCP; off-track events "
          f"{res.off_track_events} while timed, {res.out_lap_off_track_events} in the out "
          f"lap; max distance from the optimal line {100 * res.max_abs_error_m:.1f} cm")
    return 0


if __name__ == "__main__":
    sys.exit(main())
