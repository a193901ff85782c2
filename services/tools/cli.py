"""The ``racestack`` command: one entry point with a subcommand per job.

racestack up [--laps 3]          the stack racing the simulator, one process per service
racestack demo                   the main job (same as ``up``)
racestack run SERVICE            one service alone (router, simulator, planner, ...)
racestack bench ...              the paper's lap-time experiment in one process
racestack mintime ...            the minimum-time lap of the car (the limit, the planner's lines)
racestack tune ...               search a method's parameters for the fastest clean laps
racestack report RUN             the lap table and figures of a recorded run
racestack sysid RUN --out F      the car identified from a recorded run (a [vehicle] overlay)
racestack sysid --drive --out D  an identification drive recorded in the simulator (for sysid)
racestack track --from-map M     a track (centreline CSV + PNG) from a SLAM map's yaml
racestack laps                   the planner against its own kinematic model
racestack certs --out DIR        the secure profile's local CA and per-service certificates
"""

from __future__ import annotations

import argparse
import logging
import runpy
import sys
from collections.abc import Callable

from shared import roster
from shared.config import ConfigError, load_config
from shared.config.methods import planner_methods
from shared.extras import missing_extra, require
from shared.service_shell import OneLineArgumentParser, positive_int
from shared.track import TRACK_SPEC_HELP, TrackError

Handler = Callable[[argparse.Namespace], int]
#: The help of every ``--config`` option.
CONFIG_HELP = "TOML configuration file (default: the built-in configuration)"
#: Services startable with ``racestack run NAME`` (each is ``python -m services.NAME``): the
#: roster's processes, in its order.
SERVICES = roster.names()


def _cmd_laps(args: argparse.Namespace) -> int:
    """Race the planner against its own kinematic model and print lap times."""
    from services.planner import ensure_artefacts, make_planner
    from services.tools.bench import ModelPlant, race
    from shared.track import load_track

    cfg = load_config(args.config)
    track = load_track(args.track or cfg.track.source)
    settings = cfg.planner.model_copy(update={"method": args.method or cfg.planner.method})
    ensure_artefacts(settings.method, track, settings, cfg.vehicle)
    planner = make_planner(track, settings, cfg.curvature, vehicle=cfg.vehicle)
    L = track.length_m
    print(f"{settings.method} on {track.name} ({L:.2f} m), kinematic model, {args.laps} laps")
    plant = ModelPlant.kinematic(
        track, settings, on_lap=lambda n, lap_s: print(f"lap {n}: {lap_s:.2f} s")
    )
    max_ticks = round(120.0 * args.laps / settings.dt_s)
    got = race(planner, plant, args.laps, max_ticks=max_ticks)
    if got.laps < args.laps:
        print(f"racestack laps: only {got.laps} of {args.laps} laps completed in "
              f"{max_ticks} planner ticks", file=sys.stderr)
        return 1
    return 0


def _cmd_up(args: argparse.Namespace) -> int:
    """Start the stack, race, print the lap table, stop everything."""
    import threading
    from pathlib import Path

    from services.tools.launcher import UpOptions, run_up, up_config
    from shared.service_shell import install_stop_handlers

    cfg, data = up_config(args.config, track=args.track, method=args.method, cars=args.cars)
    stop = threading.Event()
    install_stop_handlers(stop)
    run_dir = Path(args.run_dir) if args.run_dir else None
    opts = UpOptions(config_path=args.config, laps=args.laps, run_dir=run_dir,
                     config_data=data, verbose=args.verbose, cars=args.cars,
                     hub_priority=True)
    if args.serve is not None:
        opts.telemetry_args += ["--serve", str(args.serve)]
    return run_up(cfg, opts, stop_requested=stop.is_set)


def _cmd_run(args: argparse.Namespace) -> int:
    """Run one service in this process, as ``python -m services.NAME`` would (its own
    shell parses the rest of the line)."""
    argv = sys.argv
    sys.argv = [f"racestack run {args.service}", *args.rest]
    try:
        runpy.run_module(f"services.{args.service}", run_name="__main__")
    except SystemExit as exc:
        code = exc.code
        return code if isinstance(code, int) else (0 if code is None else 1)
    finally:
        sys.argv = argv
    return 0


