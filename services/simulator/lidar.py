"""2-D lidar of the simulator: beams fanned over a field of view, cast on the occupancy grid.

The ray casting itself (distance transform, vectorised ray marching; error <= r / 4 plus the
rasterisation, r = cell size) lives in ``shared/track/raycast.py``, shared with the
localization bridge's particle filter.
"""

from __future__ import annotations

import numpy as np

from shared.track.occupancy import OccupancyGrid
from shared.track.raycast import EDT_CAP_M, RayMarcher, distance_transform

__all__ = ["EDT_CAP_M", "LidarScanner", "distance_transform"]


class LidarScanner:
    """Ray-marching lidar on a fixed occupancy grid (pose in, ranges out).

    Args:
        grid: the map; OCCUPIED cells (and UNKNOWN ones if `unknown_is_occupied`) stop beams.
        beams: number of beams (>= 2), spread evenly over `fov_rad` centred ahead.
        fov_rad: field of view [rad].
        range_max_m: maximum range [m]; returned for beams without a return.
        unknown_is_occupied: whether unknown cells stop beams.
    """

    def __init__(
        self,
        grid: OccupancyGrid,
        beams: int = 1080,
        fov_rad: float = 4.7,
        range_max_m: float = 30.0,
        unknown_is_occupied: bool = True,
    ) -> None:
        if beams < 2 or not fov_rad > 0.0 or not range_max_m > 0.0:
            raise ValueError("need beams >= 2, fov_rad > 0 and range_max_m > 0")
        self.grid = grid
        self.beams = int(beams)
        self.range_max_m = float(range_max_m)
        self.angle_min_rad = -0.5 * float(fov_rad)
        self.angle_increment_rad = float(fov_rad) / (self.beams - 1)
        self._beam_angles = self.angle_min_rad + self.angle_increment_rad * np.arange(self.beams)
        self.marcher = RayMarcher(grid, unknown_is_occupied=unknown_is_occupied, cap_m=EDT_CAP_M)
        self.resolution_m = self.marcher.resolution_m
        self.distance_m = self.marcher.distance_m  # kept for inspection and tests

    def scan(self, x_m: float, y_m: float, yaw_rad: float) -> np.ndarray:
        """Ranges [m] from the sensor at (x, y) [m] looking along `yaw_rad` (map frame).

        Returns:
            (beams,) float32; 0 when the sensor itself sits in a blocked cell.
        """
        ranges = self.marcher.cast(x_m, y_m, self._beam_angles + yaw_rad, self.range_max_m)
        return ranges.astype(np.float32)
