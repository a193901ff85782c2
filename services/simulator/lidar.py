"""2-D lidar by ray marching on an occupancy grid, accelerated by a distance transform.

Distance transform (numpy only): for every cell the Euclidean distance between its centre
and the nearest blocked cell's centre, computed exactly up to a cap ``D`` (larger distances
read as ``D``, still a valid lower bound):

1. per column, the vertical distance ``g`` [cells] to the nearest blocked cell (running
   maximum / minimum of blocked row indices), capped at ``D + 1``;
2. per row, ``d^2(i, j) = min_{|k| <= D} g(i, j + k)^2 + k^2`` (2D + 1 shifted minima).

Exact where the true distance is <= D: the nearest blocked cell then lies within D columns.

Ray marching (all beams at once, vectorised): a point inside a free cell whose centre is ``d``
from the nearest blocked centre is at least ``d - sqrt(2) r`` from any blocked cell (r = cell
size), so each beam advances by ``max(d - sqrt(2) r, r / 2)`` until it reaches a blocked cell
(range = midpoint of the last step, error <= r / 4 plus the rasterisation), leaves the map or
passes ``range_max`` (both: ``range_max``, no return).
"""

from __future__ import annotations

import math

import numpy as np

from shared.track.occupancy import OCCUPIED, UNKNOWN, OccupancyGrid

#: Distances in the transform are exact up to this [m]; beams step at most this far.
EDT_CAP_M = 2.0


def distance_transform(blocked: np.ndarray, cap_cells: int) -> np.ndarray:
    """Euclidean distance [cells] from each cell centre to the nearest blocked centre.

    Args:
        blocked: (rows, cols) bool, True where beams stop.
        cap_cells: D; distances above it read as D (exact below).

    Returns:
        (rows, cols) float32 distances in cells, 0 on blocked cells, at most `cap_cells`.
    """
    b = np.asarray(blocked, dtype=bool)
    rows, cols = b.shape
    cap = int(cap_cells)
    big = cap + 1
    idx = np.arange(rows)[:, None]
    # 1) vertical distance to the nearest blocked cell in the same column
    last = np.where(b, idx, -(10 * rows + big))
    last = np.maximum.accumulate(last, axis=0)
    nxt = np.where(b, idx, 10 * rows + big)
    nxt = np.minimum.accumulate(nxt[::-1], axis=0)[::-1]
    g = np.minimum(np.minimum(idx - last, nxt - idx), big).astype(np.float32)
    g2 = g * g
    # 2) horizontal lower envelope over a window of +-cap columns
    d2 = g2.copy()
    pad = np.full((rows, cap), float(big * big), dtype=np.float32)
    padded = np.concatenate([pad, g2, pad], axis=1)
    for k in range(1, cap + 1):
        kk = np.float32(k * k)
        np.minimum(d2, padded[:, cap + k : cap + k + cols] + kk, out=d2)
        np.minimum(d2, padded[:, cap - k : cap - k + cols] + kk, out=d2)
    return np.minimum(np.sqrt(d2), np.float32(cap))


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
        cells = np.asarray(grid.cells)
        blocked = cells == OCCUPIED
        if unknown_is_occupied:
            blocked |= cells == UNKNOWN
        r = float(grid.resolution_m)
        self.resolution_m = r
        cap = max(1, int(EDT_CAP_M / r))
        dist_m = distance_transform(blocked, cap).astype(np.float64) * r
        step = np.maximum(dist_m - math.sqrt(2.0) * r, 0.5 * r)
        # flat step field: a negative value marks a blocked cell
        self._step = np.where(blocked, -1.0, step).ravel()
        self._rows, self._cols = blocked.shape
        self.distance_m = dist_m  # kept for inspection and tests

    def scan(self, x_m: float, y_m: float, yaw_rad: float) -> np.ndarray:
        """Ranges [m] from the sensor at (x, y) [m] looking along `yaw_rad` (map frame).

        Returns:
            (beams,) float32; 0 when the sensor itself sits in a blocked cell.
        """
        g = self.grid
        r = self.resolution_m
        # to grid coordinates (metres from the grid origin, grid axes)
        ox, oy = float(g.origin_xy_m[0]), float(g.origin_xy_m[1])
        c0, s0 = math.cos(-g.origin_yaw_rad), math.sin(-g.origin_yaw_rad)
        px, py = x_m - ox, y_m - oy
        gx, gy = c0 * px - s0 * py, s0 * px + c0 * py
        ang = self._beam_angles + (yaw_rad - g.origin_yaw_rad)
        dx, dy = np.cos(ang), np.sin(ang)
        out = np.full(self.beams, self.range_max_m, dtype=np.float64)
        t = np.zeros(self.beams)
        last = np.zeros(self.beams)
        active = np.arange(self.beams)
        rows, cols = self._rows, self._cols
        step_field = self._step
        inv_r = 1.0 / r
        rmax = self.range_max_m
        while active.size:
            ta = t[active]
            cx = np.floor((gx + ta * dx[active]) * inv_r).astype(np.int64)
            cy = np.floor((gy + ta * dy[active]) * inv_r).astype(np.int64)
            inside = (cx >= 0) & (cx < cols) & (cy >= 0) & (cy < rows)
            st = np.full(active.size, np.inf)
            st[inside] = step_field[cy[inside] * cols + cx[inside]]
            hit = st < 0.0
            if hit.any():
                h = active[hit]
                out[h] = np.maximum(t[h] - 0.5 * last[h], 0.0)
            # outside the map (inf) or hit: finished; others advance
            go = ~hit & np.isfinite(st)
            active = active[go]
            stp = st[go]
            t_new = t[active] + stp
            last[active] = stp
            t[active] = t_new
            far = t_new >= rmax
            active = active[~far]
        return np.minimum(out, rmax).astype(np.float32)
