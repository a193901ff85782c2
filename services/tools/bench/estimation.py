"""Localisation in the bench's loop: the simulator's sensor models through the bridge's own
filter code, in the same process (``racestack bench --estimator truth|ekf|lidar``).

- ``truth``: the planner sees the true rear-axle pose (no object here; the bench as before);
- ``ekf``: the simulator's pose sensor (``[simulator.pose]``: rate, latency, noise), IMU and
  wheel odometry into ``FusedEstimator``; the planner sees the estimate at its tick;
- ``lidar``: the simulator's lidar (``[simulator.lidar]``) into the particle filter
  (``LidarPoseSource``), its pose with its covariance into the EKF with the IMU and odometry.

Both start from the car's known start pose (the bench's start, ``init = "start"``). Every
planner tick compares the estimate with the truth: ``errors()`` gives the RMS position [m]
and yaw [rad] errors, the largest position error, the lateral error (across the car: the
tube the planner's pose-source margin covers) and the filter's counts.
"""

from __future__ import annotations

import math
from collections import Counter

import numpy as np

from services.localization_bridge import (
    FilterMap,
    FusedEstimator,
    LidarPoseSource,
    map_settings,
)
from services.simulator import SensorSuite, StepResult
from shared.angles import wrap_angle
from shared.config.localization import LocalizationSettings
from shared.config.simulator import SimulatorSettings
from shared.messages import Scan
from shared.track import OccupancyGrid, Track, occupancy_for
from shared.track.raycast import EDT_CAP_M, RayMarcher

#: The estimators of ``--estimator``.
ESTIMATORS = ("truth", "ekf", "lidar")
#: Occupancy grids made in this process, by track (``track_grid``).
_GRIDS: dict[tuple, OccupancyGrid] = {}
#: The lidar's ray marchers and the filter's map data made in this process, by grid and
#: settings (``lidar_maps``).
_MARCHERS: dict[tuple, RayMarcher] = {}
_FILTER_MAPS: dict[tuple, FilterMap] = {}
#: ... at most this many of each (the robustness benchmark's workers race a few tracks each).
GRID_CACHE_SIZE = 4


def _track_key(track: Track) -> tuple:
    return (track.name, track.source, track.n_points, float(track.length_m),
            float(np.sum(track.xy)), float(np.sum(track.w_left_m) + np.sum(track.w_right_m)))


def _remember(cache: dict, key: tuple, make):
    if key not in cache:
        if len(cache) >= GRID_CACHE_SIZE:
            cache.pop(next(iter(cache)))
        cache[key] = make()
    return cache[key]


def track_grid(track: Track) -> OccupancyGrid:
    """``occupancy_for(track)``, made once per track in a process: every car and method on
    that track reads the same grid (read-only). Loading a ROS map takes a fraction of a
    second; rasterising a track's boundaries 0.01-0.1 s (10-60 s before ``inside_cells``)."""
    return _remember(_GRIDS, _track_key(track), lambda: occupancy_for(track))


def lidar_maps(
    track: Track, sim_settings: SimulatorSettings, settings: LocalizationSettings
) -> tuple[OccupancyGrid, RayMarcher, FilterMap]:
    """The track's grid, the simulated lidar's ray marcher and the particle filter's map data,
    each made once per process (``track_grid``'s reason: their distance transforms take
    5-7 s per run on a 400 m F1TENTH map, 12 % of a lidar cell of the robustness benchmark);
    all read-only, so every run on the track shares them."""
    key = _track_key(track)
    grid = track_grid(track)
    unknown = sim_settings.lidar.unknown_is_occupied
    pf = settings.particle_filter
    marcher = _remember(_MARCHERS, (*key, unknown),
                        lambda: RayMarcher(grid, unknown_is_occupied=unknown, cap_m=EDT_CAP_M))
    fmap = _remember(_FILTER_MAPS, (*key, map_settings(pf)), lambda: FilterMap.build(grid, pf))
    if marcher.grid is not grid or fmap.grid is not grid:  # the grid left its cache: rebuild
        _MARCHERS.clear()
        _FILTER_MAPS.clear()
        return lidar_maps(track, sim_settings, settings)
    return grid, marcher, fmap


