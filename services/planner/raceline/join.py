"""Joining the racing line from wherever the car stands: a smooth blend, as data (no I/O).

A car started (or handed back by the recovery rule, or moved) away from its line used to
steer for the line at once, at full lock and full throttle: on map416 it crossed the line
at 3.8 m/s and 0.2 rad and ran on over the wall where the line hugs it (13 of 30 random
standing starts left the track). Instead, the path the tracker drives during a join is a
blend, in the track's lateral coordinate, of where the car stood and the line::

    p(s) = w(u) e_0 + (1 - w(u)) q(s),   w(u) = 1 - (10 u^3 - 15 u^4 + 6 u^5),   u = (s - s_0) / L

with ``e_0`` the car's lateral position at the start, ``q(s)`` the line's (both right +,
from the centreline, [m]) and ``s`` the line's arc length [m]. Both ends lie inside the
track, so every blend of them does (up to the two normals' small angle); ``w`` (the
"smootherstep") leaves 1 and reaches 0 with zero slope and zero curvature, so the path
starts parallel to the track and meets the line tangentially, with no step in the
steering at either end (a cosine's curvature step left the car 2 cm past the line at the
end, where the line runs 2 cm from the wall). The tracker drives it as an offset from the
line, ``d(s) = p(s) - q(s) = w(u) (e_0 - q(s))`` (``Tracker.command``'s ``offset_m``), with
its slope ``d'(s)`` so the heading error is taken from the blended path, not the line.

``L`` is the length over which the lateral move keeps the path's slope within
``max_slope`` (the smootherstep's steepest slope is ``15 |D| / (8 L)`` for a move ``D``), at
least ``min_length_m``; ``D`` is the largest gap between ``e_0`` and the line over the
blend. Where that path would bend tighter than the car can steer (the centreline of a
hairpin is tighter than the car's turning circle, the line is not), shorter blends are
tried (``LENGTH_SHARES``) and the one whose tightest bend is least is kept; when even that
one is tighter than the car's turning circle, there is no blend (the tracker joins the
line directly, as it did before).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from functools import cached_property

import numpy as np

#: Steepest slope of the blended path against the line [m/m] (about 6 degrees).
MAX_SLOPE = 0.1
#: Shortest blend [m].
MIN_LENGTH_M = 1.0
#: A car closer to its line than this [m], where the line runs along the track within
#: this slope [m/m], needs no blend (the blend leaves along the track: a car put down on
#: the line where the line crosses the track stood 0.2-0.3 rad across it, and ramping up
#: from rest the identified car strayed 28 cm from its line on gen-7).
ON_LINE_M = 0.02
ON_LINE_SLOPE = 0.05
#: Rounds of lengthening the blend for the gap ahead.
ITERATIONS = 3
#: Step of the slope's central difference [m].
SLOPE_STEP_M = 0.05
#: The smootherstep's steepest slope per unit move and length.
STEEPEST = 15.0 / 8.0
#: Shares of the slope-limited length tried when that blend bends too tight for the car.
LENGTH_SHARES = (1.0, 0.75, 0.5, 0.35, 0.25)
#: Stations per metre at which a candidate blend's curvature is checked [1/m].
CHECK_PER_M = 4.0


def smootherstep_weight(u: float) -> float:
    """w(u) = 1 - (10 u^3 - 15 u^4 + 6 u^5): 1 at u = 0, 0 at u = 1, flat at both ends."""
    u = min(max(u, 0.0), 1.0)
    return 1.0 - u * u * u * (10.0 + u * (-15.0 + 6.0 * u))


#: The line's points (k, 2) [m] and right normals (k, 2) at stations (k,) [m].
LineGeometry = Callable[[np.ndarray], tuple[np.ndarray, np.ndarray]]


@dataclass(frozen=True)
class LineJoin:
    """One join: from the car's lateral position `e0_m` at line station `s0_m` onto the line.

    Attributes:
        s0_m: the line's arc length where the join starts [m].
        e0_m: the car's lateral position from the centreline there (right +) [m].
        length_m: L, the blend's length along the line [m].
        line_length_m: the line's length [m] (stations wrap).
        line_s_m: (n,) the line's stations [m].
        line_e_m: (n,) q, the line's lateral position from the centreline (right +) [m].
    """

    s0_m: float
    e0_m: float
    length_m: float
    line_length_m: float
    line_s_m: np.ndarray
    line_e_m: np.ndarray

    @classmethod
    def start(
        cls,
        s0_m: float,
        e0_m: float,
        line_s_m: np.ndarray,
        line_e_m: np.ndarray,
        line_length_m: float,
        max_slope: float | None = None,
        min_length_m: float | None = None,
        line_xy: LineGeometry | None = None,
        max_curvature_1pm: float = math.inf,
        turn_curvature_1pm: float = math.inf,
    ) -> LineJoin | None:
        """The join from (`s0_m`, `e0_m`) (see the module docstring), or None when the car
        is within ``ON_LINE_M`` of the line already and the line runs along the track there
        (``ON_LINE_SLOPE``). `line_s_m`, `line_e_m`: (n,) the
        line's stations and lateral positions (right +) [m]; `line_xy`: the line's points
        and right normals at stations (``path_curvature``), with `max_curvature_1pm` the
        tightest bend a join may take [1/m]: a blend that bends tighter is shortened
        (module docstring); when even the least tight one bends tighter than the car can
        turn at all (`turn_curvature_1pm`, [1/m]: a start at a hairpin's entry, where the
        line swings out and the centreline is tighter than the car's turning circle),
        None: the tracker joins the line directly."""
        max_slope = MAX_SLOPE if max_slope is None else max_slope
        min_length_m = MIN_LENGTH_M if min_length_m is None else min_length_m
        s = np.asarray(line_s_m, dtype=float)
        q = np.asarray(line_e_m, dtype=float)
        probe = cls(s0_m, e0_m, min_length_m, line_length_m, s, q)
        gap = abs(e0_m - probe.line_e(s0_m))
        h = SLOPE_STEP_M
        line_slope = float(probe.line_e(s0_m + h) - probe.line_e(s0_m - h)) / (2.0 * h)
        if gap < ON_LINE_M and abs(line_slope) < ON_LINE_SLOPE:
            return None
        length = min_length_m
        for _ in range(ITERATIONS):  # the gap ahead may be larger than at the start
            ahead = s0_m + np.linspace(0.0, length, 16)
            gap = max(gap, float(np.max(np.abs(e0_m - probe.line_e(ahead)))))
            length = max(length, STEEPEST * gap / max_slope)
        length = min(length, 0.5 * line_length_m)
        best: tuple[float, LineJoin] | None = None
        for share in LENGTH_SHARES if line_xy is not None else (1.0,):
            join = cls(s0_m, e0_m, max(share * length, min_length_m), line_length_m, s, q)
            if line_xy is None:
                return join
            tightest = join.tightest_curvature(line_xy)
            if best is None or tightest < best[0]:
                best = (tightest, join)
            if tightest <= max_curvature_1pm:
                return join
        if best is None or best[0] > turn_curvature_1pm:
            return None
        return best[1]

    def tightest_curvature(self, line_xy: LineGeometry) -> float:
        """The largest |kappa| [1/m] of the blended path over the whole join."""
        n = max(int(self.length_m * CHECK_PER_M), 4)
        ahead = self.s0_m + np.linspace(0.0, self.length_m, n + 1)
        return float(np.max(np.abs(self.path_curvatures(ahead, line_xy))))

    def line_e(self, s_m: float | np.ndarray) -> np.ndarray:
        """q(s): the line's lateral position from the centreline (right +) [m]."""
        s_cl, q_cl = self._closed_line
        return np.interp(np.mod(s_m, self.line_length_m), s_cl, q_cl)

    @cached_property
    def _closed_line(self) -> tuple[np.ndarray, np.ndarray]:
        """(s, q) with the last station one lap back and the first one lap on: ``line_e``'s
        table (``np.interp``'s ``period`` builds the same one, sorting the stations, in
        every call: 0.3-0.7 ms a tick during a join)."""
        L = self.line_length_m
        s, q = self.line_s_m, self.line_e_m
        return (np.concatenate([[s[-1] - L], s, [s[0] + L]]),
                np.concatenate([[q[-1]], q, [q[0]]]))

    def progress(self, s_m: float) -> float:
        """u: how far the join has come at line station `s_m`, 0 at the start, 1 at its end
        (stations behind the start count as 0)."""
        ahead = (s_m - self.s0_m) % self.line_length_m
        if ahead > 0.75 * self.line_length_m:  # just behind the start (a wobble back)
            return 0.0
        return min(ahead / self.length_m, 1.0)

    def done(self, s_m: float) -> bool:
        """True once the car is past the blend's end."""
        return self.progress(s_m) >= 1.0

    def offset(self, s_m: float) -> float:
        """d(s) = w(u) (e_0 - q(s)): the blended path's offset from the line (right +) [m]."""
        w = smootherstep_weight(self.progress(s_m))
        return w * (self.e0_m - float(self.line_e(s_m)))

    def slope(self, s_m: float) -> float:
        """d'(s): the offset's change along the line [m/m] (central difference)."""
        h = SLOPE_STEP_M
        return (self.offset(s_m + h) - self.offset(s_m - h)) / (2.0 * h)

    def offsets(self, s_m: np.ndarray) -> np.ndarray:
        """``offset`` at each of the stations `s_m` (k,) [m], at once (k,) [m]."""
        s = np.asarray(s_m, dtype=float)
        ahead = np.mod(s - self.s0_m, self.line_length_m)
        u = np.where(ahead > 0.75 * self.line_length_m, 0.0,
                     np.minimum(ahead / self.length_m, 1.0))
        w = 1.0 - u * u * u * (10.0 + u * (-15.0 + 6.0 * u))  # smootherstep_weight
        return w * (self.e0_m - self.line_e(s))

    def path_curvature(
        self,
        s_m: float,
        line_xy: LineGeometry,
        step_m: float = 0.3,
    ) -> float:
        """kappa [1/m] (left +) of the blended path at line station `s_m`: the circle through
        its points at ``s - step``, ``s``, ``s + step``; `line_xy` maps stations (k,) to the
        line's points (k, 2) and their right normals, ``(points, normals)``."""
        return float(self.path_curvatures(np.array([s_m]), line_xy, step_m)[0])

    def path_curvatures(
        self,
        s_m: np.ndarray,
        line_xy: LineGeometry,
        step_m: float = 0.3,
    ) -> np.ndarray:
        """``path_curvature`` at each of the stations `s_m` (k,), at once (k,) [1/m]: one
        call of `line_xy` and of ``offsets`` for all of them (a join's feed and its
        check took 4 ms a tick station by station)."""
        centre = np.asarray(s_m, dtype=float)
        s = np.concatenate([centre - step_m, centre, centre + step_m])
        pts, normals = line_xy(s)
        p = pts + self.offsets(s)[:, None] * normals
        a, b, c = np.split(p, 3)
        ab, bc, ca = b - a, c - b, a - c
        cross = ab[:, 0] * bc[:, 1] - ab[:, 1] * bc[:, 0]
        den = np.sqrt(np.sum(ab * ab, axis=1) * np.sum(bc * bc, axis=1)
                      * np.sum(ca * ca, axis=1))
        return np.where(den > 1e-12, 2.0 * cross / np.maximum(den, 1e-300), 0.0)
