"""The reference path over arc length as CasADi bspline lookups (solver-notes "Reference path").

The path the planner contours is a ``ReferencePath``: a closed ``Track``-like polyline with
its own arc length ``s`` and its half-widths to the REAL track's boundaries. Two kinds:

- ``centreline_path(track)``: the track's centreline itself (the paper's CiMPCC and MPCC);
- ``min_time_path(track, lap, ...)``: the minimum-time line of the simulated car
  (``services.planner.mintime.ocp``), driven by its rear axle, with the lap's speed profile
  along it (``cimpcc-line``).

One interpolant ``ref(s) -> [x, y, phi, w_right, w_left]`` over the path tiled to
``s in [-L, 2L)`` with ``phi`` unwrapped, so predicted progress never runs off the table;
the planner wraps the car's ``s`` into ``[0, L)`` every lap.
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import IntEnum

import casadi as ca
import numpy as np

from services.planner.mintime.model import INPUT_NAMES
from services.planner.mintime.ocp import MinTimeLap
from shared.curvature import periodic_spline
from shared.track import Track

#: Spacing [m] of the minimum-time line's polyline (the centrelines' about 4 cm): the
#: segment headings ``phi`` of a polyline lag its true tangent by ``kappa ds / 2``, under
#: 0.025 rad at the tightest 0.8 m radius of the lines here.
LINE_SPACING_M = 0.04

#: The minimum-time lap's acceleration input (``mintime.model.INPUT_NAMES``).
ACCEL_INPUT = "accel_mps2"
#: The kinds of reference path.
CENTRELINE, MIN_TIME_LINE = "centreline", "min-time-line"


class R(IntEnum):
    """Index of each output of the reference lookup."""

    X = 0
    Y = 1
    PHI = 2
    W_RIGHT = 3
    W_LEFT = 4


@dataclass(frozen=True, eq=False)
class SpeedProfile:
    """A speed reference along a path, periodic in its arc length.

    Attributes:
        s_m: (m,) increasing arc length along the path [m], ``s_m[0] = 0``.
        v_mps: (m,) the profile's speed [m/s] (the car's, at its CoG: what the speed loop
            controls).
        command_mps: (m,) the speed to command there [m/s]: ``v_mps`` plus the speed
            loop's lead over the lap's acceleration input (``min_time_path``).
        length_m: period (the path's length) [m].
        lap_time_s: the lap time of the lap the profile comes from [s].
        drag_mps2: (m,) the deceleration [m/s^2] the lap's drive fights there besides
            ``dv/dt`` (the tyres' drag in a bend: its acceleration input minus ``dv/dt``,
            >= 0), or None.
    """

    s_m: np.ndarray
    v_mps: np.ndarray
    command_mps: np.ndarray
    length_m: float
    lap_time_s: float
    drag_mps2: np.ndarray | None = None

    def command_at(self, s: np.ndarray | float) -> np.ndarray:
        """The speed command [m/s] at arc length(s) `s` [m] (wrapped, linear in s)."""
        s_cl = np.append(self.s_m, self.length_m)
        v_cl = np.append(self.command_mps, self.command_mps[0])
        return np.interp(np.mod(s, self.length_m), s_cl, v_cl)

    def drag_at(self, s: np.ndarray | float) -> np.ndarray:
        """The drag [m/s^2] at arc length(s) `s` [m] (wrapped, linear in s; 0 without)."""
        if self.drag_mps2 is None:
            return np.zeros(np.shape(s))
        s_cl = np.append(self.s_m, self.length_m)
        d_cl = np.append(self.drag_mps2, self.drag_mps2[0])
        return np.interp(np.mod(s, self.length_m), s_cl, d_cl)

    def speed_at(self, s: np.ndarray | float) -> np.ndarray:
        """The profile's speed [m/s] at arc length(s) `s` [m] (wrapped, linear in s)."""
        s_cl = np.append(self.s_m, self.length_m)
        v_cl = np.append(self.v_mps, self.v_mps[0])
        return np.interp(np.mod(s, self.length_m), s_cl, v_cl)


@dataclass(frozen=True, eq=False)
class ReferencePath:
    """What the planner contours (see the module docstring).

    Attributes:
        path: the polyline as a ``Track``: its points, its own arc length ``s`` (the
            planner's progress), and its half-widths to the real track's boundaries.
        kind: ``CENTRELINE`` or ``MIN_TIME_LINE``.
        track_s_m: (n,) arc length on the real track's centreline of each path point [m]
            (maps the track's progress to a search hint on the path).
        speed: the speed profile along the path, or None (the centreline has none).
    """

    path: Track
    kind: str
    track_s_m: np.ndarray
    speed: SpeedProfile | None = None

    @property
    def is_centreline(self) -> bool:
        """Whether the path is the track's own centreline (the paper's methods)."""
        return self.kind == CENTRELINE

    def path_s_near(self, track_s: float, track_length_m: float) -> float:
        """Arc length [m] on the path of the path point nearest (in track arc length) to
        the track's arc length `track_s` [m]: a hint for ``Track.project_near``."""
        d = np.abs((self.track_s_m - track_s + track_length_m / 2) % track_length_m
                   - track_length_m / 2)
        return float(self.path.s_m[int(np.argmin(d))])


def centreline_path(track: Track) -> ReferencePath:
    """The track's centreline as the reference path (CiMPCC and MPCC, the paper)."""
    return ReferencePath(track, CENTRELINE, track.s_m)


def min_time_path(
    track: Track,
    lap: MinTimeLap,
    lr_m: float,
    accel_lead_s: float,
    brake_lead_s: float,
    spacing_m: float = LINE_SPACING_M,
) -> ReferencePath:
    """The minimum-time line as a reference path, with its speed profile.

    The lap's nodes (CoG position and yaw) are moved to the rear axle (``p_r = p_cog - l_r
    [cos psi, sin psi]``: the planner's model is the rear axle's bicycle, paper eq. 12),
    joined by the closed cubic spline through them (chord-length parameter) and resampled
    every about `spacing_m`; the nodes keep their speed at their arc length on it. Each
    point's half-widths to the real boundaries come from its projection onto the track's
    centreline (as the lap timer judges): at contour error ``e`` (right +, i.e. ``e = -n``
    with ``n`` the lap's left offset) they are ``w_right - e`` and ``w_left + e``; measured
    along the centreline's normal, they are never wider than along the line's own.

    Speed reference along the line: ``v_cmd(s) = v(s) + T_a max(a(s), 0)
    + T_b min(a(s), 0)`` with the lap's speed ``v`` at each node and ``a`` its acceleration
    input from that node on (the longitudinal acceleration the drive must give: ``dv/dt``
    plus what the tyres' drag in a bend takes). A proportional speed loop ``a = k (v_cmd -
    v)`` (the simulator's, like the gym's) gives that acceleration for ``T = 1 / k``; the
    planner's kinematic model knows no such lag, and without the lead the car would run
    about 0.3 m/s below the profile through a 1 m bend. The profile's drag is that input
    minus the lap's ``dv/dt`` (for a model that holds the car's speed).

    Args:
        track: the real track (its centreline and widths).
        lap: the minimum-time lap of the car on `track`.
        lr_m: CoG to rear axle [m] of the car the lap was solved for.
        accel_lead_s, brake_lead_s: T_a, T_b [s].
        spacing_m: spacing of the resampled polyline [m].
    """
    xr = lap.x_m - lr_m * np.cos(lap.yaw_rad)
    yr = lap.y_m - lr_m * np.sin(lap.yaw_rad)
    nodes = np.column_stack([xr, yr])
    chord = np.hypot(*(np.roll(nodes, -1, axis=0) - nodes).T)
    t_nodes = np.concatenate([[0.0], np.cumsum(chord)[:-1]])
    period = float(chord.sum())
    n_out = max(10, round(period / spacing_m))
    t_out = np.arange(n_out) * (period / n_out)
    xy = periodic_spline(nodes, t_nodes, period, t_out)
    track_s, e = track.project(xy)
    w_r, w_l = track.interp_width(track_s)
    path = Track(f"{track.name}-min-time-line", xy, w_r - e, w_l + e, source=track.source)
    # the nodes' arc length on the resampled polyline (the spline passes through them)
    s_nodes = np.interp(t_nodes, np.append(t_out, period), np.append(path.s_m, path.length_m))
    a = lap.inputs[:, INPUT_NAMES.index(ACCEL_INPUT)]
    v = lap.v_mps
    command = v + accel_lead_s * np.maximum(a, 0.0) + brake_lead_s * np.minimum(a, 0.0)
    # dv/dt from node k to k+1 (the input acts from node k on), the lap closed
    t_next = np.append(lap.t_s[1:], lap.lap_time_s)
    drag = np.maximum(a - (np.roll(v, -1) - v) / (t_next - lap.t_s), 0.0)
    speed = SpeedProfile(s_nodes, v, command, path.length_m, lap.lap_time_s, drag)
    for arr in (track_s, s_nodes, command, speed.v_mps, drag):
        arr.setflags(write=False)
    return ReferencePath(path, MIN_TIME_LINE, track_s, speed)


def reference_table(track: Track) -> tuple[np.ndarray, np.ndarray]:
    """Grid ``s_ext`` (m,) [m] and values (m, 5) of the reference tiled over [-L, 2L].

    phi is the unwrapped tangent heading [rad]; it grows by the loop's total turn (+-2 pi)
    from one tile to the next. `track` is any closed path with widths (e.g.
    ``ReferencePath.path``).
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
    """``ref(s) -> [x, y, phi, w_right, w_left]`` (5,) as a cubic bspline interpolant over s
    of the closed path `track` (a track's centreline or ``ReferencePath.path``)."""
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
