"""The planner service: ``state`` in, ``cmd/drive`` and ``planner/plan`` out, over Zenoh.

Event-driven: a worker thread blocks on ``state`` (``Bus.subscribe_channel``) and plans each
new ``State`` at once (low pose-to-command latency), at most
once per planner period (a state arriving sooner than ``MIN_PERIOD_FRACTION * dt_s`` after
the last solve is skipped, the next one is used). A state older than ``stale_state_s``
(by its ``source_stamp_s`` against this machine's wall clock) or none at all for that long
gives a braking command (speed 0), never a guess: the main thread checks every period.
Stamps are wall-clock seconds.

Order of one tick, shortest pose-to-command path first: solve, publish ``cmd/drive`` (from
inside ``Planner.step``, before its result record is assembled), pause
``command_yield_s`` so the command leaves, then publish ``planner/plan`` and prepare the
next tick's warm start (``Planner.prepare``).
"""

from __future__ import annotations

import argparse
import logging
import threading
import time
from collections.abc import Sequence

import numpy as np

from services.planner.methods import make_planner
from services.planner.planner import (
    BRAKING,
    RECOVERING,
    SOLVED,
    DriveCommand,
    Planner,
    SolveResult,
)
from services.planner.raceline import RacelinePlanner
from shared.bus import Bus, ChannelSubscription, DropReporter
from shared.config import RacestackConfig
from shared.messages import DriveCmd, LogEvent, Plan, State
from shared.service_shell import Worker, run_service
from shared.track import load_track

log = logging.getLogger(__name__)
SERVICE = "planner"
#: A new state is solved only once this share of the planner period has passed.
MIN_PERIOD_FRACTION = 0.8


def plan_message(res: SolveResult, stamp_s: float, source_stamp_s: float) -> Plan:
    """The ``planner/plan`` record of one solve result."""
    return Plan(
        stamp_s=stamp_s,
        horizon=np.ascontiguousarray(res.states, dtype=np.float64),
        inputs=np.ascontiguousarray(res.inputs, dtype=np.float64),
        beta=np.ascontiguousarray(res.beta, dtype=np.float64),
        status=res.status,
        solver_status=res.solver_status[:200],
        iterations=max(0, res.iterations),
        solve_time_ms=res.solve_time_s * 1e3,
        method=res.method,
        s_m=res.s_m,
        e_con_m=float(np.clip(res.e_con_m, -1e3, 1e3)),
        source_stamp_s=source_stamp_s,
        consecutive_failures=res.consecutive_failures,
    )


class PlannerShell:
    """Turns states into commands and plans; brakes on stale, invalid or missing state."""

    def __init__(self, planner: Planner | RacelinePlanner, bus: Bus) -> None:
        self.planner = planner
        self.period = planner.settings.dt_s
        self.stale_s = planner.settings.stale_state_s
        self.command_yield_s = planner.settings.command_yield_s
        self.cmd_pub = bus.publisher(bus.keys.drive_cmd, DriveCmd)
        self.plan_pub = bus.publisher(bus.keys.plan, Plan)
        self.log_pub = bus.publisher(bus.keys.events_log, LogEvent)
        self.last_solve = 0.0
        self.last_state = time.monotonic()
        self.braking = True
        self.recovering = False
        self.steering = 0.0
        self.cmd_stamp = 0.0  #: wall-clock stamp of the last command published [s]
        self._lock = threading.Lock()  # the state worker and the main thread's watchdog

    def say(self, level: str, text: str) -> None:
        """Log locally and on ``events/log``."""
        getattr(log, level)(text)
        self.log_pub.put(LogEvent(stamp_s=time.time(), level=level, source=SERVICE, text=text))

    def brake(self) -> None:
        """Command speed 0, steering held."""
        self.cmd_pub.put(DriveCmd(stamp_s=time.time(), speed_mps=0.0, steering_rad=self.steering))

    def publish_command(self, cmd: DriveCommand) -> None:
        """Publish the command of this tick (the planner calls it before assembling its
        result record, to keep that work off the pose-to-command path)."""
        self.cmd_stamp = time.time()
        self.steering = cmd.steering_rad
        self.cmd_pub.put(
            DriveCmd(stamp_s=self.cmd_stamp, speed_mps=cmd.speed_mps, steering_rad=self.steering)
        )

    def on_state(self, st: State) -> None:
        """Plan from one state: stale or invalid -> brake; else solve (rate-limited)."""
        self.last_state = time.monotonic()
        age = time.time() - st.source_stamp_s
        if age > self.stale_s or not st.valid:
            if not self.braking:
                self.say("warning", f"stale or invalid state (age {age * 1e3:.0f} ms): braking")
            self.braking = True
            self.brake()
            return
        if time.monotonic() - self.last_solve < MIN_PERIOD_FRACTION * self.period:
            return
        self.last_solve = time.monotonic()
        res = self.planner.step(st.x_m, st.y_m, st.yaw_rad, on_command=self.publish_command)
        if self.command_yield_s > 0.0:  # let the command go out before the rest of the work
            time.sleep(self.command_yield_s)
        self.plan_pub.put(plan_message(res, self.cmd_stamp, st.source_stamp_s))
        self.planner.prepare()  # the next tick's warm start, off the pose-to-command path
        if self.braking:
            self.say("info", "state fresh: racing")
            self.braking = False
        if res.status == RECOVERING:
            if not self.recovering:
                self.say("warning", f"car lost, {res.solver_status}")
            self.recovering = True
            return
        if self.recovering:
            self.say("info", "car back on the track: racing")
            self.recovering = False
        if res.status != SOLVED:
            level = "error" if res.status == BRAKING else "warning"
            self.say(level, f"solver {res.status}: {res.solver_status}")

    def consume(self, states: ChannelSubscription[State]) -> None:
        """The worker loop: plan from every state as it arrives, until the bus closes."""
        while (st := states.recv()) is not None:
            with self._lock:
                self.on_state(st)

    def on_silence(self) -> None:
        """The watchdog (every period): brake once no state came for stale_s."""
        with self._lock:
            self._check_silence()

    def _check_silence(self) -> None:
        if time.monotonic() - self.last_state > self.stale_s:
            if not self.braking:
                self.say("warning", f"no state for {self.stale_s * 1e3:.0f} ms: braking")
                self.braking = True
                self.planner.reset()
            self.brake()


def run(cfg: RacestackConfig, args: argparse.Namespace, stop: threading.Event) -> int:
    """The service body (see the module docstring)."""
    track = load_track(cfg.track.source)
    log.info(
        "building the %s planner on %s (compiled problem cached)", cfg.planner.method, track.name
    )
    planner = make_planner(track, cfg.planner, cfg.curvature, vehicle=cfg.simulator.vehicle)
    with Bus(cfg.bus, SERVICE) as bus:
        shell = PlannerShell(planner, bus)
        drops = DropReporter(bus, SERVICE, publisher=shell.log_pub)
        states = bus.subscribe_channel(bus.keys.state, State)
        worker = Worker(
            "planner-states",
            lambda: shell.consume(states),
            stop,
            faults=bus.faults,
            fault_key=bus.keys.plan,
        ).start()
        log.info("ready; waiting for %s", bus.keys.state)
        while not stop.wait(shell.period):
            drops.poll()
            shell.on_silence()
        log.info("stopping")
    worker.join(timeout_s=2.0)  # the closed bus ends it; re-raises if it crashed
    return 0


def main(argv: Sequence[str] | None = None) -> int:
    """``python -m services.planner``."""
    return run_service(SERVICE, argv, run, description=__doc__.splitlines()[0])
