"""The simulator service: the vehicle stand-in on Zenoh, in real time.

Consumes ``cmd/drive`` (and ``sim/control``: reset / pause / resume); publishes what the real
car's drivers would: ``vehicle/pose`` (rear axle, as a lidar localiser gives it, with its
rate and latency), ``vehicle/imu``, ``vehicle/odom``, ``vehicle/scan`` (2D lidar on the
track's occupancy map), plus ``sim/truth`` and ``lap`` events for evaluation. Swapping the
simulator for the car is configuration: the same keys come from the real drivers.

Stamps are wall-clock seconds of the simulated capture instant (the simulation runs in real
time, anchored to the wall clock at start), so other services judge message age as on the
car. Without fresh commands for ``command_timeout_s`` the car brakes, like a VESC timeout.

Real time by design (issue 25). Each loop iteration steps the car and computes that step's
sensor readings (the lidar scan, its costliest part, included) *before* it waits for the
wall clock to reach the step's time, so the work uses the step's slack and the messages
leave at their instant, not a scan's cost later. When the machine still cannot keep up
(the process waited for a core), the world slows instead of jumping: a loop more than
``MAX_LAG_S`` behind real time is not caught up by a burst of old-stamped messages, nor
later by a skip; the clocks are re-anchored by the excess at once, so the simulated world
(the car, every sensor, the lap timer) lost that much time against the wall clock and goes
on step by step from where it was, its stamps never more than ``MAX_LAG_S`` old. Each is
counted (``slowdowns``, ``slowed_s``; the 1st, 10th, 100th ... said in the log) and the
world's rate (simulated / wall time) is in the closing line.

Nothing it publishes is outside its own contract, and it never dies of its own output:

* angles are wrapped into the contract's range where the records are made (yaw and slip
  into [-pi, pi]); every record is built by ``TypedPublisher.try_put``, so one that still
  fails validation is not sent but counted in ``bus.faults`` (logged once per burst,
  reported on ``events/log`` by the ``DropReporter``) and the loop goes on;
* the car's state is checked after every step (``state_fault``): a non-finite state (the
  core raises ``FloatingPointError``) or a speed, yaw rate, steering angle or position
  beyond the contract's limits resets the car to the start line, counted under
  ``STATE_FAULT_KEY`` and said on ``events/log`` (at most once per
  ``FAULT_REPORT_INTERVAL_S``, with the number of resets since the last line). A slip
  angle outside the core's canonical [-pi/2, pi/2] is counted (reason ``slip_not_canonical``)
  and published wrapped; it is the same velocity direction, so the car goes on.

Every time it puts the car elsewhere (a ``sim/control`` reset, a fault reset, the
off-track marshal below) it says so on ``vehicle/teleport`` (``Teleport``: the new rear-axle
pose and speed, stamped at the instant of the teleport), so a pose filter starts again
there at once instead of gating the jump; its sensors drop what they captured before.

When the car's footprint leaves the track, ``[simulator] off_track_policy`` decides:
``"continue"`` (default) keeps driving; ``"stop"`` ignores drive commands from then on, so
the command timeout brakes the car to rest like a VESC whose commands stopped, until a
``sim/control`` "reset" or "resume"; ``"reset_to_centreline"`` puts the car back on the
centreline at its projection, at rest, heading along the track (a marshal). Each is counted
(``off_track_actions``) and said on ``events/log``.

Several cars (``[[cars]]`` with two or more entries, issue #24): this ONE process integrates
them all. The car of ``[bus] car`` is this service; each other car is a ``SimulatorService``
of its own on a view of the same bus with that car's keys (``fleet.CarView``): its own
commands, ``sim/control``, pose, IMU, odometry, scan, truth, laps and teleports on
``racestack/<car>/...``; this service's loop steps them all together, one integration step
each. After every step the footprints are checked pair by pair
(``shared.vehicle.contact``): an episode of contact is counted once (``ContactMonitor``) and
said on ``events/log`` as a warning (``shared.vehicle.incidents``: who hit whom, when, how deep,
how fast); overlapping cars are pushed apart and, when they approach, exchange momentum
along the normal with restitution and lose speed (``collision.respond``;
``[simulator] contact_restitution``, ``contact_speed_loss``). Each car's lidar sees the
others' footprints (``cast_on_boxes``). A car's ``speed_scale`` multiplies its speed
commands; its start is ``start_gap_m`` behind the car before it (``shared.config.cars``).
A pause or resume of the first car holds or releases the whole simulation (they share one
clock); the other cars' resets are their own.

The shell is a ``shared.service.Service`` (ports in ``SimulatorService.PORTS``); its main
thread is the real-time loop (``serve``), which also polls the drop and fault reports.
"""