class InLoopEstimator:
    """Sensors of `sim_settings` -> the bridge's filter (module docstring).

    Args:
        kind: "ekf" or "lidar".
        track: the track (its occupancy map for the lidar).
        sim_settings: the simulator's sensors and seed.
        settings: ``[localization]``.
        start: the true rear-axle start pose (x [m], y [m], yaw [rad]) at time `t0_s` [s].
    """

    def __init__(
        self,
        kind: str,
        track: Track,
        sim_settings: SimulatorSettings,
        settings: LocalizationSettings,
        start: tuple[float, float, float],
        t0_s: float = 0.0,
    ) -> None:
        if kind not in ("ekf", "lidar"):
            raise ValueError(f"estimator must be 'ekf' or 'lidar', got {kind!r}")
        self.kind = kind
        self.lidar: LidarPoseSource | None = None
        if kind == "lidar":
            grid, marcher, fmap = lidar_maps(track, sim_settings, settings)
            self.sensors = SensorSuite(sim_settings, grid, marcher)
            self.lidar = LidarPoseSource(grid, settings, start, seed=sim_settings.seed,
                                         filter_map=fmap)
        else:
            self.sensors = SensorSuite(sim_settings, None)
        self.filter = FusedEstimator(settings)
        self.filter.pose(t0_s, *start, None, t0_s)  # the known start pose
        self._err_xy: list[float] = []
        self._err_lat: list[float] = []
        self._err_yaw: list[float] = []
        self.invalid_ticks = 0

    def feed(self, out: StepResult) -> None:
        """One simulation step's truth through the sensors into the filter."""
        now = out.t_s
        got = self.sensors.update(out)
        f = self.filter
        for m in got.imu:
            f.imu(m.stamp_s, m.yaw_rate_radps, now)
            if self.lidar is not None:
                self.lidar.imu(m.yaw_rate_radps)
        for o in got.odometry:
            f.odom(o.stamp_s, o.speed_mps, o.steering_rad, None, now)
            if self.lidar is not None:
                self.lidar.odom(o.speed_mps)
        if self.lidar is None:
            for p in got.pose:
                f.pose(p.stamp_s, p.x_m, p.y_m, p.yaw_rad, None, now)
            return
        for s in got.scans:
            scan = Scan(
                stamp_s=s.stamp_s,
                angle_min_rad=s.angle_min_rad,
                angle_increment_rad=s.angle_increment_rad,
                ranges_m=s.ranges_m,
            )
            bias = f.estimate(now).bias_radps
            sp = self.lidar.scan(scan, bias)
            if sp is not None:
                e = sp.estimate
                f.pose(sp.t_s, e.x_m, e.y_m, e.yaw_rad, e.cov, now)

    def pose(self, now_s: float, truth: tuple[float, float, float]) -> tuple[float, float, float]:
        """The estimate at `now_s` [s] the planner sees; `truth` (rear axle) is recorded
        against it."""
        e = self.filter.estimate(now_s)
        self.invalid_ticks += not e.valid
        dx, dy = e.x_m - truth[0], e.y_m - truth[1]
        self._err_xy.append(math.hypot(dx, dy))
        # across the car (normal to its true heading): what pushes the car off its line
        self._err_lat.append(-math.sin(truth[2]) * dx + math.cos(truth[2]) * dy)
        self._err_yaw.append(wrap_angle(e.yaw_rad - truth[2]))
        return e.x_m, e.y_m, e.yaw_rad

    def counts(self) -> Counter[str]:
        """The filter's and the lidar's counts."""
        out = Counter(self.filter.counts)
        if self.lidar is not None:
            out.update(self.lidar.counts)
        return out

    def errors(self) -> dict:
        """RMS position [m] and yaw [deg] error, max position error [m], the lateral error
        (across the car's true heading: RMS, 95th / 99th percentile and max of its size [m],
        what ``[planner.raceline] ekf_margin_m`` / ``lidar_margin_m`` cover), invalid ticks
        and the counts (results.json's ``localisation``)."""
        xy, yaw = np.asarray(self._err_xy), np.asarray(self._err_yaw)
        lat = np.abs(np.asarray(self._err_lat))
        n = xy.size
        return {
            "estimator": self.kind,
            "ticks": int(n),
            "rms_position_m": float(np.sqrt(np.mean(xy**2))) if n else None,
            "max_position_m": float(xy.max()) if n else None,
            "rms_lateral_m": float(np.sqrt(np.mean(lat**2))) if n else None,
            "p95_lateral_m": float(np.percentile(lat, 95)) if n else None,
            "p99_lateral_m": float(np.percentile(lat, 99)) if n else None,
            "max_lateral_m": float(lat.max()) if n else None,
            "rms_yaw_deg": float(np.degrees(np.sqrt(np.mean(yaw**2)))) if n else None,
            "invalid_ticks": self.invalid_ticks,
            "counts": dict(self.counts()),
        }
