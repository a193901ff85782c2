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
next tick's warm start (``Planner.prepare``). The shell is a ``shared.service.Service``: its
ports are declared in ``PlannerShell.PORTS``; the base's watchdog calls ``tick`` (the
stale-state brake) every period.
"""

from __future__ import annotations

import argparse
import logging
import threading
import time
from collections.abc import Sequence

import numpy as np

from services.planner.interface import PlannerLike
from services.planner.methods import make_planner
from services.planner.planner import DriveCommand, SolveResult
from shared.bus import Bus, ChannelSubscription
from shared.config import RacestackConfig
from shared.keys import DRIVE_CMD, EVENTS_LOG, PLAN, STATE
from shared.messages import DriveCmd, LogEvent, LogLevelName, Plan, PlanStatusName, State
from shared.service import Service, publishes, subscribes
from shared.service_shell import run_service
from shared.track import load_track

log = logging.getLogger(__name__)
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


class PlannerShell(Service):
    """Turns states into commands and plans; brakes on stale, invalid or missing state."""

    NAME = "planner"
    PORTS = (
        subscribes(STATE, State),
        publishes(DRIVE_CMD, DriveCmd),
        publishes(PLAN, Plan),
        publishes(EVENTS_LOG, LogEvent),
    )

    def __init__(self, planner: PlannerLike, bus: Bus) -> None:
        super().__init__(bus, period_s=planner.settings.dt_s)
        self.planner = planner
        self.period = planner.settings.dt_s
        self.stale_s = planner.settings.stale_state_s
        self.command_yield_s = planner.settings.command_yield_s
        self.cmd_pub = self.publisher(DRIVE_CMD)
        self.plan_pub = self.publisher(PLAN)
        self.states = self.subscribe_channel(STATE)
        self.last_solve = 0.0
        self.last_state = self.clock()
        self.braking = True
        self.recovering = False
        self.steering = 0.0
        self.cmd_stamp = 0.0  #: wall-clock stamp of the last command published [s]
        self._lock = threading.Lock()  # the state worker and the main thread's watchdog

    def brake(self) -> None:
        """Command speed 0, steering held."""
        self.cmd_pub.put(
            DriveCmd(stamp_s=self.wall_clock(), speed_mps=0.0, steering_rad=self.steering)
        )

    def publish_command(self, cmd: DriveCommand) -> None:
        """Publish the command of this tick (the planner calls it before assembling its
        result record, to keep that work off the pose-to-command path)."""
        self.cmd_stamp = self.wall_clock()
        self.steering = cmd.steering_rad
        self.cmd_pub.put(
            DriveCmd(stamp_s=self.cmd_stamp, speed_mps=cmd.speed_mps, steering_rad=self.steering)
        )

    def on_state(self, st: State) -> None:
        """Plan from one state: stale or invalid -> brake; else solve (rate-limited)."""
        self.last_state = self.clock()
        age = self.wall_clock() - st.source_stamp_s
        if age > self.stale_s or not st.valid:
            if not self.braking:
                text = f"stale or invalid state (age {age * 1e3:.0f} ms): braking"
                self.say(LogLevelName.WARNING, text)
            self.braking = True
            self.brake()
            return
        if self.clock() - self.last_solve < MIN_PERIOD_FRACTION * self.period:
            return
        self.last_solve = self.clock()
        res = self.planner.step(st.x_m, st.y_m, st.yaw_rad, on_command=self.publish_command)
        if self.command_yield_s > 0.0:  # let the command go out before the rest of the work
            time.sleep(self.command_yield_s)
        self.plan_pub.put(plan_message(res, self.cmd_stamp, st.source_stamp_s))
        self.planner.prepare()  # the next tick's warm start, off the pose-to-command path
        if self.braking:
            self.say(LogLevelName.INFO, "state fresh: racing")
            self.braking = False
        if res.status == PlanStatusName.RECOVERING:
            if not self.recovering:
                self.say(LogLevelName.WARNING, f"car lost, {res.solver_status}")
            self.recovering = True
            return
        if self.recovering:
            self.say(LogLevelName.INFO, "car back on the track: racing")
            self.recovering = False
        if res.status != PlanStatusName.SOLVED:
            braking = res.status == PlanStatusName.BRAKING
            level = LogLevelName.ERROR if braking else LogLevelName.WARNING
            self.say(level, f"solver {res.status}: {res.solver_status}")

    def consume(self, states: ChannelSubscription[State]) -> None:
        """The worker loop: plan from every state as it arrives, until the bus closes."""
        while (st := states.recv()) is not None:
            with self._lock:
                self.on_state(st)

    def serve(self, stop: threading.Event) -> int:
        """Plan from every state on a worker; this thread is the watchdog (``tick``)."""
        self.start_worker(
            "planner-states", lambda: self.consume(self.states), stop, fault_key=self.plan_pub.key
        )
        log.info("ready; waiting for %s", self.states.key)
        return super().serve(stop)

    def tick(self) -> None:
        """The watchdog (every period): brake once no state came for stale_s."""
        with self._lock:
            self._check_silence()

    def _check_silence(self) -> None:
        if self.clock() - self.last_state > self.stale_s:
            if not self.braking:
                self.say(LogLevelName.WARNING, f"no state for {self.stale_s * 1e3:.0f} ms: braking")
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
    return PlannerShell.host(cfg.bus, stop, lambda bus: PlannerShell(planner, bus))


def main(argv: Sequence[str] | None = None) -> int:
    """``python -m services.planner``."""
    return run_service(PlannerShell.NAME, argv, run, description=__doc__.splitlines()[0])
