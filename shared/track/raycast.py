"""Distance transform and vectorised ray marching on an occupancy grid (numpy only).

Shared by the simulator's lidar (``services/simulator/lidar.py``) and the localization
bridge's particle filter (``services/localization_bridge/``), which must not import each other.

Distance transform: for every cell the Euclidean distance between its centre and the nearest
blocked cell's centre, computed exactly up to a cap ``D`` (larger distances read as ``D``,
still a valid lower bound):

1. per column, the vertical distance ``g`` [cells] to the nearest blocked cell (running
   maximum / minimum of blocked row indices), capped at ``D + 1``;
2. per row, ``d^2(i, j) = min_{|k| <= D} g(i, j + k)^2 + k^2`` (2D + 1 shifted minima).

Exact where the true distance is <= D: the nearest blocked cell then lies within D columns.

Ray marching (all rays at once): a point inside a free cell whose centre is ``d`` from the
nearest blocked centre is at least ``d - sqrt(2) r`` from any blocked cell (r = cell size), so
each ray advances by ``max(d - sqrt(2) r, r / 2)`` until it reaches a blocked cell (range =
midpoint of the last step, error <= r / 4 plus the rasterisation), leaves the map or passes
``range_max`` (both: ``range_max``, no return).

The march is numpy-vectorised over the rays, so its cost is per iteration, and its last
iterations carry few rays (the long ones and those grazing a wall, which crawl at r / 2).
After ``MARCH_STEPS`` steps the rays still going (per ray, so a ray's range does not depend
on the rays cast with it) instead sample, per iteration, the next
``EDT_CAP_M`` of every remaining ray at r / 2 spacing in one (rays, samples) array and
takes its first blocked sample (range = that sample - r / 4, the same error bound): a
scan's iterations drop from 40-90 to about 15-25 (1080 beams on map416: 1.6x cheaper).
The cell lookup goes through a field padded with one "outside" cell around the map, so no
bounds test per sample.
"""

from __future__ import annotations

import math

import numpy as np

from shared.track.occupancy import OCCUPIED, UNKNOWN, OccupancyGrid

#: Distances in the ray-marching transform are exact up to this [m]; rays step at most this far.
EDT_CAP_M = 2.0
#: Rays still going after this many steps are sampled at r / 2 instead (module docstring).
MARCH_STEPS = 12

__all__ = ["EDT_CAP_M", "RayMarcher", "blocked_cells", "distance_transform", "to_grid_frame"]


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


def blocked_cells(grid: OccupancyGrid, unknown_is_occupied: bool = True) -> np.ndarray:
    """(rows, cols) bool: the cells that stop a beam (OCCUPIED, and UNKNOWN if asked)."""
    cells = np.asarray(grid.cells)
    blocked = cells == OCCUPIED
    if unknown_is_occupied:
        blocked |= cells == UNKNOWN
    return blocked


def to_grid_frame(
    grid: OccupancyGrid, x_m: np.ndarray | float, y_m: np.ndarray | float
) -> tuple[np.ndarray, np.ndarray]:
    """Map-frame points [m] -> grid-frame points [m] (from the grid's lower-left corner, along
    its axes; cell (row, col) covers ``col r <= gx < (col + 1) r``, ``row r <= gy < ...``)."""
    ox, oy = float(grid.origin_xy_m[0]), float(grid.origin_xy_m[1])
    c0, s0 = math.cos(-grid.origin_yaw_rad), math.sin(-grid.origin_yaw_rad)
    px = np.asarray(x_m, dtype=float) - ox
    py = np.asarray(y_m, dtype=float) - oy
    return c0 * px - s0 * py, s0 * px + c0 * py


