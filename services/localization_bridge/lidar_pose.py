"""The pose from the bridge's own lidar: scans checked (``scan_check.py``), then the particle
filter (``particle_filter.py``) moved by the odometry speed and IMU yaw rate between scans and
corrected by the scan. Its estimate, with its covariance, is the EKF's pose measurement
(captured at the scan's stamp). Maths only: the caller passes stamps and records.

Motion between two scans ``t0 -> t1``: ``predict(t1 - t0, v, r)`` with ``v`` the newest wheel
speed and ``r`` the mean of the gyro samples since ``t0`` (the newest one, or the odometry's
yaw rate, without any), minus the EKF's bias estimate when the caller gives one. A gap
longer than ``MAX_GAP_S`` is predicted as ``MAX_GAP_S`` (the filter's noise then has to
cover the rest).

Dropped scans are counted in ``counts`` (a ``scan_check`` reason, ``scan_out_of_order``,
``scan_before_teleport``, or ``pf_not_converged`` / ``pf_lost`` for a scan used by the
filter whose estimate is not handed on). A teleport (``place``) starts the particle cloud
again around the announced pose; scans stamped at or before it are dropped.
"""

from __future__ import annotations

import math
from collections import Counter
from dataclasses import dataclass

from services.localization_bridge.particle_filter import FilterMap, ParticleFilter, PfEstimate
from services.localization_bridge.scan_check import ScanLayout, scan_problem
from shared.config.localization import LocalizationSettings
from shared.messages import Scan
from shared.track import OccupancyGrid, Track

#: Longest interval predicted in one go between two scans [s].
MAX_GAP_S = 0.5


def start_pose(track: Track, settings: LocalizationSettings) -> tuple[float, float, float]:
    """The rear-axle pose the filter starts at with ``init = "start"``: ``initial_pose``, or
    the centreline at ``start_s_m`` heading along the track [m, m, rad]."""
    if settings.initial_pose is not None:
        return settings.initial_pose
    x, y = (float(v) for v in track.point_at(settings.start_s_m))
    return x, y, float(track.heading_at(settings.start_s_m))


@dataclass(frozen=True, slots=True)
class ScanPose:
    """The particle filter's pose at a scan's stamp `t_s` [s] (``PfEstimate``)."""

    t_s: float
    estimate: PfEstimate


class LidarPoseSource:
    """Scans + odometry + IMU -> particle-filter poses (module docstring).

    Args:
        grid: the track's occupancy map (``shared.track.occupancy_for``).
        settings: ``[localization]`` (``particle_filter``, ``init``).
        start: the start pose for ``init = "start"`` (``start_pose``).
        seed: the filter's random seed.
        filter_map: the filter's map data, built once for `grid` (``FilterMap.build``; None:
            built here).
    """

    def __init__(
        self,
        grid: OccupancyGrid,
        settings: LocalizationSettings,
        start: tuple[float, float, float] | None,
        seed: int = 0,
        filter_map: FilterMap | None = None,
    ) -> None:
        self.pf = ParticleFilter(grid, settings.particle_filter, seed=seed,
                                 filter_map=filter_map)
        if settings.init == "start" and start is not None:
            self.pf.init_pose(*start)
        self.counts: Counter[str] = Counter()
        self.layout: ScanLayout | None = None
        self.t_last: float | None = None
        self.teleport_t: float | None = None
        self.speed_mps = 0.0
        self._gyro_sum = 0.0
        self._gyro_n = 0
        self._gyro_last: float | None = None
        self._odom_rate: float | None = None

    def place(self, t_s: float, x_m: float, y_m: float, yaw_rad: float, speed_mps: float) -> None:
        """A teleport at `t_s` [s]: the cloud around the rear-axle pose (`x_m`, `y_m` [m],
        `yaw_rad` [rad]) with the filter's init stds, moving at `speed_mps` [m/s]."""
        self.pf.init_pose(x_m, y_m, yaw_rad)
        self.t_last = self.teleport_t = t_s
        self.speed_mps = speed_mps
        self._gyro_sum, self._gyro_n, self._gyro_last = 0.0, 0, None

    def odom(self, speed_mps: float, yaw_rate_radps: float | None = None) -> None:
        """The newest wheel speed [m/s] (and the odometry's yaw rate [rad/s], if any)."""
        if math.isfinite(speed_mps):
            self.speed_mps = speed_mps
        if yaw_rate_radps is not None and math.isfinite(yaw_rate_radps):
            self._odom_rate = yaw_rate_radps

    def imu(self, yaw_rate_radps: float) -> None:
        """A gyro yaw rate [rad/s]."""
        if math.isfinite(yaw_rate_radps):
            self._gyro_sum += yaw_rate_radps
            self._gyro_n += 1
            self._gyro_last = yaw_rate_radps

    def motion(self) -> tuple[float, float]:
        """The motion inputs since the last call: the newest speed [m/s] and the mean gyro yaw
        rate [rad/s] (see the module docstring); the gyro mean starts again. A threaded
        caller takes them under the lock that guards ``odom`` / ``imu`` and passes them to
        ``scan``."""
        if self._gyro_n:
            rate = self._gyro_sum / self._gyro_n
        elif self._gyro_last is not None:
            rate = self._gyro_last
        else:
            rate = self._odom_rate if self._odom_rate is not None else 0.0
        self._gyro_sum, self._gyro_n = 0.0, 0
        return self.speed_mps, rate

    def scan(
        self,
        scan: Scan,
        bias_radps: float = 0.0,
        motion: tuple[float, float] | None = None,
    ) -> ScanPose | None:
        """Use one scan: the filter's pose at its stamp, or None (counted: module docstring).
        `bias_radps`: the gyro bias to remove from the yaw rate [rad/s]; `motion`: the
        inputs of ``motion()`` taken by the caller (None: taken here)."""
        reason = scan_problem(scan, self.layout)
        if reason is not None:
            self.counts[reason] += 1
            return None
        t = scan.stamp_s
        if self.teleport_t is not None and t <= self.teleport_t:
            self.counts["scan_before_teleport"] += 1
            return None
        if self.t_last is not None and t <= self.t_last:
            self.counts["scan_out_of_order"] += 1
            return None
        if self.layout is None:
            self.layout = ScanLayout.of(scan)
        speed, rate = self.motion() if motion is None else motion
        if self.t_last is not None:
            dt = min(t - self.t_last, MAX_GAP_S)
            self.pf.predict(dt, speed, rate - bias_radps)
        self.t_last = t
        est = self.pf.update(scan)
        self.counts["scans_used"] += 1
        if est.lost:
            self.counts["pf_lost"] += 1
            return None
        if not est.converged:
            self.counts["pf_not_converged"] += 1
            return None
        return ScanPose(t, est)
