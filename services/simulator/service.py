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

The shell is a ``shared.service.Service`` (ports in ``SimulatorService.PORTS``); its main
thread is the real-time loop (``serve``), which also polls the drop and fault reports.
"""

from __future__ import annotations

import argparse
import logging
import math
import threading
import time
from collections.abc import Callable

import numpy as np

from services.simulator import LapEvent as TimerEvent
from services.simulator import LapTimer, SensorSuite, Simulator, StepResult
from services.simulator.laps import centreline_pose
from services.simulator.limits import state_fault
from services.simulator.sensors import SensorReadings
from services.simulator.state import Pose2D, rear_axle
from services.simulator.vesc_actuation import VescActuation
from shared.angles import wrap_angle
from shared.bus import Bus, LatestSlot
from shared.config import RacestackConfig
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
    ) -> None:
        super().__init__(bus, clock=clock, wall_clock=wall_clock)
        self.cfg = cfg
        self.track = track
        s = cfg.simulator
        self.sim = Simulator(s)
        grid = occupancy_for(track) if s.lidar.rate_hz > 0 else None
        self.sensors = SensorSuite(s, grid)
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
        return cls(cfg, bus, track)

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
        self.teleport(centreline_pose(self.track, START_OFFSET_M))
        self.timer.reset()
        self.stopped = False
        st = self.sim.state
        self.timer.update(t, st.x_m, st.y_m, st.yaw_rad, st.v_mps)
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
            self.sim.set_command(cmd.speed_mps, cmd.steering_rad, self.sim.t_s)
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
        return 0

    def run(self, stop: threading.Event) -> None:
        """Step the car in real time until `stop` is set."""
        h = self.cfg.simulator.integration_step_s
        self.t0_wall = self.wall_clock() - self.sim.t_s
        t0_mono = self.clock() - self.sim.t_s
        next_debug_s = self.sim.t_s
        while not stop.is_set():
            self.report()
            self.handle_inputs()
            if self.paused:
                stop.wait(h)
                t0_mono += h
                self.t0_wall += h
                continue
            res = self.advance(h)  # None: the car was reset (its state left the contract)
            # the step's sensor readings (the lidar scan too) before the wait: in its slack
            readings = self.sensors.update(res) if res is not None else None
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


main = SimulatorService.main
