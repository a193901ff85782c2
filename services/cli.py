"""The ``racestack`` command: one entry point with a subcommand per job."""

from __future__ import annotations

import argparse
import logging
import sys
from collections.abc import Callable

from shared.config import ConfigError, load_config
from shared.track import TrackError

Handler = Callable[[argparse.Namespace], int]


def _cmd_laps(args: argparse.Namespace) -> int:
    """Race the planner against its own kinematic model and print lap times."""
    import numpy as np

    from services.planner.model import discretise, kinematic_bicycle, step_numpy
    from services.planner.planner import Planner
    from shared.track import load_track

    cfg = load_config(args.config)
    track = load_track(args.track or cfg.track.source)
    settings = cfg.planner.model_copy(update={"method": args.method or cfg.planner.method})
    planner = Planner(track, settings, cfg.curvature)
    F = discretise(kinematic_bicycle(settings.wheelbase_m), settings.dt_s, settings.integrator)
    x = np.array([*track.xy[0], track.heading_rad[0], 0.0])
    L, progress, s_last, t, lap_start, laps = track.length_m, 0.0, 0.0, 0.0, 0.0, 0
    print(f"{settings.method} on {track.name} ({L:.2f} m), kinematic model, {args.laps} laps")
    while laps < args.laps and t < 120.0 * args.laps:
        res = planner.step(*x[:3])
        x = step_numpy(F, x, np.array([res.command.speed_mps, res.command.steering_rad, 0.0]))
        progress += (res.s_m - s_last + L / 2) % L - L / 2
        s_last = res.s_m
        t += settings.dt_s
        if progress >= (laps + 1) * L:
            laps += 1
            print(f"lap {laps}: {t - lap_start:.2f} s")
            lap_start = t
    return 0 if laps == args.laps else 1


def build_parser() -> argparse.ArgumentParser:
    """The argument parser of every subcommand."""
    ap = argparse.ArgumentParser(prog="racestack", description="CiMPCC racing stack for F1TENTH")
    ap.add_argument("-v", "--verbose", action="store_true", help="debug logging")
    sub = ap.add_subparsers(dest="command", required=True)

    laps = sub.add_parser("laps", help="planner vs its own kinematic model, lap times")
    laps.add_argument("--config", help="TOML configuration file")
    laps.add_argument("--track", help="built-in name, folder or centreline file")
    laps.add_argument("--method", choices=["cimpcc", "mpcc"])
    laps.add_argument("--laps", type=int, default=2)
    laps.set_defaults(handler=_cmd_laps)

    demo = sub.add_parser("demo", help="the main job: race on the default track")
    demo.add_argument("--config", help="TOML configuration file")
    demo.add_argument("--laps", type=int, default=2)
    demo.set_defaults(handler=_cmd_laps, track=None, method=None)
    return ap


def main(argv: list[str] | None = None) -> int:
    """Run the ``racestack`` command; returns the exit code."""
    args = build_parser().parse_args(argv)
    logging.basicConfig(
        level=logging.DEBUG if args.verbose else logging.INFO,
        format="%(asctime)s %(levelname)s %(name)s: %(message)s",
    )
    handler: Handler = args.handler
    try:
        return handler(args)
    except (ConfigError, TrackError) as exc:
        print(f"racestack: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        return 130


if __name__ == "__main__":
    sys.exit(main())