from __future__ import annotations

import argparse
import dataclasses
import logging
import math
import threading
import time
from collections.abc import Callable

import numpy as np

from services.simulator import LapEvent as TimerEvent
from services.simulator import LapTimer, SensorSuite, Simulator, StepResult
from services.simulator.collision import ContactParams, Motion, respond
from services.simulator.fleet import CarView
from services.simulator.laps import centreline_pose
from services.simulator.limits import state_fault
from services.simulator.sensors import SensorReadings
from services.simulator.state import Pose2D, rear_axle
from services.simulator.vesc_actuation import VescActuation
from shared.angles import wrap_angle
from shared.bus import Bus, LatestSlot
from shared.config import RacestackConfig
from shared.config.cars import start_positions
from shared.evaluation.results import OUT_LAP_START_M
from shared.keys import (
    DRIVE_CMD,
    EVENTS_LOG,
    IMU,
    LAP,
    ODOM,
    POSE,
    SCAN,
    SIM_CONTROL,
    SIM_TRUTH,
    TELEPORT,
)
from shared.messages import (
    DriveCmd,
    Imu,
    LapEvent,
    LapKindName,
    LogEvent,
    LogLevelName,
    Odom,
    Pose,
    Scan,
    SimActionName,
    SimControl,
    SimTruth,
    Teleport,
)
from shared.service import Service, publishes, subscribes
from shared.track import Track, load_track, occupancy_for
from shared.track.occupancy import OccupancyGrid
from shared.vehicle.contact import ContactMonitor
from shared.vehicle.incidents import IncidentRecord, incident_line

#: With -v, the simulator's state is logged every this long of simulated time [s].
DEBUG_PERIOD_S = 2.0
#: Rate of ``sim/truth`` [Hz].
TRUTH_RATE_HZ = 50.0
#: Where the car starts: this far along from the start line [m]: past it, as in the bench,
#: so the car drives an out lap before timing starts and lap 1 is a flying lap.
START_OFFSET_M = OUT_LAP_START_M
#: A loop iteration later than this behind real time is counted as an overrun [s].
OVERRUN_S = 0.02
#: Further behind real time than this [s], the world slows: the clocks are re-anchored by
#: the excess, so the stamps are at most this old and the car's motion stays integrated
#: step by step (the world then ran slower than real time; module docstring). Two steps:
#: a late wake-up is caught up, a longer wait for a core is not burst out with old stamps
#: (each of them brings the planner's 100 ms stale-state limit that much closer).
MAX_LAG_S = 0.02
#: Key under which faults of the car's state are counted in ``bus.faults`` (not a bus key).
STATE_FAULT_KEY = "car state"
#: Shortest interval between two ``events/log`` lines about fault resets [s].
FAULT_REPORT_INTERVAL_S = 1.0
_HALF_PI = 0.5 * math.pi
#: Slack on the core's canonical slip range [rad] (its own rounding).
_SLIP_SLACK_RAD = 1e-9


