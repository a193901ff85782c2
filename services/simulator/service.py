"""The simulator service: the vehicle stand-in on Zenoh, in real time.

Consumes ``cmd/drive`` (and ``sim/control``: reset / pause / resume); publishes what the real
car's drivers would: ``vehicle/pose`` (rear axle, as a lidar localiser gives it, with its
rate and latency), ``vehicle/imu``, ``vehicle/odom``, ``vehicle/scan`` (2D lidar on the
track's occupancy map), plus ``sim/truth`` and ``lap`` events for evaluation. Swapping the
simulator for the car is configuration: the same keys come from the real drivers.

Stamps are wall-clock seconds of the simulated capture instant (the simulation runs in real
time, anchored to the wall clock at start), so other services judge message age as on the
car. Without fresh commands for ``command_timeout_s`` the car brakes, like a VESC timeout.

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
"""

from __future__ import annotations

import argparse
import logging
import math
import threading
import time
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from services.simulator import LapTimer, SensorSuite, Simulator, StepResult, VehicleState
from services.simulator.laps import centreline_pose
from services.simulator.vesc_actuation import VescActuation
from shared.bus import Bus, DropReporter, LatestSlot
from shared.config import RacestackConfig
from shared.messages import (
    DriveCmd,
    Imu,
    LapEvent,
    LogEvent,
    Odom,
    Pose,
    Scan,
    SimControl,
    SimTruth,
)
from shared.messages.codec import MAX_STR_LEN
from shared.messages.records import (
    MAX_POS_M,
    MAX_SPEED_MPS,
    MAX_STEER_RAD,
    MAX_YAW_RATE_RADPS,
)
from shared.ratelimit import RateLimiter
from shared.service_shell import run_service
from shared.track import OccupancyGrid, Track, load_ros_map, load_track, rasterize_track

log = logging.getLogger(__name__)
SERVICE = "simulator"
#: Rate of ``sim/truth`` [Hz].
TRUTH_RATE_HZ = 50.0
#: Where the car starts: this far along from the start line [m] (behind it: timing starts
#: at once and lap 1 is a standing-start lap).
START_OFFSET_M = -0.3
#: A loop iteration later than this behind real time is counted as an overrun [s].
OVERRUN_S = 0.02
#: Key under which faults of the car's state are counted in ``bus.faults`` (not a bus key).
STATE_FAULT_KEY = "car state"
#: Shortest interval between two ``events/log`` lines about fault resets [s].
FAULT_REPORT_INTERVAL_S = 1.0
_HALF_PI = 0.5 * math.pi
#: Slack on the core's canonical slip range [rad] (its own rounding).
_SLIP_SLACK_RAD = 1e-9


def wrap_pi(a: float) -> float:
    """Angle `a` [rad] wrapped into [-pi, pi] (the contract's range of wrapped angles)."""
    return math.remainder(a, math.tau)


def state_fault(st: VehicleState) -> tuple[str, str] | None:
    """Why the car's state is outside the message contract, as (reason, detail), or None.

    Checked: every element finite, position within ``MAX_POS_M`` [m], speed within
    ``MAX_SPEED_MPS`` [m/s], yaw rate within ``MAX_YAW_RATE_RADPS`` [rad/s], steering within
    ``MAX_STEER_RAD`` [rad]. Yaw and slip are angles: the records wrap them, so they are not
    checked here.
    """
    vals = st.as_tuple()
    if not all(math.isfinite(v) for v in vals):
        return "not_finite", f"non-finite state {vals}"
    if abs(st.x_m) > MAX_POS_M or abs(st.y_m) > MAX_POS_M:
        return "position_out_of_range", (
            f"position ({st.x_m:.1f}, {st.y_m:.1f}) m beyond {MAX_POS_M:g} m"
        )
    if abs(st.v_mps) > MAX_SPEED_MPS:
        return "speed_out_of_range", f"speed {st.v_mps:.2f} m/s beyond {MAX_SPEED_MPS:g} m/s"
    if abs(st.yaw_rate_radps) > MAX_YAW_RATE_RADPS:
        return "yaw_rate_out_of_range", (
            f"yaw rate {st.yaw_rate_radps:.2f} rad/s beyond {MAX_YAW_RATE_RADPS:g} rad/s"
        )
    if abs(st.delta_rad) > MAX_STEER_RAD:
        return "steering_out_of_range", (
            f"steering {st.delta_rad:.3f} rad beyond {MAX_STEER_RAD:g} rad"
        )
    return None


