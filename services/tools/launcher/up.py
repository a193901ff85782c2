"""``racestack up``: the whole stack racing the simulator, one process per service.

The launcher hosts the Zenoh router (the hub on ``[bus] listen``), starts the simulator,
localization bridge, planner and telemetry as separate processes, waits until all are alive
(liveliness tokens), resets the simulator to the start line, races ``--laps`` laps (lap events
from the simulator), prints the lap table and each process's CPU use over the race
(``cpu.py``: the children and the launcher with its hub) and stops every child. Ctrl-C stops
them all too; a child that dies is reported and the rest are stopped.

The race starts as the bench's does: the car at rest just past the start line
(``shared.evaluation.results.OUT_LAP_START_M``), so it drives an **out lap** first (shown
as ``out lap`` in the progress, not timed, not in the lap table or its mean; its off-track
events are counted as the out lap's), then ``--laps`` flying laps.

``--track SPEC`` and ``--method NAME`` override ``[track] source`` and ``[planner] method``
(the same track specs as ``bench --track``, the methods of the registry): the launcher then
writes the configuration the services read to ``RUN/config.toml`` (the ``--config`` file's
tables with the two values replaced) and starts every service with it.

On the terminal (stdout): the ``rerun --connect ...`` line of ``--serve``; the progress of
the lap being driven and the planned speed (from ``planner/plan``: one line rewritten in
place on a TTY, a line every 10 s otherwise); the hints at the end name commands that run
as printed (``.venv/bin/rerun`` when ``.venv/bin`` is not on ``PATH``,
``shared.commands.runnable``). Logging: the launcher's own log lines (with timestamps) go
to ``RUN/logs/launcher.log`` beside the services' logs; the console gets only warnings and
errors, one short line each (``racestack up: warning: ...``); ``-v`` puts every line
(debug included, with timestamps) on stderr too (``console_logging``, ``run_log``). On
Ctrl-C the table of the laps finished so far, then the stack stops (exit code 130). It
cannot start (exit code 2, one line on stderr, nothing started, no empty run folder left)
when the run folder cannot be written, the hub's port or the ``--serve`` port is already in
use, or the services' ``[bus] connect`` endpoints are not where this hub listens: ``up`` is
the hub, so a hub nobody can reach is a configuration error to fix, not something to wait
for; so does a ``--track`` no loader takes (``--method`` takes only the registry's).

Before the planner process starts, ``up`` makes the minimum-time lap its method races on
(``services.planner.ensure_artefacts``: ``cimpcc-line``, a ``min_time`` raceline; a line
on stdout while IPOPT solves, once per track, car and settings): the planner process only
reads it. A lap with no solution on the track is one line and exit code 2 too.

Several cars (``--cars N`` or a ``[[cars]]`` list of two or more, issue #24): one simulator
for all, a bridge, planner and telemetry per car, one lap table with a column per car and
the incidents at the end (``multicar.py``).
"""

from __future__ import annotations

import logging
import sys
import time
import tomllib
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

from services.planner import MinTimeError, ensure_artefacts, for_stack
from services.tools.launcher.cpu import CpuMeter, format_cpu
from services.tools.launcher.supervisor import Supervisor, service_argv
from shared.bus import Bus, BusOpenError
from shared.commands import racestack_command, runnable
from shared.config import RacestackConfig, config_from_dict
from shared.config.toml_write import dumps as toml_dumps
from shared.evaluation import LapRecord, MethodRun, Trace, format_table, results_document
from shared.evaluation.figures import plural
from shared.keys import EVENTS_LOG, LAP, PLAN, SIM_CONTROL
from shared.messages import (
    InputCol,
    LapEvent,
    LapKindName,
    LogEvent,
    LogLevelName,
    Plan,
    SimActionName,
    SimControl,
)
from shared.net import loopback_port_taken
from shared.outdir import missing_dirs, remove_empty_dirs, writable_dir_problem
from shared.priority import apply_priority
from shared.roster import up_names
from shared.service import Service, publishes, subscribes
from shared.service_shell import HUB_WAIT_S, count_problem, endpoint_reachable, hub_endpoints
from shared.track import Track, load_track

log = logging.getLogger(__name__)

#: The services `racestack up` starts, in start order (the roster's ``up`` entries).
STACK = up_names()


