"""Simulated sensors: pose (lidar localiser), IMU, wheel odometry, lidar scans.

Each sensor is a small deterministic object: fed the truth of every simulation step
(``StepResult``: time, state, accelerations) it returns the measurements that become
available at that time, each stamped with its capture time [s]. Sampling: a sensor with rate
``f`` captures at the first step with ``t >= t_next`` and then sets ``t_next += 1/f`` (no
drift; with a 10 ms step a 40 Hz sensor captures at 0, 30, 50, 80, ... ms). Noise is white
Gaussian from the sensor's own ``numpy.random.Generator``; zero standard deviations give the
truth exactly. ``SensorSuite`` builds all sensors from ``SimulatorSettings`` with independent
generators spawned from ``settings.seed``.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass, field

import numpy as np

from services.simulator.actuators import TIME_EPS_S
from services.simulator.lidar import LidarScanner
from services.simulator.state import rear_axle
from services.simulator.vehicle import StepResult
from shared.angles import wrap_angle_shifted
from shared.car import CAR
from shared.config.simulator import (
    ImuSettings,
    LidarSettings,
    OdometrySettings,
    PoseSensorSettings,
    SimulatorSettings,
)
from shared.track.occupancy import OccupancyGrid
from shared.track.raycast import RayMarcher


@dataclass(frozen=True, slots=True)
class PoseMeasurement:
    """A localiser pose: captured at `stamp_s`, available from `release_s` [s].

    Position of the CoG [m] and yaw [rad] in [-pi, pi), map frame.
    """

    stamp_s: float
    release_s: float
    x_m: float
    y_m: float
    yaw_rad: float


@dataclass(frozen=True, slots=True)
class ImuMeasurement:
    """IMU sample at `stamp_s` [s]: yaw rate [rad/s], body-frame accelerations [m/s^2]."""

    stamp_s: float
    yaw_rate_radps: float
    accel_long_mps2: float
    accel_lat_mps2: float


@dataclass(frozen=True, slots=True)
class OdometryMeasurement:
    """Wheel odometry at `stamp_s` [s]: wheel speed ``v cos(beta)`` [m/s], steering [rad]."""

    stamp_s: float
    speed_mps: float
    steering_rad: float


@dataclass(frozen=True, slots=True)
class LidarScan:
    """A 2-D scan at `stamp_s` [s], beams counter-clockwise from `angle_min_rad`.

    Beam i points at ``angle_min_rad + i * angle_increment_rad`` in the sensor frame (x ahead,
    y left). `ranges_m`: (beams,) float32 [m]; ``range_max_m`` means no return.
    """

    stamp_s: float
    angle_min_rad: float
    angle_increment_rad: float
    range_max_m: float
    ranges_m: np.ndarray = field(repr=False)


class _Schedule:
    """Capture times at a fixed rate, aligned to the first call."""

    def __init__(self, rate_hz: float) -> None:
        self.period_s = 1.0 / rate_hz
        self.next_s: float | None = None

    def due(self, t_s: float) -> bool:
        if self.next_s is None:
            self.next_s = t_s
        if t_s + TIME_EPS_S < self.next_s:
            return False
        self.next_s += self.period_s
        if self.next_s <= t_s:  # far behind (a long step): realign instead of bursting
            self.next_s = t_s + self.period_s
        return True

    def reset(self) -> None:
        self.next_s = None


class PoseSensor:
    """Pose as a lidar localiser gives it: rate, latency (stamped at capture), noise.

    The reported position is the REAR AXLE centre (``base_link`` of F1TENTH cars, what a
    localiser reports and the planner's model uses): the CoG moved back by
    ``rear_axle_offset_m`` along the yaw.
    """

    def __init__(
        self,
        settings: PoseSensorSettings,
        rng: np.random.Generator,
        rear_axle_offset_m: float = 0.0,
    ) -> None:
        self.settings = settings
        self.rng = rng
        self.rear_axle_offset_m = rear_axle_offset_m
        self._schedule = _Schedule(settings.rate_hz)
        self._pending: deque[PoseMeasurement] = deque()

    def reset(self) -> None:
        """Forget pending measurements and restart the schedule at the next update."""
        self._schedule.reset()
        self._pending.clear()

    def update(self, truth: StepResult) -> list[PoseMeasurement]:
        """Capture if due; return the measurements released at or before ``truth.t_s``."""
        t = truth.t_s
        st = self.settings
        if self._schedule.due(t):
            s = truth.state
            x, y, yaw = rear_axle(s.x_m, s.y_m, s.yaw_rad, self.rear_axle_offset_m)
            if st.position_noise_std_m > 0.0:
                nx, ny = self.rng.normal(0.0, st.position_noise_std_m, 2)
                x += float(nx)
                y += float(ny)
            if st.yaw_noise_std_rad > 0.0:
                yaw += float(self.rng.normal(0.0, st.yaw_noise_std_rad))
            self._pending.append(
                PoseMeasurement(t, t + st.latency_s, x, y, wrap_angle_shifted(yaw))
            )
        out = []
        while self._pending and self._pending[0].release_s <= t + TIME_EPS_S:
            out.append(self._pending.popleft())
        return out


class ImuSensor:
    """Yaw rate and body-frame longitudinal / lateral acceleration (mean over the step)."""

    def __init__(self, settings: ImuSettings, rng: np.random.Generator) -> None:
        self.settings = settings
        self.rng = rng
        self._schedule = _Schedule(settings.rate_hz)

    def reset(self) -> None:
        """Restart the schedule at the next update."""
        self._schedule.reset()

    def update(self, truth: StepResult) -> list[ImuMeasurement]:
        """One sample if due at ``truth.t_s``, else nothing."""
        if not self._schedule.due(truth.t_s):
            return []
        st = self.settings
        r = truth.state.yaw_rate_radps
        ax, ay = truth.accel_long_mps2, truth.accel_lat_mps2
        if st.yaw_rate_noise_std_radps > 0.0:
            r += float(self.rng.normal(0.0, st.yaw_rate_noise_std_radps))
        if st.accel_noise_std_mps2 > 0.0:
            nx, ny = self.rng.normal(0.0, st.accel_noise_std_mps2, 2)
            ax += float(nx)
            ay += float(ny)
        return [ImuMeasurement(truth.t_s, r, ax, ay)]


class OdometrySensor:
    """Wheel speed ``v cos(beta)`` [m/s] and the true road-wheel angle [rad].

    (A VESC driver reports the last commanded steering instead; a service that imitates it
    can substitute ``StepResult.steering_target_rad``.)
    """

    def __init__(self, settings: OdometrySettings, rng: np.random.Generator) -> None:
        self.settings = settings
        self.rng = rng
        self._schedule = _Schedule(settings.rate_hz)

    def reset(self) -> None:
        """Restart the schedule at the next update."""
        self._schedule.reset()

    def update(self, truth: StepResult) -> list[OdometryMeasurement]:
        """One sample if due at ``truth.t_s``, else nothing."""
        if not self._schedule.due(truth.t_s):
            return []
        st = self.settings
        s = truth.state
        speed = s.v_mps * math.cos(s.slip_rad)
        steer = s.delta_rad
        if st.speed_noise_std_mps > 0.0:
            speed += float(self.rng.normal(0.0, st.speed_noise_std_mps))
        if st.steering_noise_std_rad > 0.0:
            steer += float(self.rng.normal(0.0, st.steering_noise_std_rad))
        return [OdometryMeasurement(truth.t_s, speed, steer)]


class LidarSensor:
    """Scans at a rate from the true pose, with Gaussian range noise on the returns."""

    def __init__(
        self,
        settings: LidarSettings,
        grid: OccupancyGrid,
        rng: np.random.Generator,
        marcher: RayMarcher | None = None,
    ) -> None:
        self.settings = settings
        self.rng = rng
        self.scanner = LidarScanner(
            grid,
            beams=settings.beams,
            fov_rad=settings.fov_rad,
            range_max_m=settings.range_max_m,
            unknown_is_occupied=settings.unknown_is_occupied,
            marcher=marcher,
        )
        self._schedule = _Schedule(settings.rate_hz)
        #: other cars the beams also hit: (M, 3) CoG poses [x m, y m, yaw rad] (None: none)
        self.boxes: np.ndarray | None = None
        #: their footprint [m]
        self.box_size_m: tuple[float, float] = (CAR.length_m, CAR.width_m)

    def reset(self) -> None:
        """Restart the schedule at the next update."""
        self._schedule.reset()

    def update(self, truth: StepResult) -> list[LidarScan]:
        """One scan if due at ``truth.t_s``, else nothing."""
        if not self._schedule.due(truth.t_s):
            return []
        s = truth.state
        st = self.settings
        x = s.x_m + st.mount_x_m * math.cos(s.yaw_rad)
        y = s.y_m + st.mount_x_m * math.sin(s.yaw_rad)
        if self.boxes is None:
            ranges = self.scanner.scan(x, y, s.yaw_rad)
        else:
            ranges = self.scanner.scan(x, y, s.yaw_rad, boxes=self.boxes,
                                       length_m=self.box_size_m[0], width_m=self.box_size_m[1])
        if st.noise_std_m > 0.0:
            hit = ranges < st.range_max_m
            noisy = ranges + self.rng.normal(0.0, st.noise_std_m, ranges.shape).astype(np.float32)
            ranges = np.where(hit, np.clip(noisy, 0.0, st.range_max_m), ranges).astype(np.float32)
        sc = self.scanner
        return [
            LidarScan(truth.t_s, sc.angle_min_rad, sc.angle_increment_rad, sc.range_max_m, ranges)
        ]


@dataclass(frozen=True, slots=True)
class SensorReadings:
    """Everything the sensors released at one step (each list may be empty)."""

    pose: list[PoseMeasurement]
    imu: list[ImuMeasurement]
    odometry: list[OdometryMeasurement]
    scans: list[LidarScan]


class SensorSuite:
    """All sensors of `settings`, with independent noise generators spawned from its seed.

    Args:
        settings: simulator settings (sensor sections and seed).
        grid: occupancy map for the lidar; None disables the lidar.
        marcher: the lidar's ray marcher, built once for `grid` (None: built here).
    """

    def __init__(
        self,
        settings: SimulatorSettings,
        grid: OccupancyGrid | None = None,
        marcher: RayMarcher | None = None,
    ) -> None:
        seeds = np.random.SeedSequence(settings.seed).spawn(4)
        gens = [np.random.default_rng(s) for s in seeds]
        self.pose = PoseSensor(settings.pose, gens[0], settings.vehicle.lr_m)
        self.imu = ImuSensor(settings.imu, gens[1])
        self.odometry = OdometrySensor(settings.odometry, gens[2])
        self.lidar = (
            LidarSensor(settings.lidar, grid, gens[3], marcher) if grid is not None else None
        )

    def reset(self) -> None:
        """Restart all schedules and drop pending measurements (noise streams continue)."""
        for s in (self.pose, self.imu, self.odometry, self.lidar):
            if s is not None:
                s.reset()

    def update(self, truth: StepResult) -> SensorReadings:
        """Feed one step's truth to every sensor."""
        return SensorReadings(
            pose=self.pose.update(truth),
            imu=self.imu.update(truth),
            odometry=self.odometry.update(truth),
            scans=self.lidar.update(truth) if self.lidar is not None else [],
        )