def occupancy_for(track: Track) -> OccupancyGrid:
    """The track's ROS map if its folder has one, else a grid rasterised from its boundaries."""
    src = Path(track.source)
    folder = src if src.is_dir() else src.parent
    if src.exists():
        maps = sorted(folder.glob("*.yaml"))
        if maps:
            return load_ros_map(maps[0])
    return rasterize_track(track, resolution_m=0.05)


class SimulatorService:
    """The real-time loop; publishers are injected so the core stays testable."""

    def __init__(self, cfg: RacestackConfig, bus: Bus, track: Track) -> None:
        self.cfg = cfg
        self.bus = bus
        self.track = track
        s = cfg.simulator
        self.sim = Simulator(s)
        grid = occupancy_for(track) if s.lidar.rate_hz > 0 else None
        self.sensors = SensorSuite(s, grid)
        veh = s.vehicle
        self.timer = LapTimer(track, width_m=veh.width_m, length_m=veh.length_m)
        k = bus.keys
        self.pub_pose = bus.publisher(k.pose, Pose)
        self.pub_imu = bus.publisher(k.imu, Imu)
        self.pub_odom = bus.publisher(k.odom, Odom)
        self.pub_scan = bus.publisher(k.scan, Scan)
        self.pub_truth = bus.publisher(k.sim_truth, SimTruth)
        self.pub_lap = bus.publisher(k.lap, LapEvent)
        self.pub_log = bus.publisher(k.events_log, LogEvent)
        self.commands: LatestSlot[DriveCmd] = LatestSlot()
        self.controls = bus.subscribe(k.sim_control, SimControl, queue_size=16)
        #: actuation = "fake_vesc": commands come from the vesc_driver's serial frames
        self.vesc: VescActuation | None = None
        if s.actuation == "fake_vesc":
            self.vesc = VescActuation(s.fake_vesc_link, cfg.vesc)
        else:
            bus.subscribe(k.drive_cmd, DriveCmd, callback=self.commands.put)
        self.drops = DropReporter(bus, SERVICE, publisher=self.pub_log)
        #: faults of its own: invalid records (by key) and car-state faults (STATE_FAULT_KEY)
        self.faults = bus.faults
        self.clock = time.monotonic  #: clock of the fault-report rate limit [s]
        self.t0_wall = time.time()
        self.paused = False
        self.overruns = 0
        self.fault_resets = 0  #: resets because the car's state left the contract
        self._reset_reports = RateLimiter(FAULT_REPORT_INTERVAL_S)
        self._next_truth = 0.0
        self.reset()

    def stamp(self, t_sim: float) -> float:
        """Wall-clock stamp [s] of simulation time `t_sim`."""
        return self.t0_wall + t_sim

    def reset(self) -> None:
        """Put the car at rest just behind the start line."""
        t = self.sim.t_s
        self.sim.reset(centreline_pose(self.track, START_OFFSET_M), speed_mps=0.0, t_s=t)
        self.sensors.reset()
        self.timer.reset()
        st = self.sim.state
        self.timer.update(t, st.x_m, st.y_m, st.yaw_rad, st.v_mps)
        log.info("car reset to the start line")

    def say(self, level: str, text: str) -> None:
        """Log locally and on ``events/log``."""
        getattr(log, level)(text)
        self.pub_log.try_put(
            stamp_s=time.time(), level=level, source=SERVICE, text=text[:MAX_STR_LEN]
        )

    def fault_reset(self, reason: str, detail: str) -> None:
        """The car's state left the contract: count it, reset the car, say so (rate-limited)."""
        self.faults.record(STATE_FAULT_KEY, reason, detail)
        self.fault_resets += 1
        self.reset()
        allowed, suppressed = self._reset_reports.allow(self.clock())
        if not allowed:
            return
        more = f" ({suppressed} more since the last report)" if suppressed else ""
        self.say(
            "error",
            f"car state left the contract ({detail}): car reset to the start line "
            f"(fault reset {self.fault_resets}){more}",
        )

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
        if cmd is not None and not self.paused:
            self.sim.set_command(cmd.speed_mps, cmd.steering_rad, self.sim.t_s)
        for ctl in self.controls.drain():
            if ctl.action == "reset":
                self.reset()
            elif ctl.action == "pause":
                self.paused = True
            elif ctl.action == "resume":
                self.paused = False

    def publish(self, res: StepResult) -> None:
        """Sensors, truth and lap events of one step.

        Angles are wrapped into [-pi, pi]; every record goes through ``try_put``, so one that
        fails validation is counted in ``bus.faults`` and skipped, never raised.
        """
        readings = self.sensors.update(res)
        for m in readings.pose:
            self.pub_pose.try_put(
                stamp_s=self.stamp(m.stamp_s),
                x_m=m.x_m,
                y_m=m.y_m,
                yaw_rad=wrap_pi(m.yaw_rad),
                cov=None,
            )
        for m in readings.imu:
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
            if ev.kind == "lap":
                log.info("lap %d: %.3f s", ev.lap, ev.lap_time_s or 0.0)
            elif ev.kind == "off_track":
                self.say("warning", f"off track at s = {ev.s_m:.1f} m")
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
                yaw_rad=wrap_pi(st.yaw_rad),
                speed_mps=st.v_mps,
                yaw_rate_radps=st.yaw_rate_radps,
                slip_rad=wrap_pi(slip),
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

    def run(self, stop: threading.Event) -> None:
        """Step the car in real time until `stop` is set."""
        h = self.cfg.simulator.integration_step_s
        self.t0_wall = time.time() - self.sim.t_s
        t0_mono = time.monotonic() - self.sim.t_s
        while not stop.is_set():
            self.drops.poll()
            self.handle_inputs()
            if self.paused:
                stop.wait(h)
                t0_mono += h
                self.t0_wall += h
                continue
            res = self.advance(h)  # None: the car was reset (its state left the contract)
            # publish when the wall clock reaches the new sim time, so no message leaves
            # before the instant its stamp names
            delay = t0_mono + self.sim.t_s - time.monotonic()
            if delay > 0:
                stop.wait(delay)
            elif delay < -OVERRUN_S:
                self.overruns += 1
            if res is not None:
                self.publish(res)


def run(cfg: RacestackConfig, args: argparse.Namespace, stop: threading.Event) -> int:
    """The service body."""
    track = load_track(cfg.track.source)
    with Bus(cfg.bus, SERVICE) as bus:
        svc = SimulatorService(cfg, bus, track)
        try:
            log.info(
                "simulating %s (%.2f m) in real time; waiting for %s",
                track.name,
                track.length_m,
                bus.keys.drive_cmd if svc.vesc is None else f"a vesc_driver on {svc.vesc.path}",
            )
            svc.run(stop)
            log.info(
                "stopping (%d real-time overruns, %d own faults, %d fault resets)",
                svc.overruns,
                svc.faults.total,
                svc.fault_resets,
            )
        finally:
            svc.close()
    return 0


def main(argv: Sequence[str] | None = None) -> int:
    """``python -m services.simulator``."""
    return run_service(SERVICE, argv, run, description=__doc__.splitlines()[0])
