"""The minimum-time lap of the simulator's car: an offline optimal-control problem.

Pure maths, no I/O: ``solve_min_time(track, vehicle, settings) -> MinTimeLap``.

Problem. Over one closed lap of the reference line (``services.planner.mintime.track``)
of length ``L``, with the car's equations along it (``services.planner.mintime.model``:
state ``x = [n, xi, v, beta, r, delta]``, input ``u = [sv, a]``)::

    minimise   T = integral_0^L (1 - n kappa) / (v cos(xi + beta)) ds
    subject to dx/ds = f(x, u, kappa(s)),   x(L) = x(0)                       (periodic)
               F_xi^2 + F_yi^2 <= (f_e mu_i F_zi)^2 per axle                   (friction)
               |alpha_i| <= f_s alpha_peak,i                      (pacejka tyres only)
               steering_min <= delta <= steering_max,  sv_min <= sv <= sv_max
               |a| <= min(a_max, min_i mu_i g),  a v <= a_max v_switch   (the simulator's)
               v_min <= v <= v_max                                 (v_max: the top speed)
               -(w_right - m) <= corner offsets <= w_left - m      (footprint, margin m)
               1 - n kappa >= NORMAL_SINGULARITY_MARGIN

``f_e`` (``ellipse_fraction``) and ``f_s`` (``slip_fraction``) are reserves for tyres whose
force falls past the peak (Pacejka; 1 for the others): the identified car's rear does, and
a lap on its peak spins at the first tracking error (issue #21). Above
``reserve_speed_mps`` (off by default) every friction-limited axle's ellipse shrinks
further, ``f_e -> f_e (1 - (1 - f_r^2) S((v - v_r) / w))^(1/2)`` with ``S`` the smoothstep
``3 x^2 - 2 x^3`` on [0, 1]: at 9-10 m/s the tracker's steering corrections need grip
the line would otherwise spend on braking and cornering (issue #21).
``mu_i`` from ``shared.vehicle.axle_peak_friction``; the gym's ``linear`` tyres have no
friction limit (only steering, acceleration and speed bound the car). With Pacejka tyres
``|a|`` stays 0.1 % below ``min_i mu_i g`` (``mintime.model.PACEJKA_ACCEL_BACKOFF``). The
``a v`` form of the drive limit is the simulator's ``a <= a_max v_switch / v`` above
``v_switch`` (added only when ``v_max > v_switch``; below it ``a <= a_max`` binds).
``v_min`` (1 m/s) keeps the car in the simulator's dynamic regime (full weight above
0.7 m/s).

Transcription (``services.planner.mintime.nlp``). ``N = round(L / ds)`` intervals of
length ``h = L / N``; in each, Radau IIA collocation of degree 3 (points ``tau = 0.155,
0.645, 1``; the last is the interval's end, i.e. the next interval's start, and the last
interval ends at the first start, so periodicity costs nothing). The input is constant per
interval. The lap time is the collocation quadrature of ``dt/ds``. Path constraints hold at
every collocation point and at each interval's start, each with its interval's input (the
acceleration jumps at a node, and the tyres must hold on both sides of it); the footprint
at the ``N`` grid nodes (widths there: the minimum over the footprint's reach). A small
regularisation, ``1e-4 h sum (sv / sv_max)^2 + 1e-4 sum (da / a_lim)^2`` [s], keeps IPOPT
off chattering on singular arcs (e.g. along the speed cap) at a cost well under a
millisecond of lap time. No
input-rate bounds: the simulator's speed loop moves ``a`` within its 10 ms actuation delay,
and the steering's rate is already the input ``sv`` with the simulator's bounds.

IPOPT (MUMPS) starts from the centreline at the quasi-steady point-mass speed profile
(``mintime.model.point_mass_speed`` at ``mu g``), with kinematic steering and slip.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass

import casadi as ca
import numpy as np

from services.planner.mintime.model import (
    BETA,
    INPUT_NAMES,
    N_,
    STATE_NAMES,
    XI,
    SpatialModel,
    V,
    friction_circle_mps2,
    point_mass_speed,
    spatial_model,
)
from services.planner.mintime.model import point_mass_lap_time as _pm_lap_time
from services.planner.mintime.nlp import (
    RADAU_TAU,
    Grid,
    Transcription,
    initial_guess,
    make_grid,
    radau_matrices,
    transcribe,
)
from services.planner.mintime.track import ReferenceLine, reference_line
from shared.config.vehicle import DynamicVehicleParams
from shared.track import Track, TrackError

#: Bump when the problem or its results change (part of the cache key).
CODE_VERSION = "mintime-1"
#: IPOPT statuses that count as solved.
SOLVED_STATUSES = frozenset({"Solve_Succeeded", "Solved_To_Acceptable_Level"})
#: IPOPT statuses that mean no feasible point exists (locally).
INFEASIBLE_STATUSES = frozenset({"Infeasible_Problem_Detected", "Restoration_Failed"})


class MinTimeError(TrackError):
    """No minimum-time lap exists on this track with this car and settings (one line)."""


@dataclass(frozen=True)
class MinTimeSettings:
    """Settings of the minimum-time problem.

    Attributes:
        v_max_mps: top speed cap [m/s] (the CLI's default: the planners' v_up, 4.18 m/s).
        ds_m: grid spacing along the reference [m].
        margin_m: the footprint's corners stay this far inside the boundaries [m].
        v_min_mps: lowest speed allowed [m/s] (keeps the simulator's dynamic regime).
        max_iter: IPOPT iteration limit.
        tol: IPOPT tolerance.
        slip_fraction: Pacejka tyres: each axle's |slip angle| stays within this share of
            its peak slip (1: up to the peak). Past the peak the force falls, so a lap at the
            peak leaves no room for a tracking error; the identified car's rear at 0.7 of
            its peak slip still gives 97 % of its peak force. No effect on other tyres.
        ellipse_fraction: Pacejka tyres: each axle's force stays within this share of its
            friction ellipse's radius, ``F_x^2 + F_y^2 <= (f mu_i F_z)^2`` (1: the whole
            ellipse): room for the speed loop's corrections, whose longitudinal force
            would otherwise push the lateral one past the peak. No effect on other tyres.
        reserve_speed_mps: above this speed [m/s] each axle of any friction-limited tyre
            (``linear_saturated``, ``pacejka``) keeps a reserve of its friction ellipse for
            the tracker's feedback (``reserve_fraction``, module docstring); None
            (default), or at or above ``v_max_mps``: no reserve, the problem of before.
        reserve_fraction: the share of the ellipse's radius an axle may use
            ``reserve_width_mps`` and more above ``reserve_speed_mps`` [-].
        reserve_width_mps: the speed range [m/s] over which the share falls from 1 to
            ``reserve_fraction`` (a smoothstep, so the constraint stays smooth in ``v``).
        reserve_steering_weight_s: with the reserve, a cost [s] on the steering rate,
            ``k h sum S(v) (sv / sv_max)^2`` (``S`` the same smoothstep): a line the 20 Hz
            tracker can steer (without it the lap flicks the wheels at the rate limit for
            0.1 s while braking at 9-10 m/s, and the car spins); 0: none.
        reserve_margin_m: with the reserve, the footprint keeps ``m_r S(v)`` [m] more
            margin (the tracking error's tube grows with the speed); 0: none.
        reserve_yaw_pole_per_s: with the reserve, a friction-limited car's yaw, linearised
            about straight running at the line's speed and acceleration, diverges no faster
            than this [1/s] (``shared.vehicle.yaw_stability``: braking hard above about
            4.4 m/s the gym car oversteers, at 10 m/s its yaw diverges at 8 1/s, faster
            than the tracker's delays catch); None: no bound.
        reserve_from_mps: with the reserve (a line capped above ``reserve_speed_mps``), the
            speed [m/s] from which its grip part fades in over ``reserve_width_mps`` (the
            ellipse shares and the steering-rate cost; the margin, the tracking error's
            tube, still grows from ``reserve_speed_mps``); None: ``reserve_speed_mps``. On a line
            capped at 10 m/s the tight bends' apexes are at 4-5 m/s, entered braking from
            7-10: with the reserve faded in from 4.18 m/s they were at the full ellipse and
            the car spun in 8 of 15 of the generator's tracks (issue 21).
        reserve_rear_fraction: with the reserve, the rear axle's own share of its
            ellipse's radius (a saturated rear spins the car; a saturated front pushes it
            wide, which the tracker's outward cut catches); None: ``reserve_fraction``.
        rear_ellipse_fraction: Pacejka tyres: the rear axle's own share of its friction
            ellipse's radius at every speed (``requests.rear_ellipse_fraction``: a car whose
            rear grips less than its front oversteers at the limit, and a rear at its ellipse
            has nothing left for the yaw moment a front with grip to spare puts on it);
            None: ``ellipse_fraction``. No effect on other tyres.
    """

    v_max_mps: float = 4.18
    ds_m: float = 0.1
    margin_m: float = 0.02
    v_min_mps: float = 1.0
    max_iter: int = 3000
    tol: float = 1e-8
    slip_fraction: float = 1.0
    ellipse_fraction: float = 1.0
    reserve_speed_mps: float | None = None
    reserve_fraction: float = 0.9
    reserve_width_mps: float = 2.0
    reserve_steering_weight_s: float = 0.0
    reserve_margin_m: float = 0.0
    reserve_yaw_pole_per_s: float | None = None
    reserve_rear_fraction: float | None = None
    reserve_from_mps: float | None = None
    rear_ellipse_fraction: float | None = None

    @property
    def reserve_active(self) -> bool:
        """Whether the high-speed reserve changes the problem (a speed below the top)."""
        return self.reserve_speed_mps is not None and self.reserve_speed_mps < self.v_max_mps

    @property
    def reserve_start_mps(self) -> float:
        """The speed [m/s] from which an active reserve fades in (``reserve_from_mps``,
        else ``reserve_speed_mps``)."""
        start = self.reserve_from_mps
        if start is None:
            start = self.reserve_speed_mps
        if start is None:
            raise ValueError("no high-speed reserve: reserve_speed_mps is None")
        return float(start)

    def __post_init__(self) -> None:
        checks = (
            ("v_max_mps", lambda v: 1.0 < v <= 100.0, "in (1, 100] m/s"),
            ("ds_m", lambda v: 0.005 <= v <= 2.0, "in [0.005, 2] m"),
            ("margin_m", lambda v: 0.0 <= v <= 1.0, "in [0, 1] m"),
            ("v_min_mps", lambda v: 0.7 <= v < self.v_max_mps, "in [0.7, v_max) m/s"),
            ("max_iter", lambda v: 1 <= v <= 100000, "in [1, 100000]"),
            ("tol", lambda v: 0.0 < v < 1.0, "in (0, 1)"),
            ("slip_fraction", lambda v: 0.1 <= v <= 1.0, "in [0.1, 1]"),
            ("ellipse_fraction", lambda v: 0.1 <= v <= 1.0, "in [0.1, 1]"),
            ("reserve_fraction", lambda v: 0.1 <= v <= 1.0, "in [0.1, 1]"),
            ("reserve_width_mps", lambda v: 0.01 <= v <= 50.0, "in [0.01, 50] m/s"),
            ("reserve_steering_weight_s", lambda v: 0.0 <= v <= 10.0, "in [0, 10] s"),
            ("reserve_margin_m", lambda v: 0.0 <= v <= 0.5, "in [0, 0.5] m"),
        )
        if self.reserve_speed_mps is not None:
            checks += (("reserve_speed_mps", lambda v: 0.0 < v <= 100.0, "in (0, 100] m/s"),)
        if self.reserve_from_mps is not None:
            checks += (("reserve_from_mps", lambda v: 0.0 <= v <= 100.0, "in [0, 100] m/s"),)
        if self.reserve_rear_fraction is not None:
            checks += (("reserve_rear_fraction", lambda v: 0.1 <= v <= 1.0, "in [0.1, 1]"),)
        if self.rear_ellipse_fraction is not None:
            checks += (("rear_ellipse_fraction", lambda v: 0.1 <= v <= 1.0, "in [0.1, 1]"),)
        if self.reserve_yaw_pole_per_s is not None:
            checks += (("reserve_yaw_pole_per_s", lambda v: 0.0 <= v <= 100.0,
                        "in [0, 100] 1/s"),)
        for name, ok, what in checks:
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int | float):
                raise ValueError(f"{name} must be a number, got {value!r}")
            if not (math.isfinite(value) and ok(value)):
                raise ValueError(f"{name} must be {what}, got {value!r}")


@dataclass(frozen=True, eq=False)
class MinTimeLap:
    """The minimum-time lap. Per-node arrays have shape (N,); node k is at arc length
    ``s_ref_m[k] = k ds_m`` of the reference line and holds the car's state there.

    Attributes:
        lap_time_s: the optimal lap time [s].
        status: IPOPT's return status; success: whether it counts as solved.
        iterations: IPOPT iterations; solve_time_s: wall time of building and solving [s].
        ds_m: grid spacing [m] (``L / N``); v_max_mps, margin_m: the settings used.
        tyre_model: the car's tyre model; track_name, track_length_m: the track.
        reference_length_m: arc length of the reference line [m].
        s_ref_m: node arc length along the reference [m]; t_s: time at each node [s].
        s_m: arc length along the driven line (the CoG's path, chords between nodes) [m].
        x_m, y_m: CoG position [m]; psi_rad: course (path heading) in [0, 2 pi) [rad];
        yaw_rad: car yaw [rad] (unwrapped); kappa_radpm: path curvature [1/m] (left +).
        v_mps: speed [m/s]; ax_mps2: its rate dv/dt [m/s^2]; n_m: offset (left +) [m].
        states: (N, 6) in ``STATE_NAMES`` order; inputs: (N, 2) in ``INPUT_NAMES`` order
            (acting from node k to node k+1).
        min_clearance_m: smallest distance of a footprint corner inside the boundaries at
            the nodes, judged like the lap timer (projection onto the polyline) [m].
        point_mass_lap_time_s: for comparison, the quasi-steady point mass on the reference
            line (friction circle ``min_i mu_i g``, the same acceleration limit) [s].
        cache_hit: whether the record came from a cache (set by the shell that loads it).
    """

    lap_time_s: float
    status: str
    success: bool
    iterations: int
    solve_time_s: float
    ds_m: float
    v_max_mps: float
    margin_m: float
    tyre_model: str
    track_name: str
    track_length_m: float
    reference_length_m: float
    s_ref_m: np.ndarray
    t_s: np.ndarray
    s_m: np.ndarray
    x_m: np.ndarray
    y_m: np.ndarray
    psi_rad: np.ndarray
    yaw_rad: np.ndarray
    kappa_radpm: np.ndarray
    v_mps: np.ndarray
    ax_mps2: np.ndarray
    n_m: np.ndarray
    states: np.ndarray
    inputs: np.ndarray
    min_clearance_m: float
    point_mass_lap_time_s: float
    cache_hit: bool = False

    def __post_init__(self) -> None:
        for value in self.__dict__.values():
            if isinstance(value, np.ndarray):
                value.setflags(write=False)

    @property
    def state_names(self) -> tuple[str, ...]:
        """Names of the columns of ``states``."""
        return STATE_NAMES

    @property
    def input_names(self) -> tuple[str, ...]:
        """Names of the columns of ``inputs``."""
        return INPUT_NAMES


def ipopt_options(settings: MinTimeSettings) -> dict:
    """nlpsol options: IPOPT with MUMPS, quiet."""
    return {
        "print_time": False,
        "error_on_fail": False,
        "ipopt": {
            "linear_solver": "mumps",
            "print_level": 0,
            "sb": "yes",
            "max_iter": settings.max_iter,
            "tol": settings.tol,
            "acceptable_tol": 1e-5,
            "mu_strategy": "adaptive",
        },
    }


def solve_min_time(
    track: Track,
    vehicle: DynamicVehicleParams,
    settings: MinTimeSettings | None = None,
) -> MinTimeLap:
    """The minimum-time flying lap of `vehicle` on `track` (module docstring).

    Raises:
        MinTimeError: the footprint does not fit across the track, or IPOPT finds no
            feasible lap.
    """
    cfg = settings or MinTimeSettings()
    t0 = time.perf_counter()
    ref = reference_line(track)
    grid = make_grid(ref, vehicle, cfg.ds_m)
    room = grid.w_left + grid.w_right - 2.0 * cfg.margin_m
    k = int(np.argmin(room))
    if room[k] < vehicle.width_m:
        raise MinTimeError(
            track.source,
            f"no feasible lap: the track is {grid.w_left[k] + grid.w_right[k]:.3f} m wide near "
            f"s = {grid.s_nodes[k]:.1f} m; the car needs {vehicle.width_m:.3f} m + 2 x "
            f"{cfg.margin_m:.3f} m margin",
        )
    reserve = (
        (cfg.reserve_start_mps, cfg.reserve_width_mps, cfg.reserve_fraction)
        if cfg.reserve_active
        else None
    )
    model = spatial_model(vehicle, cfg.slip_fraction, cfg.ellipse_fraction, reserve,
                          cfg.reserve_yaw_pole_per_s, cfg.reserve_rear_fraction,
                          cfg.rear_ellipse_fraction)
    steering = (
        (cfg.reserve_start_mps, cfg.reserve_width_mps, cfg.reserve_steering_weight_s,
         cfg.reserve_margin_m, cfg.reserve_speed_mps)
        if cfg.reserve_active
        and (cfg.reserve_steering_weight_s > 0.0 or cfg.reserve_margin_m > 0.0)
        else None
    )
    tr = transcribe(model, vehicle, grid, cfg.v_max_mps, cfg.v_min_mps, cfg.margin_m, steering)
    x0 = tr.pack(*initial_guess(grid, vehicle, model, cfg.v_max_mps, cfg.v_min_mps))
    solver = ca.nlpsol("mintime", "ipopt", tr.nlp, ipopt_options(cfg))
    sol = solver(x0=x0, lbx=tr.lbx, ubx=tr.ubx, lbg=tr.lbg, ubg=tr.ubg)
    stats = solver.stats()
    status = str(stats.get("return_status", "unknown"))
    z = np.asarray(sol["x"], dtype=float).reshape(-1)
    iters = int(stats.get("iter_count", 0))
    if status in INFEASIBLE_STATUSES:
        raise MinTimeError(
            track.source,
            f"no feasible lap found (IPOPT: {status} after {iters} iterations): the track is "
            "too narrow or too tight for the car",
        )
    if status not in SOLVED_STATUSES or not np.all(np.isfinite(z)):
        raise MinTimeError(
            track.source,
            f"no minimum-time lap: IPOPT stopped with {status} after {iters} iterations "
            "(not proven infeasible; another grid spacing may converge)",
        )
    states_col, inputs = tr.unpack(z)
    elapsed = time.perf_counter() - t0
    return _lap_record(
        track, vehicle, cfg, ref, tr, model, states_col, inputs, status, iters, elapsed
    )


def _lap_record(
    track: Track,
    vehicle: DynamicVehicleParams,
    cfg: MinTimeSettings,
    ref: ReferenceLine,
    tr: Transcription,
    model: SpatialModel,
    states_col: np.ndarray,
    inputs: np.ndarray,
    status: str,
    iters: int,
    wall: float,
) -> MinTimeLap:
    """The result record from the solution (see ``MinTimeLap``)."""
    g = tr.grid
    n, d = g.n, len(RADAU_TAU)
    _c, b = radau_matrices(RADAU_TAU)
    x_nodes = np.roll(states_col[:, (d - 1) * n :], 1, axis=1)  # node k ends interval k-1
    kappa_row = g.kappa_col.reshape(1, -1)
    u_tiled = np.tile(inputs, (1, d))
    _dx, dt_ds, _vd, _cd = model.ode.map(d * n)(states_col, u_tiled, kappa_row)
    dt_ds = np.asarray(dt_ds).reshape(d, n)
    dt = g.h * (b[1:, None] * dt_ds).sum(axis=0)  # time over each interval [s]
    t_nodes = np.concatenate([[0.0], np.cumsum(dt)[:-1]])
    _dx, _dt, v_dot, chi_dot = model.ode.map(n)(x_nodes, inputs, g.kappa_nodes.reshape(1, -1))
    v_dot = np.asarray(v_dot).reshape(-1)
    chi_dot = np.asarray(chi_dot).reshape(-1)
    pts = ref.points(g.s_nodes)
    normal = np.column_stack([-np.sin(pts.heading_rad), np.cos(pts.heading_rad)])
    xy = pts.xy + x_nodes[N_][:, None] * normal
    yaw = pts.heading_rad + x_nodes[XI]
    course = yaw + x_nodes[BETA]
    chord = np.hypot(*(np.roll(xy, -1, axis=0) - xy).T)
    return MinTimeLap(
        lap_time_s=float(dt.sum()),
        status=status,
        success=status in SOLVED_STATUSES,
        iterations=iters,
        solve_time_s=wall,
        ds_m=g.h,
        v_max_mps=cfg.v_max_mps,
        margin_m=cfg.margin_m,
        tyre_model=vehicle.tyre_model,
        track_name=track.name,
        track_length_m=track.length_m,
        reference_length_m=ref.length_m,
        s_ref_m=g.s_nodes,
        t_s=t_nodes,
        s_m=np.concatenate([[0.0], np.cumsum(chord)[:-1]]),
        x_m=xy[:, 0],
        y_m=xy[:, 1],
        psi_rad=np.mod(course, 2.0 * np.pi),
        yaw_rad=yaw,
        kappa_radpm=chi_dot / x_nodes[V],
        v_mps=x_nodes[V].copy(),
        ax_mps2=v_dot,
        n_m=x_nodes[N_].copy(),
        states=x_nodes.T.copy(),
        inputs=inputs.T.copy(),
        min_clearance_m=footprint_clearance(track, vehicle, xy, yaw),
        point_mass_lap_time_s=point_mass_lap_time(vehicle, model, g, cfg.v_max_mps),
    )


def point_mass_lap_time(
    vehicle: DynamicVehicleParams, model: SpatialModel, g: Grid, v_max: float
) -> float:
    """Lap time [s] of the quasi-steady point mass on the reference line (see MinTimeLap)."""
    a = model.accel_limit_mps2
    v = point_mass_speed(g.kappa_nodes, g.h, v_max, friction_circle_mps2(vehicle), a, a)
    return _pm_lap_time(v, g.h)


def footprint_clearance(
    track: Track, vehicle: DynamicVehicleParams, xy: np.ndarray, yaw: np.ndarray
) -> float:
    """Smallest distance [m] of a footprint corner inside the boundaries, over poses.

    Judged as the lap timer does: each corner of the ``length x width`` rectangle centred on
    the CoG ``xy`` (m, 2) with yaw ``yaw`` (m,) is projected onto the polyline centreline;
    its clearance is ``min(w_right - e_con, w_left + e_con)`` there. Negative: off track.
    """
    hl, hw = 0.5 * vehicle.length_m, 0.5 * vehicle.width_m
    body = np.array([[hl, hw], [hl, -hw], [-hl, -hw], [-hl, hw]])
    c, s = np.cos(yaw)[:, None], np.sin(yaw)[:, None]
    cx = xy[:, 0:1] + c * body[:, 0] - s * body[:, 1]
    cy = xy[:, 1:2] + s * body[:, 0] + c * body[:, 1]
    corners = np.column_stack([cx.reshape(-1), cy.reshape(-1)])
    s_c, e_c = track.project(corners)
    w_r, w_l = track.interp_width(s_c)
    return float(np.min(np.minimum(w_r - e_c, w_l + e_c)))
