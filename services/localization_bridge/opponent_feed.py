"""Opponents of one scan, as the bridge publishes them (issue #24): maths only, no I/O.

``OpponentFeed.process`` takes a scan (ranges, beam angles, its stamp) and the car's pose at
the scan's stamp (rear axle, map frame, from the bridge's fused state), places the lidar
with the mount of ``[localization.particle_filter]`` (``lidar_x_m``, ``lidar_y_m``,
``lidar_yaw_rad``), runs the detector and the tracker of ``opponents.py`` and returns the
fields of the ``Opponents`` record's tracks (``OpponentTrack``, ``shared.messages``) with
the cost of the scan [s of CPU time].

``pose_at`` moves a state to another time by a unicycle (speed, yaw rate): the bridge's
state is "now", the scan was captured a few milliseconds before.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field

import numpy as np

from services.localization_bridge.opponents import (
    Detection,
    DetectorParams,
    OpponentDetector,
    OpponentTracker,
    ScanView,
    TrackerParams,
)
from services.localization_bridge.opponents import OpponentTrack as OpponentTrack_
from shared.car import CAR
from shared.config.localization import OpponentSettings
from shared.config.particle_filter import ParticleFilterSettings
from shared.messages import OpponentTrack
from shared.messages.records import MAX_POS_M, MAX_SPEED_MPS, MAX_TRACK_VAR
from shared.track import Track
from shared.track.occupancy import OccupancyGrid

__all__ = ["FeedResult", "OpponentFeed", "pose_at"]


def pose_at(
    x_m: float, y_m: float, yaw_rad: float, speed_mps: float, yaw_rate_radps: float, dt_s: float
) -> tuple[float, float, float]:
    """The pose [m, m, rad] `dt_s` [s] later (negative: earlier) along a unicycle of
    `speed_mps` [m/s] and `yaw_rate_radps` [rad/s] (midpoint heading)."""
    yaw_mid = yaw_rad + 0.5 * yaw_rate_radps * dt_s
    return (
        x_m + speed_mps * math.cos(yaw_mid) * dt_s,
        y_m + speed_mps * math.sin(yaw_mid) * dt_s,
        yaw_rad + yaw_rate_radps * dt_s,
    )


@dataclass(frozen=True)
class FeedResult:
    """One scan's output.

    Attributes:
        tracks: the confirmed tracks, as ``OpponentTrack`` records.
        detections: car-sized clusters found in the scan.
        cost_s: CPU time of the scan (detector + tracker) [s].
    """

    tracks: list[OpponentTrack]
    detections: int
    cost_s: float


@dataclass
class OpponentFeed:
    """The bridge's detector and tracker (module docstring).

    Args:
        grid: the track's occupancy map; track: its centreline (heading hints).
        settings: ``[localization.opponents]``; mount: ``[localization.particle_filter]``
            (the lidar's place on the car).
        length_m, width_m: an opponent's footprint [m].
    """

    grid: OccupancyGrid
    track: Track | None
    settings: OpponentSettings
    mount: ParticleFilterSettings
    length_m: float = CAR.length_m
    width_m: float = CAR.width_m
    costs_s: list[float] = field(default_factory=list)

    def __post_init__(self) -> None:
        s = self.settings
        self.detector = OpponentDetector(
            self.grid,
            DetectorParams(length_m=self.length_m, width_m=self.width_m,
                           unexplained_m=s.unexplained_m, min_points=s.min_points,
                           tracked_unexplained_m=s.tracked_unexplained_m),
            track=self.track,
        )
        self.tracker = OpponentTracker(
            TrackerParams(accel_std_mps2=s.accel_std_mps2, meas_std_m=s.meas_std_m,
                          confirm_hits=s.confirm_hits, max_misses=s.max_misses,
                          max_coast_s=s.max_coast_s)
        )
        self._born: dict[int, float] = {}

    def reset(self) -> None:
        """Forget every track (a teleport: the scene the tracks were in is gone)."""
        self.tracker = OpponentTracker(self.tracker.params)
        self._born.clear()

    def sensor_pose(self, x_m: float, y_m: float, yaw_rad: float) -> tuple[float, float, float]:
        """The lidar's pose [m, m, rad] of a rear-axle pose."""
        m = self.mount
        c, s = math.cos(yaw_rad), math.sin(yaw_rad)
        return (x_m + c * m.lidar_x_m - s * m.lidar_y_m,
                y_m + s * m.lidar_x_m + c * m.lidar_y_m,
                yaw_rad + m.lidar_yaw_rad)

    def process(
        self,
        t_s: float,
        ranges_m: np.ndarray,
        angle_min_rad: float,
        angle_increment_rad: float,
        rear_axle_pose: tuple[float, float, float],
    ) -> FeedResult:
        """Detect and track the opponents of one scan.

        Args:
            t_s: the scan's stamp [s]; ranges_m: (K,) [m] (+inf or beyond ``max_range_m``:
                no return); angle_min_rad, angle_increment_rad: the beams [rad];
            rear_axle_pose: the car's rear axle at `t_s` [m, m, rad] (map frame).
        """
        t0 = time.thread_time()
        sensor = self.sensor_pose(*rear_axle_pose)
        found = self.detector.detect(ranges_m, angle_min_rad, angle_increment_rad,
                                     self.settings.max_range_m, sensor,
                                     self.tracker.predicted_centres(t_s))
        view = ScanView(ranges_m, angle_min_rad, angle_increment_rad,
                        self.settings.max_range_m, sensor)
        confirmed = self.tracker.update(t_s, [(d.x_m, d.y_m, d.yaw_rad) for d in found], view,
                                        self.detector.free_at)
        alive = {tr.track_id for tr in self.tracker.tracks}
        for k in [k for k in self._born if k not in alive]:
            del self._born[k]
        out: list[OpponentTrack] = []
        for tr in confirmed:
            born = self._born.setdefault(tr.track_id, t_s)
            out.append(self._record(tr, t_s - born, found))
        cost = time.thread_time() - t0
        self.costs_s.append(cost)
        return FeedResult(out, len(found), cost)

    def _record(self, tr: OpponentTrack_, age_s: float, found: list[Detection]) -> OpponentTrack:
        """The record of track `tr`, `age_s` [s] old (values clipped into the contract)."""
        x, y = tr.position
        vx, vy = tr.velocity
        P = tr.P
        speed = math.hypot(vx, vy)
        # heading: the nearest detection's box axis, turned to the velocity; else the velocity
        yaw = math.atan2(vy, vx) if speed > 0.0 else 0.0
        if found:
            near = min(found, key=lambda d: (d.x_m - x) ** 2 + (d.y_m - y) ** 2)
            if (near.x_m - x) ** 2 + (near.y_m - y) ** 2 < (0.5 * self.length_m) ** 2:
                yaw = near.yaw_rad
                if speed > 0.2 and math.cos(yaw - math.atan2(vy, vx)) < 0.0:
                    yaw += math.pi
        yaw = math.atan2(math.sin(yaw), math.cos(yaw))
        if speed > 1e-6:
            u = np.array([vx, vy]) / speed
            speed_var = float(u @ P[2:, 2:] @ u)
        else:
            speed_var = float(0.5 * (P[2, 2] + P[3, 3]))
        pos = lambda v: min(max(v, -MAX_POS_M), MAX_POS_M)  # noqa: E731
        vel = lambda v: min(max(v, -MAX_SPEED_MPS), MAX_SPEED_MPS)  # noqa: E731
        var = lambda v: min(max(v, 0.0), MAX_TRACK_VAR)  # noqa: E731
        return OpponentTrack(
            id=tr.track_id, x_m=pos(x), y_m=pos(y), vx_mps=vel(vx), vy_mps=vel(vy),
            yaw_rad=yaw, length_m=self.length_m, width_m=self.width_m,
            cov_xx_m2=var(float(P[0, 0])), cov_xy_m2=float(np.clip(P[0, 1], -MAX_TRACK_VAR,
                                                                    MAX_TRACK_VAR)),
            cov_yy_m2=var(float(P[1, 1])), speed_var_m2ps2=var(speed_var),
            age_s=max(0.0, age_s), hits=tr.hits,
        )