def _cmd_bench(args: argparse.Namespace) -> int:
    if not args.no_figures:
        require("matplotlib")  # checked before the methods race, not after
    from services.tools.bench import main as bench_main

    return bench_main(args=args)


def _cmd_mintime(args: argparse.Namespace) -> int:
    if not args.no_figures:
        require("matplotlib")
    from services.tools.mintime import main as mintime_main

    return mintime_main(args=args)


def _cmd_tune(args: argparse.Namespace) -> int:
    require("optuna", "matplotlib")
    from services.tools.tune import main as tune_main

    return tune_main(args=args)


def _cmd_report(args: argparse.Namespace) -> int:
    from services.tools.report import main as report_main

    return int(report_main(args.rest))


def _cmd_sysid(args: argparse.Namespace) -> int:
    from services.tools.sysid import main as sysid_main

    return sysid_main(args=args)


def _cmd_track(args: argparse.Namespace) -> int:
    require("skimage", "scipy", "matplotlib")
    from services.tools.track import main as track_main

    return track_main(args=args)


def tcp_port(text: str) -> int:
    """An argparse ``type``: a TCP port number, 1..65535."""
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a port number") from None
    if not 1 <= value <= 65535:
        raise argparse.ArgumentTypeError(f"a port is 1..65535, got {value}")
    return value


def _plain(parser: argparse.ArgumentParser) -> None:
    """Remove RST double backticks from the help of `parser` and its subcommands (help
    texts come from docstrings)."""
    for text_attr in ("description", "epilog"):
        text = getattr(parser, text_attr)
        if text:
            setattr(parser, text_attr, text.replace("``", ""))
    for action in parser._actions:
        if action.help and action.help is not argparse.SUPPRESS:
            action.help = action.help.replace("``", "")
        if isinstance(action, argparse._SubParsersAction):
            for choice in action._choices_actions:
                if choice.help:
                    choice.help = choice.help.replace("``", "")
            for sub in action.choices.values():
                _plain(sub)


def _cmd_certs(args: argparse.Namespace) -> int:
    from services.tools.certs import certs_main

    return certs_main(args)


