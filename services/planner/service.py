"""The planner service: ``state`` in, ``cmd/drive`` and ``planner/plan`` out, over Zenoh.

Event-driven: a worker thread blocks on ``state`` (``Bus.subscribe_channel``) and plans a
new ``State`` at once (low pose-to-command latency), at most once per planner period: the
solve is triggered by the first state of a NEW pose (``source_stamp_s`` newer than the one
last solved; the bridge publishes one the moment it fuses a pose) at least
``MIN_PERIOD_FRACTION * dt_s`` after the last solve, so each solve starts from the newest
pose and the solves keep to the pose's arrival. A state of no new pose (the bridge's
fallback prediction, or a fixed-rate bridge's repeat) is solved only once
``LATE_PERIOD_FRACTION * dt_s`` have passed without a new pose (a slow localiser keeps
the control going). A state older than ``stale_state_s``
(by its ``source_stamp_s`` against this machine's wall clock) gives a braking command
(speed 0) at once, never a guess. No state at all for ``stale_state_s`` is a DEADLINE, not
a poll: each state re-arms a ``BrakeDeadline`` and a second worker waits on a condition
with the time left as its timeout, so the brake goes out ``stale_state_s`` after the last
state (plus the wake-up's scheduling jitter), and again every planner period while no
state comes. Stamps are wall-clock seconds.

Order of one tick, shortest pose-to-command path first: solve, publish ``cmd/drive`` (from
inside ``Planner.step``, before its result record is assembled), pause
``command_yield_s`` so the command leaves, then publish ``planner/plan`` and prepare the
next tick's warm start (``Planner.prepare``). The shell is a ``shared.service.Service``: its
ports are declared in ``PlannerShell.PORTS``; the base's watchdog (main thread) publishes the
drop reports and watches both workers.

Opponents (issue #24): when the method plans around the other cars (the registry's
``MethodSpec.opponents``, and the planner has ``set_opponents``) the shell subscribes to its
car's ``opponents`` (the bridge's lidar tracker, one record per scan, newest kept) and hands
the planner the newest record's tracks before each solve
(``services.planner.opponents.estimates_from_record``: moved to now at their velocity; a
record older than ``[planner] opponent_stale_s`` gives none, malformed tracks are dropped;
both counted in ``opponent_counts``, a warning at most once per second, never a crash). No
record yet: the planner races alone. Other methods do not subscribe.
"""

from __future__ import annotations

import argparse
import logging
import threading
import time
from collections.abc import Callable, Sequence

import numpy as np

from services.planner.interface import DriveCommand, PlannerLike, SolveResult
from services.planner.mintime.requests import for_stack
from services.planner.mintime.store import MinTimeArtefactMissingError
from services.planner.opponents import OpponentEstimate, RecordCounts, estimates_from_record
from services.planner.registry import make_planner
from shared.bus import Bus, ChannelSubscription
from shared.config import RacestackConfig
from shared.config.methods import plans_with_opponents
from shared.keys import DRIVE_CMD, EVENTS_LOG, OPPONENTS, PLAN, STATE
from shared.messages import (
    DriveCmd,
    LogEvent,
    LogLevelName,
    Opponents,
    Plan,
    PlanStatusName,
    State,
)
from shared.service import Service, publishes, subscribes
from shared.service_shell import run_service
from shared.track import load_track

log = logging.getLogger(__name__)
#: A new state is solved only once this share of the planner period has passed.
MIN_PERIOD_FRACTION = 0.8
#: ... and a state of no new pose only once this share has passed.
LATE_PERIOD_FRACTION = 1.5


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


class BrakeDeadline:
    """When the planner must brake for want of a state: a deadline, as data (no clock).

    ``arm(now)`` at every state sets it to ``now + stale_s``; ``fire(now)`` once it is due
    says "brake now" and sets the next one ``repeat_s`` later (the brake is repeated while
    no state comes). Times are the caller's monotonic clock [s].
    """

    def __init__(self, stale_s: float, repeat_s: float, now: float) -> None:
        self.stale_s = stale_s
        self.repeat_s = repeat_s
        self.due_s = now + stale_s  #: when the next brake is due [s]
        self.armed_s = now  #: when the last state (or the start) armed it [s]

    def arm(self, now: float) -> None:
        """A state arrived at `now` [s]: the brake is due ``stale_s`` later."""
        self.armed_s = now
        self.due_s = now + self.stale_s

    def remaining(self, now: float) -> float:
        """Seconds until the brake is due (<= 0: due)."""
        return self.due_s - now

    def fire(self, now: float) -> bool:
        """True (and the next brake ``repeat_s`` later) if the brake is due at `now`."""
        if now < self.due_s:
            return False
        self.due_s = now + self.repeat_s
        return True


