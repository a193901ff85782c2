"""``racestack up``: the whole stack racing the simulator, one process per service.

The launcher hosts the Zenoh router (the hub on ``[bus] listen``), starts the simulator,
localization bridge, planner and telemetry as separate processes, waits until all are alive
(liveliness tokens), resets the simulator to the start line, races ``--laps`` laps (lap events
from the simulator), prints the lap table and stops every child. Ctrl-C stops them all too; a
child that dies is reported and the rest are stopped.
"""

from __future__ import annotations

import logging
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

from services.launcher.supervisor import Supervisor, service_argv
from shared.bus import Bus
from shared.config import RacestackConfig
from shared.evaluation import LapRecord, MethodRun, Trace, format_table, results_document
from shared.keys import EVENTS_LOG, LAP, PLAN, SIM_CONTROL
from shared.messages import (
    LapEvent,
    LapKindName,
    LogEvent,
    LogLevelName,
    Plan,
    SimActionName,
    SimControl,
)
from shared.service import Service, publishes, subscribes
from shared.track import load_track

log = logging.getLogger(__name__)

#: The services `racestack up` starts, in start order.
STACK = ("simulator", "localization_bridge", "planner", "telemetry")


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


def run_up(cfg: RacestackConfig, opts: UpOptions, stop_requested=lambda: False) -> int:
    """Run the stack; returns 0 when all laps were raced, else non-zero."""
    track = load_track(cfg.track.source)
    run_dir = opts.run_dir or Path("runs") / time.strftime("%Y%m%d-%H%M%S")
    run_dir.mkdir(parents=True, exist_ok=True)
    print(
        f"racestack up: {cfg.planner.method} on {track.name} ({track.length_m:.2f} m), "
        f"{opts.laps} laps; logs and telemetry in {run_dir}",
        flush=True,
    )
    laps: list[LapRecord] = []
    with (
        Launcher.open_bus(cfg.bus) as bus,
        Supervisor(log_dir=run_dir / "logs") as sup,
    ):
        node = Launcher(bus)
        lap_events = node.subscribe(LAP, queue_size=1000)
        solve_ms: list[float] = []  # appended on the Zenoh thread (list.append is atomic)
        node.subscribe(PLAN, lambda p: solve_ms.append(p.solve_time_ms))
        logs = node.subscribe(EVENTS_LOG, queue_size=1000)
        control = node.publisher(SIM_CONTROL)
        node.announce()
        for name in opts.services:
            extra = list(opts.telemetry_args) if name == "telemetry" else []
            if name == "telemetry":
                extra += ["--out", str(run_dir)]
            sup.start(name, service_argv(name, opts.config_path, extra))
        print(f"waiting for {', '.join(opts.services)} ...", flush=True)
        ok = sup.wait_until(
            lambda: not bus.missing_alive(opts.services) or stop_requested(), opts.start_timeout_s
        )
        if stop_requested():
            print("interrupted", flush=True)
            return 130
        if not ok:
            return _report_failure(sup, bus, opts, "start")
        print("all services alive: racing", flush=True)
        control.wait_matching(5.0)
        control.put(SimControl(stamp_s=time.time(), action=SimActionName.RESET))
        last_progress = time.monotonic()
        while len(laps) < opts.laps:
            if stop_requested():
                print("interrupted: stopping the stack", flush=True)
                return 130
            dead = sup.dead()
            if dead:
                return _report_failure(sup, bus, opts, "race")
            for ev in lap_events.drain():
                last_progress = time.monotonic()
                if ev.kind == LapKindName.LAP and ev.lap_time_s is not None:
                    laps.append(
                        LapRecord(
                            ev.lap_time_s,
                            ev.mean_speed_mps or 0.0,
                            ev.off_track_events,
                            ev.max_abs_e_con_m or 0.0,
                        )
                    )
                    print(
                        f"lap {len(laps)}: {ev.lap_time_s:.3f} s, "
                        f"{ev.mean_speed_mps or 0.0:.2f} m/s, off-track {ev.off_track_events}, "
                        f"max |e_con| {ev.max_abs_e_con_m or 0.0:.3f} m",
                        flush=True,
                    )
                elif ev.kind == LapKindName.OFF_TRACK:
                    print(f"off track at lap {ev.lap}", flush=True)
            for msg in logs.drain():
                if msg.level in (LogLevelName.WARNING, LogLevelName.ERROR):
                    print(f"[{msg.source}] {msg.level}: {msg.text}", flush=True)
            if time.monotonic() - last_progress > opts.lap_timeout_s:
                print(f"no lap event for {opts.lap_timeout_s:.0f} s: giving up", flush=True)
                break
            time.sleep(0.05)
        print("stopping the stack", flush=True)
    run = MethodRun(cfg.planner.method, laps, Trace(), list(solve_ms), 0, opts.laps)
    doc = results_document(track.name, track.length_m, [run])
    print(format_table(doc), flush=True)
    if "telemetry" in opts.services:
        print(f"recording: {run_dir / 'telemetry.rrd'} (open: rerun {run_dir / 'telemetry.rrd'};"
              f" figures: racestack report {run_dir})", flush=True)
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
