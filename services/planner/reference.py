"""The reference path over arc length as CasADi bspline lookups (solver-notes "Reference path").

One interpolant ``ref(s) -> [x, y, phi, w_right, w_left]`` over the track tiled to
``s in [-L, 2L)`` with ``phi`` unwrapped, so predicted progress never runs off the table;
the planner wraps the car's ``s`` into ``[0, L)`` every lap.
"""

from __future__ import annotations

from enum import IntEnum

import casadi as ca
import numpy as np

from shared.track import Track


class R(IntEnum):
    """Index of each output of the reference lookup."""

    X = 0
    Y = 1
    PHI = 2
    W_RIGHT = 3
    W_LEFT = 4


def reference_table(track: Track) -> tuple[np.ndarray, np.ndarray]:
    """Grid ``s_ext`` (m,) [m] and values (m, 5) of the reference tiled over [-L, 2L].

    phi is the unwrapped tangent heading [rad]; it grows by the loop's total turn (+-2 pi)
    from one tile to the next.
    """
    s, x, y, phi = track.closed_arrays()
    w_r = np.append(track.w_right_m, track.w_right_m[0])
    w_l = np.append(track.w_left_m, track.w_left_m[0])
    L = track.length_m
    turn = phi[-1] - phi[0]
    # drop the duplicated closing point inside the tiling, keep the very last one
    base = slice(0, -1)
    tiles_s, tiles_v = [], []
    for k in (-1, 0, 1):
        tiles_s.append(s[base] + k * L)
        tiles_v.append(
            np.column_stack([x[base], y[base], phi[base] + k * turn, w_r[base], w_l[base]])
        )
    tiles_s.append([2 * L])
    tiles_v.append([[x[0], y[0], phi[0] + 2 * turn, w_r[0], w_l[0]]])
    return np.concatenate(tiles_s), np.vstack(tiles_v)


def reference_lookup(track: Track) -> ca.Function:
    """``ref(s) -> [x, y, phi, w_right, w_left]`` (5,) as a cubic bspline interpolant over s."""
    s_ext, values = reference_table(track)
    # CasADi wants the outputs of each grid point consecutively (output index fastest)
    return ca.interpolant("ref", "bspline", [s_ext.tolist()], values.ravel().tolist())


def track_errors(ref_at_s: ca.SX | ca.MX, x: ca.SX | ca.MX, y: ca.SX | ca.MX) -> tuple:
    """Contour and lag error of position (x, y) against the reference at its progress s.

    ``e_con = sin(phi_ref)(x - x_ref) - cos(phi_ref)(y - y_ref)`` (positive right of the path),
    ``e_lag = -cos(phi_ref)(x - x_ref) - sin(phi_ref)(y - y_ref)`` (paper Fig. 2).
    """
    dx = x - ref_at_s[R.X]
    dy = y - ref_at_s[R.Y]
    c = ca.cos(ref_at_s[R.PHI])
    s = ca.sin(ref_at_s[R.PHI])
    return s * dx - c * dy, -c * dx - s * dy
