"""2-D lidar of the simulator: beams fanned over a field of view, cast on the occupancy grid.

The ray casting itself (distance transform, vectorised ray marching; error <= r / 4 plus the
rasterisation, r = cell size) lives in ``shared/track/raycast.py``, shared with the
localization bridge's particle filter. Other cars (issue #24) are footprint rectangles cast
analytically (``cast_on_boxes``), so a scan can see an opponent: ``scan(..., boxes=...)``.
"""

from __future__ import annotations

import numpy as np

from shared.car import CAR
from shared.track.occupancy import OccupancyGrid
from shared.track.raycast import EDT_CAP_M, RayMarcher, distance_transform

__all__ = ["EDT_CAP_M", "LidarScanner", "cast_on_boxes", "distance_transform"]


def cast_on_boxes(
    x_m: float,
    y_m: float,
    angle_rad: np.ndarray,
    boxes: np.ndarray,
    range_max_m: float,
    length_m: float = CAR.length_m,
    width_m: float = CAR.width_m,
) -> np.ndarray:
    """Ranges [m] of rays from (x, y) [m] along `angle_rad` (K,) [rad] to the nearest of the
    rectangles centred on `boxes` (M, 3) [x m, y m, yaw rad], ``length_m`` along the yaw and
    ``width_m`` across (slab method in each box's frame, all rays x boxes at once).

    Returns:
        (K,) float64, `range_max_m` where a ray meets no box within range; a ray starting
        inside a box reads 0.
    """
    ang = np.asarray(angle_rad, dtype=float).ravel()
    b = np.asarray(boxes, dtype=float).reshape(-1, 3)
    out = np.full(ang.size, float(range_max_m))
    if b.shape[0] == 0 or ang.size == 0:
        return out
    c, s = np.cos(b[:, 2])[:, None], np.sin(b[:, 2])[:, None]  # (M, 1)
    ox, oy = x_m - b[:, 0:1], y_m - b[:, 1:2]
    # ray origin and direction in each box frame: (M, 1) and (M, K)
    o_lon, o_lat = c * ox + s * oy, -s * ox + c * oy
    dx, dy = np.cos(ang)[None, :], np.sin(ang)[None, :]
    d_lon, d_lat = c * dx + s * dy, -s * dx + c * dy
    t_near = np.zeros((b.shape[0], ang.size))
    t_far = np.full_like(t_near, np.inf)
    for o, d, h in ((o_lon, d_lon, 0.5 * length_m), (o_lat, d_lat, 0.5 * width_m)):
        with np.errstate(divide="ignore", invalid="ignore"):
            inv = 1.0 / d
            t1, t2 = (-h - o) * inv, (h - o) * inv
        parallel = d == 0.0
        lo = np.where(parallel, np.where(np.abs(o) <= h, -np.inf, np.inf), np.minimum(t1, t2))
        hi = np.where(parallel, np.where(np.abs(o) <= h, np.inf, -np.inf), np.maximum(t1, t2))
        t_near = np.maximum(t_near, lo)
        t_far = np.minimum(t_far, hi)
    hit = t_near <= t_far
    t = np.where(hit, t_near, np.inf).min(axis=0)
    return np.minimum(out, t)


class LidarScanner:
    """Ray-marching lidar on a fixed occupancy grid (pose in, ranges out).

    Args:
        grid: the map; OCCUPIED cells (and UNKNOWN ones if `unknown_is_occupied`) stop beams.
        beams: number of beams (>= 2), spread evenly over `fov_rad` centred ahead.
        fov_rad: field of view [rad].
        range_max_m: maximum range [m]; returned for beams without a return.
        unknown_is_occupied: whether unknown cells stop beams.
        marcher: the ray marcher of `grid` (its distance transform takes seconds on a large
            map; a process scanning one map many times builds it once); None: built here.
    """

    def __init__(
        self,
        grid: OccupancyGrid,
        beams: int = 1080,
        fov_rad: float = 4.7,
        range_max_m: float = 30.0,
        unknown_is_occupied: bool = True,
        marcher: RayMarcher | None = None,
    ) -> None:
        if beams < 2 or not fov_rad > 0.0 or not range_max_m > 0.0:
            raise ValueError("need beams >= 2, fov_rad > 0 and range_max_m > 0")
        self.grid = grid
        self.beams = int(beams)
        self.range_max_m = float(range_max_m)
        self.angle_min_rad = -0.5 * float(fov_rad)
        self.angle_increment_rad = float(fov_rad) / (self.beams - 1)
        self._beam_angles = self.angle_min_rad + self.angle_increment_rad * np.arange(self.beams)
        if marcher is None:
            marcher = RayMarcher(grid, unknown_is_occupied=unknown_is_occupied, cap_m=EDT_CAP_M)
        elif marcher.grid is not grid or marcher.unknown_is_occupied != unknown_is_occupied:
            raise ValueError("marcher was built for another grid or unknown-cell rule")
        self.marcher = marcher
        self.resolution_m = self.marcher.resolution_m
        self.distance_m = self.marcher.distance_m  # kept for inspection and tests

    def scan(
        self,
        x_m: float,
        y_m: float,
        yaw_rad: float,
        boxes: np.ndarray | None = None,
        length_m: float = CAR.length_m,
        width_m: float = CAR.width_m,
    ) -> np.ndarray:
        """Ranges [m] from the sensor at (x, y) [m] looking along `yaw_rad` (map frame).

        Args:
            boxes: optional (M, 3) poses [x m, y m, yaw rad] of other cars, footprints
                ``length_m x width_m`` [m] centred on them (``cast_on_boxes``); the nearer of
                map and car wins.

        Returns:
            (beams,) float32; 0 when the sensor itself sits in a blocked cell.
        """
        angles = self._beam_angles + yaw_rad
        ranges = self.marcher.cast(x_m, y_m, angles, self.range_max_m)
        if boxes is not None and np.size(boxes):
            cars = cast_on_boxes(
                x_m, y_m, angles, boxes, self.range_max_m, length_m=length_m, width_m=width_m
            )
            ranges = np.minimum(ranges, cars)
        return ranges.astype(np.float32)