class RayMarcher:
    """Ray casting on a fixed occupancy grid by distance-field-accelerated ray marching.

    Args:
        grid: the map.
        unknown_is_occupied: whether UNKNOWN cells stop rays (OCCUPIED ones always do).
        cap_m: cap of the distance transform [m] (the longest single step).

    Attributes:
        distance_m: (rows, cols) float64 distance [m] from each cell centre to the nearest
            blocked centre, capped at `cap_m`.
    """

    def __init__(
        self, grid: OccupancyGrid, unknown_is_occupied: bool = True, cap_m: float = EDT_CAP_M
    ) -> None:
        self.grid = grid
        self.unknown_is_occupied = bool(unknown_is_occupied)
        blocked = blocked_cells(grid, unknown_is_occupied)
        r = float(grid.resolution_m)
        self.resolution_m = r
        cap = max(1, int(cap_m / r))
        dist_m = distance_transform(blocked, cap).astype(np.float64) * r
        step = np.maximum(dist_m - math.sqrt(2.0) * r, 0.5 * r)
        # flat step field padded with one cell around the map: a negative value marks a
        # blocked cell, 0 a cell outside the map
        rows, cols = blocked.shape
        padded = np.zeros((rows + 2, cols + 2))
        padded[1:-1, 1:-1] = np.where(blocked, -1.0, step)
        self._step = padded.ravel()
        self._rows, self._cols = rows, cols
        self._tail_samples = max(1, round(cap_m / (0.5 * r)))
        self.distance_m = dist_m

    def _field_at(self, gx: np.ndarray, gy: np.ndarray) -> np.ndarray:
        """The step field at grid-frame points [m] (any shape): < 0 blocked, 0 outside the
        map, else the safe step [m]."""
        inv_r = 1.0 / self.resolution_m
        cols, rows = self._cols, self._rows
        cx = np.floor(gx * inv_r)
        cy = np.floor(gy * inv_r)
        np.clip(cx, -1.0, cols, out=cx)
        np.clip(cy, -1.0, rows, out=cy)
        cy += 1.0
        cy *= cols + 2
        cy += cx
        cy += 1.0
        return self._step[cy.astype(np.intp)]

    def cast(
        self,
        x_m: np.ndarray | float,
        y_m: np.ndarray | float,
        angle_rad: np.ndarray | float,
        range_max_m: float,
    ) -> np.ndarray:
        """Ranges [m] of rays from (x, y) [m] along `angle_rad` [rad] (map frame).

        The three arguments broadcast to one shape ``S``; returns float64 ``S`` ranges, at most
        `range_max_m` (= no return: beyond range or out of the map), 0 for a ray starting in a
        blocked cell.
        """
        g = self.grid
        gx0, gy0 = to_grid_frame(g, x_m, y_m)
        ang0 = np.asarray(angle_rad, dtype=float) - g.origin_yaw_rad
        gx0, gy0, ang0 = np.broadcast_arrays(gx0, gy0, ang0)
        shape = ang0.shape
        gx, gy = gx0.ravel(), gy0.ravel()
        ang = ang0.ravel()
        n = ang.size
        dx, dy = np.cos(ang), np.sin(ang)
        out = np.full(n, float(range_max_m), dtype=np.float64)
        t = np.zeros(n)
        last = np.zeros(n)
        active = np.arange(n)
        rmax = float(range_max_m)
        for _ in range(MARCH_STEPS):
            if not active.size:
                break
            ta = t[active]
            st = self._field_at(gx[active] + ta * dx[active], gy[active] + ta * dy[active])
            hit = st < 0.0
            if hit.any():
                h = active[hit]
                out[h] = np.maximum(t[h] - 0.5 * last[h], 0.0)
            # outside the map (0) or hit: finished; others advance
            go = st > 0.0
            active = active[go]
            stp = st[go]
            t_new = ta[go] + stp
            last[active] = stp
            t[active] = t_new
            active = active[t_new < rmax]
        if active.size:  # the tail: its current points first (not yet looked up)
            ta = t[active]
            st = self._field_at(gx[active] + ta * dx[active], gy[active] + ta * dy[active])
            hit = st < 0.0
            if hit.any():
                h = active[hit]
                out[h] = np.maximum(t[h] - 0.5 * last[h], 0.0)
            active = active[st > 0.0]
        half = 0.5 * self.resolution_m
        offsets = half * np.arange(1, self._tail_samples + 1)  # (K,) [m]
        while active.size:  # then EDT_CAP_M of samples at r / 2 per iteration
            ts = t[active][:, None] + offsets[None, :]  # (A, K)
            st = self._field_at(gx[active][:, None] + ts * dx[active][:, None],
                                gy[active][:, None] + ts * dy[active][:, None])
            st[ts >= rmax] = 0.0  # beyond range: no return
            event = st <= 0.0
            ended = event.any(axis=1)
            k = event.argmax(axis=1)
            rows_ = np.arange(active.size)
            blocked = ended & (st[rows_, k] < 0.0)
            out[active[blocked]] = ts[rows_[blocked], k[blocked]] - 0.5 * half
            keep = ~ended
            active = active[keep]
            t[active] = ts[keep, -1]
        return np.minimum(out, rmax).reshape(shape)