class SimulatorService(Service):
    """The real-time loop; the bus is injected so the loop stays testable without Zenoh."""

    NAME = "simulator"
    PORTS = (
        subscribes(DRIVE_CMD, DriveCmd),
        subscribes(SIM_CONTROL, SimControl),
        publishes(POSE, Pose),
        publishes(IMU, Imu),
        publishes(ODOM, Odom),
        publishes(SCAN, Scan),
        publishes(SIM_TRUTH, SimTruth),
        publishes(LAP, LapEvent),
        publishes(TELEPORT, Teleport),
        publishes(EVENTS_LOG, LogEvent),
    )
    EVENT_INTERVAL_S = FAULT_REPORT_INTERVAL_S

    def __init__(
        self,
        cfg: RacestackConfig,
        bus: Bus,
        track: Track,
        *,
        clock: Callable[[], float] = time.monotonic,
        wall_clock: Callable[[], float] = time.time,
        start_s_m: float = START_OFFSET_M,
        speed_scale: float = 1.0,
        grid: OccupancyGrid | None = None,
    ) -> None:
        super().__init__(bus, clock=clock, wall_clock=wall_clock)
        self.cfg = cfg
        self.track = track
        self.start_s_m = float(start_s_m)  #: where a reset puts the car (arc length [m])
        self.speed_scale = float(speed_scale)  #: its speed commands are scaled by this
        #: the other cars this service's loop steps ([[cars]]; empty: one car)
        self.others: list[SimulatorService] = []
        self.contacts: ContactMonitor | None = None
        self.impacts = 0  #: contacts with an impact (approaching along the normal)
        s = cfg.simulator
        self.sim = Simulator(s)
        if grid is None and s.lidar.rate_hz > 0:
            grid = occupancy_for(track)
        self.grid = grid if s.lidar.rate_hz > 0 else None  #: the lidar's map (shared by cars)
        self.sensors = SensorSuite(s, self.grid)
        veh = s.vehicle
        self.timer = LapTimer(track, width_m=veh.width_m, length_m=veh.length_m)
        self.pub_pose = self.publisher(POSE)
        self.pub_imu = self.publisher(IMU)
        self.pub_odom = self.publisher(ODOM)
        self.pub_scan = self.publisher(SCAN)
        self.pub_truth = self.publisher(SIM_TRUTH)
        self.pub_lap = self.publisher(LAP)
        self.pub_teleport = self.publisher(TELEPORT)
        self.commands: LatestSlot[DriveCmd] = LatestSlot()
        self.controls = self.subscribe(SIM_CONTROL, queue_size=16)
        #: actuation = "fake_vesc": commands come from the vesc_driver's serial frames
        self.vesc: VescActuation | None = None
        if s.actuation == "fake_vesc":
            self.vesc = VescActuation(s.fake_vesc_link, cfg.vesc)
        #: the vesc_driver polls the fake VESC's IMU: it publishes vehicle/imu, not us
        self.vesc_imu = self.vesc is not None and cfg.vesc.poll_imu_rate_hz > 0
        if self.vesc is None:
            self.subscribe(DRIVE_CMD, self.commands.put)
        #: faults of its own: invalid records (by key) and car-state faults (STATE_FAULT_KEY)
        self.faults = bus.faults
        self.t0_wall = self.wall_clock()
        self.paused = False
        self.stopped = False  #: off_track_policy "stop" acted: commands are ignored
        self.overruns = 0
        self.slowdowns = 0  #: times it was more than MAX_LAG_S behind and the world slowed
        self.slowed_s = 0.0  #: world time lost against the wall clock in all [s]
        self.longest_slowdown_s = 0.0  #: the largest single one [s]
        self.fault_resets = 0  #: resets because the car's state left the contract
        self.off_track_actions = 0  #: off-track events the policy acted on (or let pass)
        self.teleports = 0  #: times the car was put elsewhere (each said on vehicle/teleport)
        self._next_truth = 0.0
        self.reset()

    @classmethod
    def create(cls, cfg: RacestackConfig, args: argparse.Namespace, bus: Bus) -> SimulatorService:
        """The simulator on the configured track."""
        log = logging.getLogger(cls.__module__)
        log.info("loading the track %s", cfg.track.source)
        track = load_track(cfg.track.source)
        log.info("track %s: %.2f m; building the car and its sensors (lidar at %g Hz)",
                 track.name, track.length_m, cfg.simulator.lidar.rate_hz)
        if cfg.simulates_another_car:
            log.info("racing [simulator.vehicle] (preset %s), not the planners' [vehicle] "
                     "(preset %s): a model mismatch", cfg.simulator.vehicle.preset,
                     cfg.vehicle.preset)
        if len(cfg.cars) < 2:
            return cls(cfg, bus, track)
        return cls.fleet(cfg, bus, track)

    @classmethod
    def fleet(cls, cfg: RacestackConfig, bus: Bus, track: Track, **kw: object
              ) -> SimulatorService:
        """The simulator of every car of ``[[cars]]``: the service of ``[bus] car`` (it
        must be in the list) with the others added (module docstring).

        Raises:
            ValueError: ``[bus] car`` is not in ``[[cars]]``, or ``actuation = "fake_vesc"``
                (one fake VESC, one car).
        """
        names = [c.name for c in cfg.cars]
        if cfg.bus.car not in names:
            raise ValueError(f"[bus] car {cfg.bus.car!r} is not in [[cars]] ({names})")
        if cfg.simulator.actuation != "bus":
            raise ValueError('several cars need [simulator] actuation = "bus"')
        starts = start_positions(cfg.cars, START_OFFSET_M)
        own = names.index(cfg.bus.car)
        me = cfg.cars[own]
        svc = cls(cfg, bus, track, start_s_m=starts[own], speed_scale=me.speed_scale,
                  **kw)  # type: ignore[arg-type]
        kw["grid"] = svc.grid  # one map for every car's lidar
        for car, s0 in zip(cfg.cars, starts, strict=True):
            if car.name != cfg.bus.car:
                view: Bus = CarView(bus, car.name)  # type: ignore[assignment]
                other = cls(cfg, view, track, start_s_m=s0, speed_scale=car.speed_scale,
                            **kw)  # type: ignore[arg-type]
                other.reporter = None  # the counters are shared: this service reports them
                svc.add_car(other)
        return svc

    def add_car(self, other: SimulatorService) -> None:
        """Step `other` (a car on its own keys) in this service's loop, with contacts."""
        self.others.append(other)
        veh = self.cfg.simulator.vehicle
        self.contacts = ContactMonitor(1 + len(self.others), veh.length_m, veh.width_m)
        self.log.info("%d cars: %s", 1 + len(self.others),
                      ", ".join(c.keys.car for c in (self, *self.others)))

    def stamp(self, t_sim: float) -> float:
        """Wall-clock stamp [s] of simulation time `t_sim`."""
        return self.t0_wall + t_sim

    def teleport(self, pose: Pose2D) -> None:
        """Put the car at rest at CoG `pose` now, restart the sensors, and say so on
        ``vehicle/teleport`` (the rear-axle pose, as the pose sensor reports it)."""
        t = self.sim.t_s
        self.sim.reset(pose, speed_mps=0.0, t_s=t)
        self.sensors.reset()
        self.teleports += 1
        st = self.sim.state
        x, y, yaw = rear_axle(st.x_m, st.y_m, st.yaw_rad, self.cfg.simulator.vehicle.lr_m)
        self.pub_teleport.try_put(
            stamp_s=self.stamp(t), x_m=x, y_m=y, yaw_rad=wrap_angle(yaw), speed_mps=0.0
        )

    def reset(self) -> None:
        """Put the car at rest just behind the start line (and release an off-track stop)."""
        t = self.sim.t_s
        self.teleport(centreline_pose(self.track, self.start_s_m))
        self.timer.reset()
        self.stopped = False
        st = self.sim.state
        self.timer.update(t, st.x_m, st.y_m, st.yaw_rad, st.v_mps)
        if self.start_s_m < 0.0:  # behind the line: an out lap over it first, as the leader
            self.timer.count_from_behind_line()
        self.log.info("car reset to the start line")

    def fault_reset(self, reason: str, detail: str) -> None:
        """The car's state left the contract: count it, reset the car, say so (rate-limited)."""
        self.faults.record(STATE_FAULT_KEY, reason, detail)
        self.fault_resets += 1
        self.reset()
        self.say(
            LogLevelName.ERROR,
            f"car state left the contract ({detail}): car reset to the start line "
            f"(fault reset {self.fault_resets})",
            limit="fault_reset",
        )

    def on_off_track(self, ev: TimerEvent) -> None:
        """The footprint left the track: apply ``[simulator] off_track_policy`` and say so."""
        self.off_track_actions += 1
        policy = self.cfg.simulator.off_track_policy
        where = f"off track at s = {ev.s_m:.1f} m"
        if policy == "stop":
            self.stopped = True
            self.say(
                LogLevelName.WARNING,
                f"{where}: car stopped (off-track stop {self.off_track_actions}); drive "
                "commands are ignored until sim/control reset or resume",
            )
        elif policy == "reset_to_centreline":
            self.teleport(centreline_pose(self.track, ev.s_m))
            self.say(
                LogLevelName.WARNING,
                f"{where}: car put back on the centreline at rest "
                f"(off-track reset {self.off_track_actions})",
            )
        else:
            self.say(LogLevelName.WARNING, where)

    def advance(self, h: float) -> StepResult | None:
        """Step the car by `h` [s] and check its state; None when it had to be reset.

        A non-finite state (``FloatingPointError`` from the core) or a state beyond the
        contract (``state_fault``) resets the car to the start line (``fault_reset``).
        """
        try:
            res = self.sim.step(None, h)
        except FloatingPointError as exc:
            self.fault_reset("not_finite", str(exc)[:300])
            return None
        fault = state_fault(res.state)
        if fault is not None:
            self.fault_reset(*fault)
            return None
        return res

    def handle_inputs(self) -> None:
        """Apply the newest drive command and any control requests."""
        if self.vesc is not None:
            st = self.sim.state
            cmd = self.vesc.update(st.v_mps * math.cos(st.slip_rad))
        else:
            cmd = self.commands.take()
        if cmd is not None and not (self.paused or self.stopped):
            if not getattr(self, "_said_first_cmd", False):
                self._said_first_cmd = True
                self.log.info("first drive command at t = %.2f s: %.2f m/s, %.3f rad",
                              self.sim.t_s, cmd.speed_mps, cmd.steering_rad)
            speed = cmd.speed_mps if self.speed_scale == 1.0 else cmd.speed_mps * self.speed_scale
            self.sim.set_command(speed, cmd.steering_rad, self.sim.t_s)
        for ctl in self.controls.drain():
            if ctl.action == SimActionName.RESET:
                self.reset()
            elif ctl.action == SimActionName.PAUSE:
                self.paused = True
            elif ctl.action == SimActionName.RESUME:
                self.paused = self.stopped = False

    def publish(self, res: StepResult, readings: SensorReadings | None = None) -> None:
        """Sensors, truth and lap events of one step (`readings`: the sensors' output for
        `res`, computed ahead by the loop; None: computed here).

        Angles are wrapped into [-pi, pi); every record goes through ``try_put``, so one that
        fails validation is counted in ``bus.faults`` and skipped, never raised.
        """
        if readings is None:
            readings = self.sensors.update(res)
        if self.vesc is not None:  # the fake VESC's IMU measures the step's truth
            self.vesc.set_imu(res.state.yaw_rate_radps, res.accel_long_mps2, res.accel_lat_mps2)
        for m in readings.pose:
            self.pub_pose.try_put(
                stamp_s=self.stamp(m.stamp_s),
                x_m=m.x_m,
                y_m=m.y_m,
                yaw_rad=wrap_angle(m.yaw_rad),
                cov=None,
            )
        for m in readings.imu if not self.vesc_imu else ():  # else the vesc_driver's
            self.pub_imu.try_put(
                stamp_s=self.stamp(m.stamp_s),
                yaw_rate_radps=m.yaw_rate_radps,
                ax_mps2=m.accel_long_mps2,
                ay_mps2=m.accel_lat_mps2,
            )
        for m in readings.odometry if self.vesc is None else ():  # else the vesc_driver's
            self.pub_odom.try_put(
                stamp_s=self.stamp(m.stamp_s),
                speed_mps=m.speed_mps,
                steering_rad=m.steering_rad,
                yaw_rate_radps=None,
            )
        for m in readings.scans:
            self.pub_scan.try_put(
                stamp_s=self.stamp(m.stamp_s),
                angle_min_rad=m.angle_min_rad,
                angle_increment_rad=m.angle_increment_rad,
                ranges_m=np.asarray(m.ranges_m, dtype=np.float32),
            )
        st = res.state
        for ev in self.timer.update(res.t_s, st.x_m, st.y_m, st.yaw_rad, st.v_mps):
            self.pub_lap.try_put(
                stamp_s=self.stamp(ev.t_s),
                kind=ev.kind,
                lap=ev.lap,
                lap_time_s=ev.lap_time_s,
                mean_speed_mps=ev.mean_speed_mps,
                off_track_events=ev.off_track_events,
                max_abs_e_con_m=ev.max_abs_e_con_m,
            )
            if ev.kind == LapKindName.LAP:
                self.log.info("lap %d: %.3f s", ev.lap, ev.lap_time_s or 0.0)
            elif ev.kind == LapKindName.OFF_TRACK:
                self.on_off_track(ev)
        if res.t_s + 1e-9 >= self._next_truth:
            self._next_truth = res.t_s + 1.0 / TRUTH_RATE_HZ
            slip = st.slip_rad
            if not -_HALF_PI - _SLIP_SLACK_RAD <= slip <= _HALF_PI + _SLIP_SLACK_RAD:
                self.faults.record(
                    STATE_FAULT_KEY,
                    "slip_not_canonical",
                    f"slip {slip:.3f} rad outside [-pi/2, pi/2]; published wrapped",
                )
            self.pub_truth.try_put(
                stamp_s=self.stamp(res.t_s),
                x_m=st.x_m,
                y_m=st.y_m,
                yaw_rad=wrap_angle(st.yaw_rad),
                speed_mps=st.v_mps,
                yaw_rate_radps=st.yaw_rate_radps,
                slip_rad=wrap_angle(slip),
                steering_rad=st.delta_rad,
                s_m=self.timer.s_m,
                e_con_m=self.timer.e_con_m,
                off_track=self.timer.off_track,
                lap=self.timer.laps_completed,
            )

    def collide(self) -> None:
        """Contacts between the cars after a step (module docstring): count and say new
        episodes, push overlapping cars apart with the impact's response, and give every
        car's lidar the others' footprints."""
        cars = (self, *self.others)
        states = [c.sim.state for c in cars]
        poses = np.array([[s.x_m, s.y_m, s.yaw_rad] for s in states])
        vel = np.array([[s.v_mps * math.cos(s.yaw_rad + s.slip_rad),
                         s.v_mps * math.sin(s.yaw_rad + s.slip_rad)] for s in states])
        assert self.contacts is not None
        for inc in self.contacts.update(self.sim.t_s, poses, vel):
            a, b = cars[inc.car_a].keys.car, cars[inc.car_b].keys.car
            closing = float((vel[inc.car_a] - vel[inc.car_b]) @ np.asarray(inc.normal))
            if inc.striker < 0:
                striker, struck = "none", f"{a}+{b}"
            else:
                striker = cars[inc.striker].keys.car
                struck = b if striker == a else a
            rec = IncidentRecord(len(self.contacts.incidents), striker, struck, inc.t_s,
                                 inc.depth_m, closing)
            self.say(LogLevelName.WARNING, incident_line(rec))
        veh = self.cfg.simulator.vehicle
        params = ContactParams(self.cfg.simulator.contact_restitution,
                               self.cfg.simulator.contact_speed_loss, veh.length_m,
                               veh.width_m)
        motions = [Motion(s.x_m, s.y_m, s.yaw_rad, s.v_mps, s.slip_rad) for s in states]
        for i in range(len(cars)):
            for j in range(i + 1, len(cars)):
                got = respond(motions[i], motions[j], params)
                if got is None:
                    continue
                motions[i], motions[j], impact = got
                self.impacts += int(impact)
                for k in (i, j):
                    m = motions[k]
                    cars[k].sim.nudge(m.x_m, m.y_m, m.speed_mps, m.slip_rad)
        boxes = np.array([[m.x_m, m.y_m, m.yaw_rad] for m in motions])
        for k, c in enumerate(cars):
            if c.sensors.lidar is not None:
                c.sensors.lidar.boxes = np.delete(boxes, k, axis=0)
                c.sensors.lidar.box_size_m = (veh.length_m, veh.width_m)

    def step_fleet(self, h: float) -> list[StepResult | None]:
        """Step every car by `h` [s], then their contacts: each car's result (None: it was
        reset), the states after the contacts' response."""
        results = [c.advance(h) for c in (self, *self.others)]
        if self.others:
            self.collide()
            cars = (self, *self.others)
            results = [None if r is None else dataclasses.replace(r, state=c.sim.state)
                       for c, r in zip(cars, results, strict=True)]
        return results

    def close(self) -> None:
        """Stop the fake VESC (actuation = "fake_vesc")."""
        if self.vesc is not None:
            self.vesc.close()

    def serve(self, stop: threading.Event) -> int:
        """The service's main thread: the real-time loop until `stop`."""
        self.log.info(
            "simulating %s (%.2f m) in real time; waiting for %s",
            self.track.name,
            self.track.length_m,
            self.keys.drive_cmd if self.vesc is None else f"a vesc_driver on {self.vesc.path}",
        )
        wall0 = self.clock()
        sim0 = self.sim.t_s
        self.run(stop)
        wall = self.clock() - wall0
        rate = (self.sim.t_s - sim0) / wall if wall > 0 else 1.0
        self.log.info(
            "stopping (%d real-time overruns, %d slowdowns of the world (%.2f s, longest "
            "%.3f s; the world ran at %.3f of real time), %d own faults, %d fault resets, "
            "%d off-track)",
            self.overruns,
            self.slowdowns,
            self.slowed_s,
            self.longest_slowdown_s,
            rate,
            self.faults.total,
            self.fault_resets,
            self.off_track_actions,
        )
        if self.contacts is not None:
            self.log.info("%d cars: %d contacts (%d impacts)", 1 + len(self.others),
                          len(self.contacts.incidents), self.impacts)
        return 0

    def run(self, stop: threading.Event) -> None:
        """Step the car in real time until `stop` is set."""
        h = self.cfg.simulator.integration_step_s
        self.t0_wall = self.wall_clock() - self.sim.t_s
        t0_mono = self.clock() - self.sim.t_s
        next_debug_s = self.sim.t_s
        fleet = (self, *self.others)
        while not stop.is_set():
            for car in fleet:
                car.report()
                car.handle_inputs()
            if self.paused:
                stop.wait(h)
                t0_mono += h
                self.t0_wall += h
                continue
            # None: the car was reset (its state left the contract)
            res, *rest = self.step_fleet(h) if self.others else (self.advance(h),)
            # the step's sensor readings (the lidar scan too) before the wait: in its slack
            readings = self.sensors.update(res) if res is not None else None
            rest_readings = [car.sensors.update(r) if r is not None else None
                             for car, r in zip(self.others, rest, strict=True)]
            if self.sim.t_s >= next_debug_s:  # with -v: a line every DEBUG_PERIOD_S
                next_debug_s = self.sim.t_s + DEBUG_PERIOD_S
                st = self.sim.state
                self.log.debug("t = %.1f s: %.2f m/s at s = %.1f m, %d laps, %d overruns",
                               self.sim.t_s, st.v_mps, self.timer.s_m,
                               self.timer.laps_completed, self.overruns)
            # publish when the wall clock reaches the new sim time, so no message leaves
            # before the instant its stamp names
            delay = t0_mono + self.sim.t_s - self.clock()
            if delay > 0:
                stop.wait(delay)
            else:
                if delay < -OVERRUN_S:
                    self.overruns += 1
                if delay < -MAX_LAG_S:  # the world slows by the excess (module docstring)
                    excess = -delay - MAX_LAG_S
                    t0_mono += excess
                    self.t0_wall += excess
                    self.slowdowns += 1
                    self.slowed_s += excess
                    self.longest_slowdown_s = max(self.longest_slowdown_s, excess)
                    if math.log10(self.slowdowns).is_integer():  # 1st, 10th, 100th, ...
                        self.log.warning(
                            "%.3f s behind real time: the world slows by %.3f s (%d times, "
                            "%.2f s in all; the machine is too loaded for real time)",
                            -delay, excess, self.slowdowns, self.slowed_s,
                        )
            if res is not None:
                self.publish(res, readings)
            for car, r, rd in zip(self.others, rest, rest_readings, strict=True):
                car.t0_wall = self.t0_wall  # one clock for all
                if r is not None:
                    car.publish(r, rd)


main = SimulatorService.main
