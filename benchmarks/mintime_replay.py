"""The minimum-time lap driven in the project's simulator: replayed lap vs the OCP's time.

    .venv/bin/python -m benchmarks.mintime_replay                         # map416, 4.18 m/s
    .venv/bin/python -m benchmarks.mintime_replay --track paperlike
    .venv/bin/python -m benchmarks.mintime_replay --track paperlike --v-max 10

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
from shared.track import load_track

MAP416 = Path(__file__).resolve().parents[1].parent / "shared" / "tracks" / "map416"


def main(argv: list[str] | None = None) -> int:
    """Solve or load, replay, print."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--track", default=str(MAP416), help="track (default ../shared map416)")
    ap.add_argument("--v-max", type=float, default=4.18, help="top speed of the OCP [m/s]")
    ap.add_argument("--laps", type=int, default=3, help="flying laps to time")
    args = ap.parse_args(argv)
    cfg = load_config(None)
    track = load_track(args.track)
    lap = make_min_time_lap(track, cfg.simulator.vehicle, MinTimeSettings(v_max_mps=args.v_max))
    res = replay_min_time(lap, track, cfg.simulator, ReplayOptions(laps=args.laps))
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