def build_parser() -> argparse.ArgumentParser:
    """The argument parser of every subcommand."""
    ap = OneLineArgumentParser(prog="racestack", description="CiMPCC racing stack for F1TENTH")
    ap.add_argument("-v", "--verbose", action="store_true",
                    help="debug logging (default: info; up: warnings, see up --help)")
    sub = ap.add_subparsers(dest="command", required=True)

    for name, help_text in (
        (
            "up",
            "race the stack against the simulator (one process per "
            "service), print the lap table, stop",
        ),
        ("demo", "the main job: same as `up`"),
    ):
        up = sub.add_parser(name, help=help_text)
        up.add_argument("--config", help=CONFIG_HELP)
        up.add_argument(
            "--laps",
            type=positive_int,
            default=3,
            help="timed laps to race, after an untimed out lap, before the table is printed "
            "and the stack stops (a whole number >= 1; default 3)",
        )
        up.add_argument(
            "--track", help=f"{TRACK_SPEC_HELP} (default: the config's [track] source)"
        )
        up.add_argument(
            "--method", choices=planner_methods(),
            help="the planner's method, one of the registry's (default: the configuration's "
            "[planner] method)",
        )
        up.add_argument(
            "--cars", type=positive_int, metavar="N",
            help="race N cars: one simulator, a bridge, planner and telemetry per car; the "
            "configuration's [[cars]] first, then cars of the same method at speed scale "
            "0.85, 1.5 m apart (default: the configuration's [[cars]], else one car)",
        )
        up.add_argument("--run-dir", help="where logs and telemetry go (default runs/<time>)")
        up.add_argument(
            "--serve",
            type=tcp_port,
            metavar="PORT",
            help="also serve live telemetry on 127.0.0.1:PORT for a Rerun viewer "
            "(the rerun --connect line is printed; default: not served)",
        )
        up.add_argument(
            "-v", "--verbose", action="store_true", dest="up_verbose",
            help="every log line (debug, with timestamps) on stderr too; default: warnings "
            "and errors only, the full log in RUN/logs/launcher.log",
        )
        up.set_defaults(handler=_cmd_up)

    run = sub.add_parser(
        "run",
        help="run one service alone",
        description="racestack run SERVICE [--config FILE] [service options]",
    )
    run.add_argument("service", choices=SERVICES, help="the service to run")
    run.add_argument("rest", nargs=argparse.REMAINDER, help="the service's own options")
    run.set_defaults(handler=_cmd_run)

    from services.tools.bench import build_parser as bench_parser

    bench = sub.add_parser("bench", help="the paper's lap-time experiment (in process)")
    bench_parser(bench)
    bench.set_defaults(handler=_cmd_bench)

    from services.tools.mintime import build_parser as mintime_parser

    mintime = sub.add_parser("mintime", help="minimum-time lap of the car (OCP)")
    mintime_parser(mintime)
    mintime.set_defaults(handler=_cmd_mintime)

    from services.tools.tune import build_parser as tune_parser

    tune = sub.add_parser("tune", help="search a method's parameters for the fastest clean laps")
    tune_parser(tune)
    tune.set_defaults(handler=_cmd_tune)

    report = sub.add_parser(  # no help of its own: --help reaches report's parser
        "report", help="lap table and figures of a recorded run (.rrd)", add_help=False
    )
    report.add_argument("rest", nargs=argparse.REMAINDER, help="RUN.rrd or run folder, options")
    report.set_defaults(handler=_cmd_report)

    from services.tools.sysid import build_parser as sysid_parser

    sysid = sub.add_parser("sysid", help="the car identified from a recorded run ([vehicle])")
    sysid_parser(sysid)
    sysid.set_defaults(handler=_cmd_sysid)

    from services.tools.track import build_parser as track_parser

    track = sub.add_parser(
        "track", help="a track (F1TENTH centreline CSV + PNG) from a SLAM occupancy map"
    )
    track_parser(track)
    track.set_defaults(handler=_cmd_track)

    from services.tools.certs import certs_parser

    certs = sub.add_parser("certs", help="the secure profile's local CA and certificates")
    certs_parser(certs)
    certs.set_defaults(handler=_cmd_certs)

    laps = sub.add_parser("laps", help="planner vs its own kinematic model, lap times")
    laps.add_argument("--config", help=CONFIG_HELP)
    laps.add_argument("--track", help=f"{TRACK_SPEC_HELP} (default: the config's)")
    laps.add_argument(
        "--method", choices=planner_methods(),
        help="a method of the registry (default: the configuration's [planner] method)",
    )
    laps.add_argument(
        "--laps", type=positive_int, default=2,
        help="laps to race (a whole number >= 1; default 2)"
    )
    laps.set_defaults(handler=_cmd_laps)
    _plain(ap)
    return ap


def main(argv: list[str] | None = None) -> int:
    """Run the ``racestack`` command; returns the exit code."""
    ap = build_parser()
    argv = sys.argv[1:] if argv is None else list(argv)
    args, unknown = ap.parse_known_args(argv)
    if args.command == "report":  # all after the word is report's own (--help included)
        args.rest = argv[argv.index("report") + 1 :]
    elif unknown:
        ap.parse_args(argv)  # the one-line error naming them
    if args.command in ("up", "demo"):
        from services.tools.launcher import console_logging

        args.verbose = args.verbose or args.up_verbose
        console_logging(args.verbose)
    elif args.command not in ("run", "report"):
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
    except ImportError as exc:  # an optional extra not installed: one line naming it
        extra = missing_extra(exc)
        if extra is None:
            raise
        print(f"racestack {args.command}: {extra}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        return 130


if __name__ == "__main__":
    sys.exit(main())