class PlannerShell(Service):
    """Turns states into commands and plans; brakes on stale, invalid or missing state."""

    NAME = "planner"
    PORTS = (
        subscribes(STATE, State),
        subscribes(OPPONENTS, Opponents),
        publishes(DRIVE_CMD, DriveCmd),
        publishes(PLAN, Plan),
        publishes(EVENTS_LOG, LogEvent),
    )

    def __init__(
        self,
        planner: PlannerLike,
        bus: Bus,
        *,
        clock: Callable[[], float] = time.monotonic,
        wall_clock: Callable[[], float] = time.time,
        opponents: bool | None = None,
    ) -> None:
        """`opponents`: subscribe to ``opponents`` and hand them to the planner (None: when
        the registry says ``planner.settings.method`` plans with opponents and the planner
        takes them)."""
        super().__init__(bus, period_s=planner.settings.dt_s, clock=clock, wall_clock=wall_clock)
        self.planner = planner
        self.period = planner.settings.dt_s
        self.stale_s = planner.settings.stale_state_s
        self.command_yield_s = planner.settings.command_yield_s
        self.cmd_pub = self.publisher(DRIVE_CMD)
        self.plan_pub = self.publisher(PLAN)
        self.states = self.subscribe_channel(STATE)
        self.last_solve = -float("inf")
        self.solved_source_s = -float("inf")  #: ``source_stamp_s`` of the last solve's state
        self.last_state = self.clock()
        self.last_state_wall_s = self.wall_clock()  #: wall time of the last state's arrival [s]
        self.deadline = BrakeDeadline(self.stale_s, self.period, self.last_state)
        self._deadline_cond = threading.Condition()
        self._closing = False
        #: (last state's arrival, brake's stamp) [s, wall clock] of each deadline brake
        self.deadline_brakes: list[tuple[float, float]] = []
        self.braking = True
        self.recovering = False
        self.steering = 0.0
        self.cmd_stamp = 0.0  #: wall-clock stamp of the last command published [s]
        self._lock = threading.Lock()  # the state worker and the deadline worker
        takes = callable(getattr(planner, "set_opponents", None))
        if opponents is None:
            opponents = takes and plans_with_opponents(planner.settings.method)
        #: the newest ``opponents`` record (None: the method plans without opponents)
        self.opponent_sub = self.subscribe(OPPONENTS) if opponents and takes else None
        self.opponent_stale_s = planner.settings.opponent_stale_s
        #: records converted, stale ones, tracks handed on, malformed tracks dropped
        self.opponent_counts = RecordCounts()
        self._opponent_record: Opponents | None = None
        self._opponents: list[OpponentEstimate] = []

    def brake(self) -> float:
        """Command speed 0, steering held; returns the command's stamp [s]."""
        stamp = self.wall_clock()
        self.cmd_pub.put(DriveCmd(stamp_s=stamp, speed_mps=0.0, steering_rad=self.steering))
        return stamp

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
        self.last_state_wall_s = self.wall_clock()
        with self._deadline_cond:
            self.deadline.arm(self.last_state)  # the brake deadline moves on
        age = self.wall_clock() - st.source_stamp_s
        if age > self.stale_s or not st.valid:
            if not self.braking:
                text = f"stale or invalid state (age {age * 1e3:.0f} ms): braking"
                self.say(LogLevelName.WARNING, text)
            self.braking = True
            self.brake()
            return
        now = self.clock()
        since = now - self.last_solve
        fresh = st.source_stamp_s > self.solved_source_s
        if since < (MIN_PERIOD_FRACTION if fresh else LATE_PERIOD_FRACTION) * self.period:
            return
        self.last_solve = now
        self.solved_source_s = st.source_stamp_s
        if self.opponent_sub is not None:
            self.hand_opponents()
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

    def hand_opponents(self) -> list[OpponentEstimate]:
        """Give the planner the newest ``opponents`` record's tracks, as of now (module
        docstring); returns what it was given. A record is converted once; one that grew
        stale since is dropped (counted once) and the planner gets none."""
        counts = self.opponent_counts
        before = (counts.stale, counts.bad_tracks)
        record = self.opponent_sub.take() if self.opponent_sub is not None else None
        now = self.wall_clock()
        if record is not None:
            self._opponent_record = record
            self._opponents = estimates_from_record(record, now, self.opponent_stale_s, counts)
        elif self._opponents and now - self._opponent_record.source_stamp_s > (
            self.opponent_stale_s
        ):
            counts.stale += 1  # no newer record since: the tracks went stale
            self._opponents = []
        if (counts.stale, counts.bad_tracks) != before:
            self.say(LogLevelName.WARNING,
                     f"opponents: {counts.stale} stale records, {counts.bad_tracks} malformed "
                     f"tracks dropped of {counts.records} records", limit="opponents")
        try:
            self.planner.set_opponents(self._opponents)  # type: ignore[attr-defined]
        except Exception as exc:  # a planner that refuses them races alone, never crashes
            detail = f"{type(exc).__name__}: {exc}"
            self.bus.faults.record(self.keys.opponents, "set_opponents", detail)
            return []
        return self._opponents

    def consume(self, states: ChannelSubscription[State]) -> None:
        """The worker loop: plan from every state as it arrives, until the bus closes."""
        while (st := states.recv()) is not None:
            with self._lock:
                self.on_state(st)

    def deadline_step(self, wait: Callable[[float], object] | None = None) -> bool:
        """One round of the deadline worker: wait until the brake is due (``wait(seconds)``,
        called holding the deadline's condition; default: wait on that condition, which
        ``close`` notifies; a state that re-armed the deadline meanwhile only makes the next
        round wait again), or brake if it is due; True when it braked."""
        with self._deadline_cond:
            left = self.deadline.remaining(self.clock())
            if left > 0.0:
                (wait or self._deadline_cond.wait)(left)
                return False
        with self._lock:  # not during a solve (a state came then, so it is not due)
            with self._deadline_cond:
                now = self.clock()
                if not self.deadline.fire(now):
                    return False  # a state re-armed it meanwhile
                last_wall = self.last_state_wall_s
            if not self.braking:
                self.say(LogLevelName.WARNING,
                         f"no state for {(now - self.last_state) * 1e3:.0f} ms "
                         f"(limit {self.stale_s * 1e3:.0f} ms): braking")
                self.braking = True
                self.planner.reset()
            stamp = self.brake()
            if len(self.deadline_brakes) < 10_000:
                self.deadline_brakes.append((last_wall, stamp))
        return True

    def watch_deadline(self) -> None:
        """The deadline worker: brake whenever the deadline passes, until ``close``."""
        while not self._closing:
            self.deadline_step()

    def serve(self, stop: threading.Event) -> int:
        """Plan from every state on a worker, brake on the deadline on another; this thread
        is the base's watchdog (reports, worker crashes)."""
        self.start_worker(
            "planner-states", lambda: self.consume(self.states), stop, fault_key=self.plan_pub.key
        )
        self.start_worker(
            "planner-deadline", self.watch_deadline, stop, fault_key=self.cmd_pub.key
        )
        log.info("ready; waiting for %s", self.states.key)
        return super().serve(stop)

    def close(self) -> None:
        """End the deadline worker (the closed bus ends the state worker)."""
        with self._deadline_cond:
            self._closing = True
            self._deadline_cond.notify_all()


def run(cfg: RacestackConfig, args: argparse.Namespace, stop: threading.Event) -> int:
    """The service body (see the module docstring). A minimum-time lap the method races on
    (``cimpcc-line``, a ``min_time`` raceline) is only read: when it is missing, the one
    line ``MinTimeArtefactMissingError`` (a ``TrackError``: exit code 2) names the
    ``racestack mintime`` command, with this configuration, that makes it."""
    track = load_track(cfg.track.source)
    log.info("building the %s planner on %s", cfg.planner.method, track.name)
    try:
        # the raceline's margin widened for the pose source's error (``for_stack``)
        settings = for_stack(cfg.planner, cfg.localization.pose_source)
        planner = make_planner(track, settings, cfg.curvature, vehicle=cfg.vehicle)
    except MinTimeArtefactMissingError as exc:  # made by the tools, never solved here
        raise exc.for_config(args.config, cfg.track.source) from None
    return PlannerShell.host(cfg.bus, stop, lambda bus: PlannerShell(planner, bus))


def main(argv: Sequence[str] | None = None) -> int:
    """``python -m services.planner``."""
    return run_service(PlannerShell.NAME, argv, run, description=__doc__.splitlines()[0])
