"""The reference line of the minimum-time lap: a smooth, arc-length parametrised centreline.

Pure maths, no I/O. The optimal-control problem (``services.planner.mintime.ocp``) writes the
car's position in curvilinear coordinates ``(s, n)`` about a reference curve ``c(s)``:
``p = c(s) + n N(s)`` with ``N`` the unit LEFT normal (``n`` positive left; the track's
``e_con`` is positive right, so ``n = -e_con`` on the reference). It needs the curve's
heading ``theta(s)`` and signed curvature ``kappa(s) = theta'(s)`` (positive for left
turns, as ``Track.signed_curvature``) at any arc length, smooth enough to differentiate.

The curve is the closed interpolating cubic spline through the centreline points
(``shared.curvature.periodic_spline``, chord-length parameter ``t``): it passes through
every point, so it stays within ``kappa h^2 / 8`` of the polyline (under 1 mm for 4 cm
points, under 1 cm for the F1TENTH maps' 0.4 m). Its derivatives come from central
differences of the cubic pieces (``SPLINE_STEP``: exact within a piece up to rounding), its
arc length ``s(t)`` from the trapezoid rule on ``|c'(t)|`` at ``ARC_SAMPLES_PER_POINT``
samples per centreline segment, and ``t(s)`` by interpolating that table.

Boundaries: the lap timer judges the car against the polyline centreline and its linearly
interpolated widths (``services.simulator.laps``). The widths here are measured from the
reference curve: a reference point at contour error ``e`` (right +) of the polyline is
``w_left + e`` from the left boundary and ``w_right - e`` from the right one.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from shared.curvature import periodic_spline
from shared.track import Track

#: Parameter step [m] of the central differences on the spline.
SPLINE_STEP = 1e-4
#: Arc-length samples per centreline segment (trapezoid rule on |c'(t)|).
ARC_SAMPLES_PER_POINT = 16


@dataclass(frozen=True, eq=False)
class CurvePoints:
    """The reference curve at given arc lengths (arrays of one shape ``(m,)``).

    Attributes:
        s_m: arc length along the reference [m].
        xy: (m, 2) position [m].
        heading_rad: tangent heading theta [rad] (unwrapped along the input order).
        kappa_1pm: signed curvature [1/m], positive for left turns.
    """

    s_m: np.ndarray
    xy: np.ndarray
    heading_rad: np.ndarray
    kappa_1pm: np.ndarray


@dataclass(frozen=True, eq=False)
class ReferenceLine:
    """The smooth closed reference curve of a track (see the module docstring).

    Attributes:
        track: the track it was built from.
        length_m: arc length of the closed curve [m] (slightly above the polyline's).
        t_table: (k,) spline parameters (chord length of the track's polyline) [m].
        s_table: (k,) arc length of the curve at ``t_table`` [m]; both increase to the
            closing values ``track.length_m`` and ``length_m``.
    """

    track: Track
    length_m: float
    t_table: np.ndarray
    s_table: np.ndarray

    def points(self, s_m: np.ndarray) -> CurvePoints:
        """Position, heading and curvature at arc lengths `s_m` [m] (wrapped into the lap)."""
        s = np.asarray(s_m, dtype=float).reshape(-1)
        t = np.interp(np.mod(s, self.length_m), self.s_table, self.t_table)
        p, d1, d2 = spline_derivatives(self.track, t)
        heading = np.unwrap(np.arctan2(d1[:, 1], d1[:, 0]))
        speed2 = np.einsum("ij,ij->i", d1, d1)
        kappa = (d1[:, 0] * d2[:, 1] - d1[:, 1] * d2[:, 0]) / speed2**1.5
        return CurvePoints(s, p, heading, kappa)

    def effective_curvature(self, s_m: np.ndarray, d_m: float, samples: int = 9) -> np.ndarray:
        """Curvature [1/m] of the circle that deviates from the tangent at `s_m` as the
        curve does at distance `d_m` [m] along it (ahead > 0, behind < 0).

        Small-angle deviation of the curve from its tangent at ``s``:
        ``y(d) = integral_0^d (d - w) kappa(s + w) dw``; the result is ``2 y(d) / d^2``
        (the curvature itself where it is constant; Simpson's rule on `samples` points).
        """
        s = np.asarray(s_m, dtype=float).reshape(-1)
        w = np.linspace(0.0, d_m, samples)
        k = self.points((s[:, None] + w[None, :]).reshape(-1)).kappa_1pm.reshape(s.size, -1)
        simpson = np.ones(samples)
        simpson[1:-1:2], simpson[2:-1:2] = 4.0, 2.0
        y = (k * (d_m - w)[None, :] * simpson[None, :]).sum(axis=1) * (d_m / (samples - 1)) / 3
        return 2.0 * y / (d_m * d_m)

    def widths(self, xy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(w_left, w_right) [m] from reference points `xy` (m, 2) to the track boundaries."""
        s_poly, e = self.track.project(np.asarray(xy, dtype=float).reshape(-1, 2))
        w_r, w_l = self.track.interp_width(s_poly)
        return np.asarray(w_l + e, dtype=float), np.asarray(w_r - e, dtype=float)


def spline_derivatives(track: Track, t: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The centreline spline and its first two derivatives at parameters `t` [m].

    Returns:
        (c, c', c'') each (m, 2): position [m], d/dt [-], d^2/dt^2 [1/m].
    """
    t = np.asarray(t, dtype=float).reshape(-1)
    h = SPLINE_STEP
    pts = periodic_spline(
        track.xy, track.s_m, track.length_m, np.concatenate([t - h, t, t + h])
    )
    m = t.size
    lo, mid, hi = pts[:m], pts[m : 2 * m], pts[2 * m :]
    return mid, (hi - lo) / (2.0 * h), (hi - 2.0 * mid + lo) / (h * h)


def reference_line(track: Track) -> ReferenceLine:
    """The reference curve of `track` with its arc-length table (module docstring)."""
    k = ARC_SAMPLES_PER_POINT * track.n_points
    t = np.linspace(0.0, track.length_m, k + 1)
    _, d1, _ = spline_derivatives(track, t)
    speed = np.hypot(d1[:, 0], d1[:, 1])
    s = np.concatenate([[0.0], np.cumsum(0.5 * (speed[1:] + speed[:-1]) * np.diff(t))])
    for arr in (t, s):
        arr.setflags(write=False)
    return ReferenceLine(track, float(s[-1]), t, s)


def windowed_min(values: np.ndarray, half_window: int) -> np.ndarray:
    """Periodic running minimum: ``out_i = min(values_(i-k .. i+k))``, ``k = half_window``."""
    v = np.asarray(values, dtype=float)
    out = v.copy()
    for shift in range(1, max(0, half_window) + 1):
        out = np.minimum(out, np.minimum(np.roll(v, shift), np.roll(v, -shift)))
    return out