class Launcher(Service):
    """The launcher on the bus: it hosts the router (the hub), watches laps, solve times and
    warnings, and resets the simulator at the start."""

    NAME = "launcher"
    LISTEN_DEFAULT = True
    MODE = "router"
    PORTS = (
        subscribes(LAP, LapEvent),
        subscribes(PLAN, Plan),
        subscribes(EVENTS_LOG, LogEvent),
        publishes(SIM_CONTROL, SimControl),
    )


@dataclass
class UpOptions:
    """What `racestack up` was asked to do."""

    config_path: str | None
    laps: int = 3
    services: tuple[str, ...] = STACK
    run_dir: Path | None = None
    start_timeout_s: float = 120.0
    lap_timeout_s: float = 120.0
    telemetry_args: list[str] = field(default_factory=list)
    #: the configuration the services are to read instead of `config_path` (the overrides
    #: of ``--track``/``--method``: ``up_config``), written to ``RUN/config.toml``; None:
    #: `config_path` as it is.
    config_data: dict | None = None
    verbose: bool = False
    #: ``--cars N``: race N cars (None: the configuration's ``[[cars]]``, else one car)
    cars: int | None = None
    #: True (``racestack up``): this process, hosting the hub, takes the hub's scheduling
    #: (``[processes.router]``, real time where permitted) just before the bus opens, so
    #: Zenoh's threads carry the critical path's messages at its priority (the services it
    #: starts set their own: one asking for none drops the real-time policy it inherited).
    #: False: the caller's process keeps its own (a test, a benchmark running ``up`` inside).
    hub_priority: bool = False


def up_config(
    config_path: str | None,
    track: str | None = None,
    method: str | None = None,
    cars: int | None = None,
) -> tuple[RacestackConfig, dict | None]:
    """The configuration of ``up`` with ``--track``/``--method``/``--cars`` applied: (the
    validated configuration, the TOML tables the services are to read, None without
    overrides and with one car). With several cars (``--cars N >= 2`` or a ``[[cars]]``
    list of two or more) the tables are always returned (each car's file is made of them).

    Raises:
        ConfigError: the file or a value is invalid (an unknown method among them).
    """
    from services.tools.launcher.multicar import cars_config
    from shared.config import load_config

    cfg = load_config(config_path)  # the file's own one-line errors first
    several = (cars is not None and cars >= 2) or (cars is None and len(cfg.cars) >= 2)
    if track is None and method is None and not several:
        return cfg, None
    data = tomllib.loads(Path(config_path).read_text(encoding="utf-8")) if config_path else {}
    if track is not None:
        data.setdefault("track", {})["source"] = track
    if method is not None:
        data.setdefault("planner", {})["method"] = method
    if several:
        data = cars_config(data, cars if cars is not None else len(cfg.cars))
    elif cars == 1:
        data.pop("cars", None)
    where = f"{config_path or 'the built-in configuration'} with --track/--method/--cars"
    return config_from_dict(data, where), data


def console_logging(verbose: bool = False, stream=None) -> logging.Handler:
    """Log to the console for ``up``: warnings and errors as one short line each
    (``racestack up: warning: TEXT``); with `verbose` every line, debug included, with time
    and logger. Replaces the root logger's handlers; returns the console handler."""
    handler = logging.StreamHandler(stream or sys.stderr)
    if verbose:
        handler.setLevel(logging.DEBUG)
        handler.setFormatter(logging.Formatter(LOG_FORMAT))
    else:
        handler.setLevel(logging.WARNING)
        handler.setFormatter(_ShortFormatter())
    root = logging.getLogger()
    for old in list(root.handlers):
        root.removeHandler(old)
    root.addHandler(handler)
    root.setLevel(logging.DEBUG if verbose else logging.INFO)
    return handler


