"""The particle filter's sensor model: a likelihood field on the occupancy map (no I/O).

For a beam end point ``e`` (map frame) the distance ``d(e)`` [m] to the nearest wall surface
(the border between free and blocked cells, measured from either side, so an end point behind
a wall is as unlikely as one in front of it) gives the beam's normalised likelihood

    q(e) = z_hit exp(-d(e)^2 / (2 sigma^2)) + z_rand        (0 < q <= z_hit + z_rand <= 1)

and a particle's log likelihood is ``sum_beams log q``. ``log q`` is tabulated per cell of a
grid `upsample` times finer than the map (distance at the sub-cell centres, capped at
``cap_m``; cells outside the map read as the cap), so scoring is one table look-up per beam.
Tables exist for a ladder of sigmas ``sigma_0 2^k`` (the filter anneals from the widest to the
narrowest as its cloud contracts).
"""

from __future__ import annotations

import math

import numpy as np

from shared.track.occupancy import OccupancyGrid
from shared.track.raycast import blocked_cells, distance_transform, to_grid_frame

#: Cells of padding around the table (end points outside the map read the cap).
PAD_CELLS = 2


def wall_distance_m(blocked: np.ndarray, cell_m: float, cap_m: float) -> np.ndarray:
    """Distance [m] from each cell centre to the free / blocked border, either side.

    Args:
        blocked: (rows, cols) bool.
        cell_m: cell edge [m].
        cap_m: distances above read as this [m].

    Returns:
        (rows, cols) float32 ``max(edt - cell / 2, 0)`` with ``edt`` the centre-to-centre
        distance to the nearest cell of the other kind (cell / 2 for cells on the border).
    """
    cap_cells = max(1, math.ceil(cap_m / cell_m) + 1)
    d_free = distance_transform(blocked, cap_cells)  # in free cells: to the nearest blocked
    d_blocked = distance_transform(~blocked, cap_cells)  # in blocked cells: to the nearest free
    edt = np.where(blocked, d_blocked, d_free).astype(np.float32) * np.float32(cell_m)
    return np.clip(edt - np.float32(0.5 * cell_m), 0.0, np.float32(cap_m))


class LikelihoodField:
    """Tabulated ``log q`` of the module docstring for a ladder of sigmas.

    Args:
        grid: the map.
        sigmas_m: (L,) hit sigmas [m], ascending.
        z_hit, z_rand: mixture weights [-].
        cap_m: distance cap [m].
        upsample: sub-cells per map cell edge (>= 1).
        unknown_is_occupied: UNKNOWN cells count as blocked.
    """

    def __init__(
        self,
        grid: OccupancyGrid,
        sigmas_m: tuple[float, ...],
        z_hit: float,
        z_rand: float,
        cap_m: float,
        upsample: int = 2,
        unknown_is_occupied: bool = True,
    ) -> None:
        self.grid = grid
        self.sigmas_m = tuple(float(s) for s in sigmas_m)
        up = max(1, int(upsample))
        blocked = blocked_cells(grid, unknown_is_occupied)
        fine = np.repeat(np.repeat(blocked, up, axis=0), up, axis=1)
        self.cell_m = float(grid.resolution_m) / up
        dist = wall_distance_m(fine, self.cell_m, cap_m)
        dist = np.pad(dist, PAD_CELLS, constant_values=np.float32(cap_m))
        self.distance_m = dist  # padded, (rows + 2 P, cols + 2 P)
        self.rows, self.cols = dist.shape
        d2 = dist.astype(np.float64) ** 2
        self._tables = [
            np.log(z_hit * np.exp(-d2 / (2.0 * s * s)) + z_rand).astype(np.float32).ravel()
            for s in self.sigmas_m
        ]
        self.log_q_max = math.log(z_hit + z_rand)
        s0 = self.sigmas_m[0]
        self._hit = np.exp(-d2 / (2.0 * s0 * s0)).astype(np.float32).ravel()

    def hit_fraction(
        self, pose: np.ndarray, beam_x_m: np.ndarray, beam_y_m: np.ndarray
    ) -> float:
        """Mean over the beams of ``exp(-d^2 / (2 sigma_0^2))`` for one (3,) pose: the soft
        fraction of beams that end on a mapped wall (1: all, 0: none) [-]."""
        flat = self._cells(np.asarray(pose, dtype=float).reshape(1, 3), beam_x_m, beam_y_m)
        return float(self._hit.take(flat).mean())

    def log_likelihood(
        self,
        poses: np.ndarray,
        beam_x_m: np.ndarray,
        beam_y_m: np.ndarray,
        level: int,
    ) -> np.ndarray:
        """Summed ``log q`` of each pose's beam end points.

        End point of beam k of pose i in table cells (float32, the hot path):
        ``f = (g_i + R(psi_i) b_k) / cell + PAD_CELLS``, truncated and clipped into the table.

        Args:
            poses: (N, 3) [x m, y m, yaw rad] map frame.
            beam_x_m, beam_y_m: (K,) beam end points in the car frame [m].
            level: index into `sigmas_m`.

        Returns:
            (N,) float64 log likelihoods.
        """
        flat = self._cells(poses, beam_x_m, beam_y_m)
        return self._tables[level].take(flat).sum(axis=1, dtype=np.float64)

    def _cells(self, poses: np.ndarray, beam_x_m: np.ndarray, beam_y_m: np.ndarray) -> np.ndarray:
        """(N, K) int32 flat table indices of the beam end points (see log_likelihood)."""
        g = self.grid
        inv = 1.0 / self.cell_m
        gx, gy = to_grid_frame(g, poses[:, 0], poses[:, 1])
        th = poses[:, 2] - g.origin_yaw_rad
        c = np.cos(th).astype(np.float32)[:, None]
        s = np.sin(th).astype(np.float32)[:, None]
        bx = (np.asarray(beam_x_m) * inv).astype(np.float32)
        by = (np.asarray(beam_y_m) * inv).astype(np.float32)
        fx = c * bx
        fx -= s * by
        fx += (gx * inv + PAD_CELLS).astype(np.float32)[:, None]
        fy = s * bx
        fy += c * by
        fy += (gy * inv + PAD_CELLS).astype(np.float32)[:, None]
        np.clip(fx, 0.0, self.cols - 1, out=fx)
        np.clip(fy, 0.0, self.rows - 1, out=fy)
        flat = fy.astype(np.int32)
        flat *= self.cols
        flat += fx.astype(np.int32)
        return flat