def run_log(path: Path, verbose: bool = False) -> logging.Handler:
    """Add the run's log file (`path`, every line from INFO, DEBUG with `verbose`, with
    time and logger) to the root logger; returns the handler (remove and close it after)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    handler = logging.FileHandler(path, encoding="utf-8")
    handler.setLevel(logging.DEBUG if verbose else logging.INFO)
    handler.setFormatter(logging.Formatter(LOG_FORMAT))
    logging.getLogger().addHandler(handler)
    return handler


#: The long log format: the run's log file, the console with ``-v``.
LOG_FORMAT = "%(asctime)s %(levelname)s %(name)s: %(message)s"


class _ShortFormatter(logging.Formatter):
    """``racestack up: warning: TEXT`` (the exception's last line appended, if any)."""

    def format(self, record: logging.LogRecord) -> str:
        text = f"racestack up: {record.levelname.lower()}: {record.getMessage()}"
        if record.exc_info and record.exc_info[1] is not None:
            text += f" ({type(record.exc_info[1]).__name__}: {record.exc_info[1]})"
        return text


def run_up(cfg: RacestackConfig, opts: UpOptions, stop_requested=lambda: False) -> int:
    """Run the stack (see ``_run_up``); in the secure profile (``[bus] security = "mtls"``)
    first the certificates and the router (``services.tools.launcher.secure``)."""
    if cfg.bus.security != "mtls":
        return _run_up(cfg, opts, stop_requested)
    identities: tuple[str, ...] = opts.services
    if len(cfg.cars) >= 2:  # each car's services have their own certificate
        from services.tools.launcher.multicar import write_car_configs
        from shared.security.identities import car_identity

        names = [c.name for c in cfg.cars]
        identities = (*opts.services,
                      *(car_identity(s, c) for c in names for s in opts.services))
        if opts.run_dir is None:
            opts.run_dir = Path("runs") / time.strftime("%Y%m%d-%H%M%S")
        # the router reads the race's configuration: the rules of every car
        base, _ = write_car_configs(opts.config_data or {}, cfg, opts.run_dir)
        opts.config_path = str(base)
    from services.tools.launcher.secure import run_secure

    if opts.run_dir is None:
        opts.run_dir = Path("runs") / time.strftime("%Y%m%d-%H%M%S")
    run_dir = opts.run_dir
    return run_secure(cfg, opts.config_path, run_dir, identities,
                      lambda: _run_up(cfg, opts, stop_requested))


def _run_up(cfg: RacestackConfig, opts: UpOptions, stop_requested=lambda: False) -> int:
    """Run the stack; returns 0 when all laps were raced, 130 when interrupted (the table
    of the laps finished so far is printed), 2 when it cannot start (an unusable run
    folder, the hub port taken, a hub the services could not reach: one line on stderr,
    nothing started, no empty run folder left), else non-zero."""
    problem = count_problem("--laps", opts.laps)
    if problem:
        return _cannot_start(problem)
    serve = _serve_port(opts)
    if serve is not None and loopback_port_taken(serve):
        return _cannot_start(
            f"--serve {serve}: 127.0.0.1:{serve} is already in use (a Rerun viewer or another "
            "stack serving there?); choose another port, e.g. --serve 9877"
        )
    track = load_track(cfg.track.source)
    run_dir = opts.run_dir or Path("runs") / time.strftime("%Y%m%d-%H%M%S")
    created = missing_dirs(run_dir)
    problem = writable_dir_problem(run_dir)
    if problem:
        remove_empty_dirs(created)
        return _cannot_start(f"{problem}; give --run-dir a folder you can write")
    if "planner" in opts.services:  # the planner process only reads its minimum-time lap
        try:
            methods = {c.method or cfg.planner.method for c in cfg.cars} or {
                cfg.planner.method}
            planner = for_stack(cfg.planner, cfg.localization.pose_source)
            for method in sorted(methods):
                ensure_artefacts(method, track, planner, cfg.vehicle, progress=_say)
        except MinTimeError as exc:
            remove_empty_dirs(created)
            return _cannot_start(str(exc))
    if opts.hub_priority and cfg.bus.security != "mtls":  # mtls: services.router is the hub
        _take_hub_priority(cfg)
    try:
        bus = Launcher.open_bus(cfg.bus)
    except BusOpenError as exc:
        remove_empty_dirs(created)
        return _cannot_start(str(exc))
    with bus:
        unreachable = _unreachable_hub(cfg, opts.services)
        if unreachable:
            remove_empty_dirs(created)
            return _cannot_start(
                f"the services would connect to {', '.join(unreachable)}, where this hub "
                f"does not listen ({', '.join(bus.settings.listen)}): fix [bus] connect"
            )
        several = len(cfg.cars) >= 2
        if opts.config_data is not None and not several:  # --track/--method: this one
            path = run_dir / "config.toml"
            path.write_text(toml_dumps(opts.config_data, "racestack up: the configuration "
                                       "the services read (--track/--method applied)"),
                            encoding="utf-8")
            opts.config_path = str(path)
        who = (f"{len(cfg.cars)} cars ({', '.join(c.name for c in cfg.cars)})" if several
               else cfg.planner.method)
        print(
            f"racestack up: {who} on {track.name} ({track.length_m:.2f} m), "
            f"an out lap and {plural(opts.laps, 'timed lap')}; logs and telemetry in {run_dir}",
            flush=True,
        )
        file_log = run_log(run_dir / "logs" / "launcher.log", opts.verbose)
        try:
            if several:
                from services.tools.launcher.multicar import race_cars

                return race_cars(cfg, opts, bus, track, run_dir, stop_requested,
                                 opts.config_data or {"cars": [c.model_dump(exclude_none=True)
                                                               for c in cfg.cars]})
            return _race(cfg, opts, bus, track, run_dir, stop_requested)
        finally:
            logging.getLogger().removeHandler(file_log)
            file_log.close()


def _take_hub_priority(cfg: RacestackConfig) -> None:
    """Schedule this process as the hub (``[processes.router]``): after the minimum-time lap
    is made (a long solve at real-time priority would hold a CPU), before Zenoh starts its
    threads (they inherit it). What is not permitted is one log line (info where asked only
    where permitted), as in a service."""
    report = apply_priority(cfg.processes.router)
    for line in report.warnings:
        log.warning("[processes.router] %s", line)
    for line in report.notes:
        log.info("[processes.router] %s", line)


def _serve_port(opts: UpOptions) -> int | None:
    """The live-telemetry port telemetry is to serve on (``--serve PORT``), or None."""
    args = opts.telemetry_args
    if "--serve" in args and args.index("--serve") + 1 < len(args):
        try:
            return int(args[args.index("--serve") + 1])
        except ValueError:
            return None
    return None


def _say(line: str) -> None:
    """A progress line of ``up`` on stdout (before the stack starts)."""
    print(f"racestack up: {line}", flush=True)


def _cannot_start(line: str) -> int:
    """Say why ``up`` cannot start (one line on stderr); exit code 2."""
    print(f"racestack up: error: {line}", file=sys.stderr, flush=True)
    return 2


def _unreachable_hub(cfg: RacestackConfig, services: tuple[str, ...]) -> list[str]:
    """The hub endpoints some service of `services` would connect to where nothing
    listens (probed for up to ``HUB_WAIT_S``; empty when every service can reach one)."""
    wanted = {name: hub_endpoints(cfg.bus, name) for name in services}
    deadline = time.monotonic() + HUB_WAIT_S
    while True:
        bad = sorted({e for eps in wanted.values() if eps and not any(
            endpoint_reachable(x) for x in eps) for e in eps})
        if not bad or time.monotonic() >= deadline:
            return bad
        time.sleep(0.2)


def lap_progress_line(lap: int, laps: int, s_m: float, length_m: float, v_mps: float) -> str:
    """One progress line: ``lap 2/3: 12.3 of 32.8 m (38 %), 3.21 m/s``; lap 0 is the out lap
    (``out lap: 12.3 of 32.8 m (38 %), 3.21 m/s``).

    Args:
        lap: the lap being driven (1-based; 0: the out lap); laps: the laps asked for.
        s_m: progress along the centreline [m] (wrapped into the lap).
        length_m: the track length [m]; v_mps: the planned speed [m/s].
    """
    s = s_m % length_m if length_m > 0 else 0.0
    pct = 100.0 * s / length_m if length_m > 0 else 0.0
    where = "out lap" if lap == 0 else f"lap {lap}/{laps}"
    return f"{where}: {s:.1f} of {length_m:.1f} m ({pct:.0f} %), {v_mps:.2f} m/s"


class LiveLine:
    """Progress on the terminal: one line rewritten in place on a TTY (at most every
    `tty_period_s`), else a plain line every `period_s` [s] of wall time."""

    def __init__(self, stream=None, period_s: float = 10.0, tty_period_s: float = 0.25):
        self.stream = stream or sys.stdout
        self.tty = bool(getattr(self.stream, "isatty", lambda: False)())
        self.period_s = tty_period_s if self.tty else period_s
        self._last = time.monotonic()
        self._shown = False

    def show(self, text: str, now: float | None = None) -> None:
        """Show `text` if it is time to."""
        now = time.monotonic() if now is None else now
        if now - self._last < self.period_s:
            return
        self._last = now
        if self.tty:
            self.stream.write(f"\r\033[K{text}")
            self._shown = True
        else:
            self.stream.write(text + "\n")
        self.stream.flush()

    def clear(self) -> None:
        """End the in-place line before other output."""
        if self._shown:
            self.stream.write("\r\033[K")
            self.stream.flush()
            self._shown = False


@dataclass
class OffTrackTally:
    """The off-track events of a race as ``lap_events`` tells them: every excursion of the
    run (``off_track`` events) and those of the out lap (before timing ``start``ed), so the
    lap table's total agrees with its rows (a lap's own count is in its ``lap`` event)."""

    started: bool = False
    total: int = 0
    out_lap: int = 0

    def see(self, ev: LapEvent) -> None:
        """Count one lap event."""
        if ev.kind == LapKindName.START:
            self.started = True
        elif ev.kind == LapKindName.OFF_TRACK:
            self.total += 1
            if not self.started:
                self.out_lap += 1

    def run(self, method: str, laps: list[LapRecord], solve_ms: list[float], requested: int,
            extra: dict | None = None) -> MethodRun:
        """The race as a ``MethodRun`` with the whole run's off-track events: never fewer
        than the laps' own plus the out lap's."""
        in_laps = sum(lap.off_track_events for lap in laps)
        return MethodRun(
            method, laps, Trace(), solve_ms, 0, requested, extra=extra or {},
            run_off_track_events=max(self.total, in_laps + self.out_lap),
            out_lap_off_track_events=self.out_lap,
        )


def closing_hint(run_dir: Path) -> str:
    """The last line of ``up``: where the recording is and the commands, runnable as
    printed (``shared.commands``), that open it and draw its figures."""
    rrd = f"{run_dir}/telemetry.*.rrd"
    return (f"recording: {rrd} (open: {runnable('rerun')} {rrd}; figures: "
            f"{racestack_command()} report {run_dir})")


def _connect_line(log_path: Path | None, timeout_s: float) -> str | None:
    """The ``rerun --connect ...`` line telemetry wrote into its log (None if absent)."""
    deadline = time.monotonic() + timeout_s
    while log_path is not None:
        if log_path.exists():
            for line in log_path.read_text(errors="replace").splitlines():
                if "rerun --connect" in line:
                    # niced, as telemetry is: the viewer gives way to the critical path
                    return (f"watch live with: nice -n 10 {runnable('rerun')} --connect "
                            + line.split("rerun --connect", 1)[1].strip())
        if time.monotonic() >= deadline:
            return None
        time.sleep(0.1)
    return None


def _race(
    cfg: RacestackConfig,
    opts: UpOptions,
    bus: Bus,
    track: Track,
    run_dir: Path,
    stop_requested: Callable[[], bool],
) -> int:
    """Start the children, race the laps, print the table, stop everything."""
    laps: list[LapRecord] = []
    interrupted = False
    with Supervisor(log_dir=run_dir / "logs") as sup:
        node = Launcher(bus)
        lap_events = node.subscribe(LAP, queue_size=1000)
        tally = OffTrackTally()
        solve_ms: list[float] = []  # appended on the Zenoh thread (list.append is atomic)
        latest: dict[str, float] = {}  # the newest plan's progress and speed (Zenoh thread)

        def on_plan(p: Plan) -> None:
            solve_ms.append(p.solve_time_ms)
            latest["s_m"] = p.s_m
            latest["v_mps"] = float(p.inputs[0, InputCol.V_L]) if len(p.inputs) else 0.0

        node.subscribe(PLAN, on_plan)
        logs = node.subscribe(EVENTS_LOG, queue_size=1000)
        control = node.publisher(SIM_CONTROL)
        node.announce()
        children = {}
        for name in opts.services:
            extra = list(opts.telemetry_args) if name == "telemetry" else []
            if name == "telemetry":
                extra += ["--out", str(run_dir)]
            children[name] = sup.start(name, service_argv(name, opts.config_path, extra))
        print(f"waiting for {', '.join(opts.services)} ...", flush=True)
        ok = sup.wait_until(
            lambda: not bus.missing_alive(opts.services) or stop_requested(), opts.start_timeout_s
        )
        if stop_requested():
            print("interrupted", flush=True)
            return 130
        if not ok:
            return _report_failure(sup, bus, opts, "start")
        if "--serve" in opts.telemetry_args and "telemetry" in children:
            line = _connect_line(children["telemetry"].log_path, 5.0)
            print(line or "live telemetry: no rerun --connect line in "
                  f"{children['telemetry'].log_path} yet (see that log)", flush=True)
        print("all services alive: racing", flush=True)
        cpu = CpuMeter({n: c.pid for n, c in children.items()}, own="launcher (with the hub)")
        control.wait_matching(5.0)
        cpu.start()
        control.put(SimControl(stamp_s=time.time(), action=SimActionName.RESET))
        last_progress = time.monotonic()
        live = LiveLine()
        while len(laps) < opts.laps:
            if stop_requested():
                live.clear()
                print("interrupted: the laps finished so far, then stopping the stack",
                      flush=True)
                interrupted = True
                break
            dead = sup.dead()
            if dead:
                live.clear()
                return _report_failure(sup, bus, opts, "race")
            for ev in lap_events.drain():
                last_progress = time.monotonic()
                started = tally.started
                tally.see(ev)
                if ev.kind == LapKindName.START and not started:
                    live.clear()
                    print(f"out lap done: timing {plural(opts.laps, 'lap')}", flush=True)
                elif ev.kind == LapKindName.LAP and ev.lap_time_s is not None:
                    laps.append(
                        LapRecord(
                            ev.lap_time_s,
                            ev.mean_speed_mps or 0.0,
                            ev.off_track_events,
                            ev.max_abs_e_con_m or 0.0,
                        )
                    )
                    live.clear()
                    print(
                        f"lap {len(laps)}: {ev.lap_time_s:.3f} s, "
                        f"{ev.mean_speed_mps or 0.0:.2f} m/s, off-track {ev.off_track_events}, "
                        f"max |e_con| {ev.max_abs_e_con_m or 0.0:.3f} m",
                        flush=True,
                    )
                elif ev.kind == LapKindName.OFF_TRACK:
                    live.clear()
                    print(f"off track at lap {ev.lap}", flush=True)
            for msg in logs.drain():
                if msg.level in (LogLevelName.WARNING, LogLevelName.ERROR):
                    live.clear()
                    print(f"[{msg.source}] {msg.level}: {msg.text}", flush=True)
            if "s_m" in latest and len(laps) < opts.laps:
                lap_now = len(laps) + 1 if tally.started else 0
                live.show(lap_progress_line(lap_now, opts.laps, latest["s_m"],
                                            track.length_m, latest["v_mps"]))
            if time.monotonic() - last_progress > opts.lap_timeout_s:
                live.clear()
                print(f"no lap event for {opts.lap_timeout_s:.0f} s: giving up", flush=True)
                break
            time.sleep(0.05)
        live.clear()
        run = tally.run(cfg.planner.method, laps, list(solve_ms), opts.laps,
                        extra={"aborted": "interrupted"} if interrupted else {})
        doc = results_document(track.name, track.length_m, [run])
        if laps or not interrupted:
            print(format_table(doc), flush=True)
        else:
            print("no lap finished", flush=True)
        print(format_cpu(cpu.stop()), flush=True)
        print("stopping the stack", flush=True)
    if "telemetry" in opts.services:
        print(closing_hint(run_dir), flush=True)
    if interrupted:
        return 130
    return 0 if len(laps) >= opts.laps else 1


def _report_failure(sup: Supervisor, bus: Bus, opts: UpOptions, phase: str) -> int:
    """Say which child died (or who is missing) and where its log is."""
    for child in sup.dead():
        print(
            f"{child.name} (pid {child.pid}) exited with code {child.exit_code()} "
            f"during {phase}; log: {child.log_path}",
            file=sys.stderr,
            flush=True,
        )
        if child.log_path and child.log_path.exists():
            tail = child.log_path.read_text(errors="replace").splitlines()[-15:]
            print("\n".join(f"  | {line}" for line in tail), file=sys.stderr, flush=True)
    missing = bus.missing_alive(opts.services)
    if missing and not sup.dead():
        print(
            f"not alive after {opts.start_timeout_s:.0f} s: {', '.join(sorted(missing))}",
            file=sys.stderr,
            flush=True,
        )
    print("stopping the rest", file=sys.stderr, flush=True)
    return 3
