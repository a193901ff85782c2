"""The simulator's car in curvilinear coordinates along a reference line, for the min-time OCP.

Pure maths, no I/O. State along the reference's arc length ``s`` [m] (``STATE_NAMES``)::

    x = [n, xi, v, beta, r, delta]      u = [sv, a]

``n`` lateral offset of the CoG from the reference [m], LEFT positive; ``xi = psi - theta(s)``
heading error of the car's yaw against the reference tangent [rad]; ``v`` CoG speed [m/s];
``beta`` slip angle [rad]; ``r`` yaw rate [rad/s]; ``delta`` road-wheel angle [rad]; inputs the
steering rate ``sv`` [rad/s] and the longitudinal acceleration demand ``a`` [m/s^2] (what the
simulator's speed loop asks of the tyres). With ``kappa(s)`` the reference's signed
curvature (left +) and the course ``chi = psi + beta``::

    s_dot  = v cos(xi + beta) / (1 - n kappa)
    n_dot  = v sin(xi + beta)
    xi_dot = r - kappa s_dot
    v_dot, beta_dot, r_dot = shared.vehicle.make_dynamic_derivatives(p, saturate=False)
    delta_dot = sv

and ``dx/ds = x_dot / s_dot``, ``dt/ds = 1 / s_dot = (1 - n kappa) / (v cos(xi + beta))``.
The vehicle equations are the simulator's own (``shared.vehicle``), with the smooth tyre laws:
the optimiser keeps each axle inside its friction ellipse as a constraint, and there the
smooth and the simulator's saturated laws agree. ``braking`` is passed as False: driving
forwards (each wheel rolls at ``u > BRAKE_SIGN_RAMP_MPS``) a brake force is the same
``F_z a / g`` either way.

Footprint. The lap timer (``services.simulator.laps``) checks the four corners of the
``length x width`` rectangle centred on the CoG, aligned with the yaw. A corner at body
coordinates ``(c_x, c_y)`` lies ``d = c_x cos(xi) - c_y sin(xi)`` along the reference
tangent and ``y = n + c_x sin(xi) + c_y cos(xi)`` across it; on a circular arc of
curvature ``kappa`` through the reference point its offset from the reference is exactly
(``rho`` = its distance from the centre of curvature)::

    1/kappa - rho = y - kappa d^2 / (sqrt(kappa^2 d^2 + (1 - kappa y)^2) + (1 - kappa y))

(smooth, and ``y`` at ``kappa = 0``): a corner ahead of the CoG in a left turn sits to the
right of the curve, by ``kappa d^2 / 2`` to first order (4.6 cm for 0.29 m at 1.1 1/m).
Where the curvature changes (turn entries and exits) ``kappa`` is the effective curvature
over the corner's reach, which keeps the offsets within about a millimetre of the lap
timer's projection instead of 5 mm.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import casadi as ca
import numpy as np

from shared.config.vehicle import DynamicVehicleParams
from shared.vehicle import CASADI_OPS, GRAVITY_MPS2, axle_peak_friction, make_dynamic_derivatives
from shared.vehicle.tyres import pacejka_peak_slip_rad
from shared.vehicle.yaw_stability import yaw_pole_margin

STATE_NAMES = ("n_m", "xi_rad", "v_mps", "beta_rad", "r_radps", "delta_rad")
INPUT_NAMES = ("steering_rate_radps", "accel_mps2")
NX = len(STATE_NAMES)
NU = len(INPUT_NAMES)
#: Pacejka tyres: |a| stays this share below min_i mu_i g (the lateral limit's square root
#: has an infinite slope there, which stalls IPOPT; 0.1 % of the acceleration is nothing).
PACEJKA_ACCEL_BACKOFF = 1e-3
#: The servo's reach (below) is modelled when the rate limit times its time constant exceeds
#: this share of the steering range's half-width: the gym's 0.01 s servo (3.2 rad/s x 0.01 s
#: = 0.032 rad of 0.42) meets its rate limit almost everywhere, the identified car's 0.158 s
#: one (0.51 rad) never does.
SERVO_REACH_MIN_SHARE = 0.25
#: Index of each state element.
N_, XI, V, BETA, R, DELTA = range(NX)


@dataclass(frozen=True)
class SpatialModel:
    """CasADi functions of the car along the reference (see the module docstring).

    Attributes:
        ode: ``(x[6], u[2], kappa) -> (dx/ds [6], dt/ds, v_dot, chi_dot)``; ``chi_dot =
            r + beta_dot`` is the course rate [rad/s] (path curvature = chi_dot / v).
        tyres: ``(x, u) -> [(F_x^2 + F_y^2) / (mu_i F_z)^2 front, rear, alpha_f, alpha_r]``
            (friction-ellipse use [-], slip angles [rad]).
        footprint: ``(x, kappa_front, kappa_rear) -> (4,)`` lateral offsets [m] (left +)
            of the corners front-left, front-right, rear-right, rear-left; each end of the
            car with the reference's effective curvature over its reach
            (``ReferenceLine.effective_curvature`` at ``+-length / 2``).
        friction_limited: whether the tyres have a friction limit (not ``linear``).
        peak_slip_rad: (front, rear) |alpha| bounds (Pacejka peak), or None.
        accel_limit_mps2: ``min(a_max, min_i mu_i g)`` [m/s^2], the simulator's |a| cap.
        servo_time_constant_s: ``tau`` of a servo whose reach bounds the steering rate, or
            None (``servo_reach``).
        ellipse_use_max: bound on the ``tyres`` use [-] (``ellipse_fraction ** 2``).
        reserve: the high-speed reserve ``(v_r [m/s], w [m/s], f_r [-])`` of
            ``MinTimeSettings`` (``reserve_speed_mps``, ``reserve_width_mps``,
            ``reserve_fraction``), or None: ``use_bound``.
        yaw_stability: ``(x, u) -> margin [-]``, >= 0 where the car's yaw under the
            acceleration ``a`` diverges no faster than the bound ``MinTimeSettings
            .reserve_yaw_pole_per_s`` (``shared.vehicle.yaw_stability.yaw_pole_margin``),
            or None: no such bound.
        rear_reserve_fraction: the rear axle's share of its ellipse's radius at speed
            with the reserve (a saturated rear spins the car, a saturated front pushes it
            wide), or None: the reserve's ``f_r`` for both axles.
        rear_ellipse_use_max: the rear axle's own bound on its ``tyres`` use [-]
            (``MinTimeSettings.rear_ellipse_fraction ** 2``), or None: ``ellipse_use_max``.
    """

    ode: ca.Function
    tyres: ca.Function
    footprint: ca.Function
    friction_limited: bool
    peak_slip_rad: tuple[float, float] | None
    accel_limit_mps2: float
    servo_time_constant_s: float | None = None
    ellipse_use_max: float = 1.0
    reserve: tuple[float, float, float] | None = None
    yaw_stability: ca.Function | None = None
    rear_reserve_fraction: float | None = None
    rear_ellipse_use_max: float | None = None

    def axle_use_max(self, rear: bool = False) -> float:
        """The front (`rear`: the rear) axle's bound on its ellipse use [-] below any
        high-speed reserve: ``ellipse_use_max``, or the rear's own ``rear_ellipse_use_max``."""
        if rear and self.rear_ellipse_use_max is not None:
            return self.rear_ellipse_use_max
        return self.ellipse_use_max

    def use_bound(
        self, v_mps: ca.MX | ca.SX | float, rear: bool = False
    ) -> ca.MX | ca.SX | float:
        """Bound on the front (`rear`: the rear) axle's ellipse use [-] at speed `v_mps`
        [m/s]: ``axle_use_max(rear)``, times ``1 - (1 - f_r^2) S((v - v_r) / w)`` with the
        reserve (``S`` the smoothstep ``3 x^2 - 2 x^3`` of x clipped to [0, 1]: 1 up to
        ``v_r``, ``f_r^2`` from ``v_r + w`` on; ``f_r`` the rear's own share for the rear
        when ``rear_reserve_fraction`` is set)."""
        if self.reserve is None:
            return self.axle_use_max(rear)
        v_r, width, f_r = self.reserve
        if rear and self.rear_reserve_fraction is not None:
            f_r = self.rear_reserve_fraction
        ramp = reserve_ramp(v_mps, v_r, width)
        return self.axle_use_max(rear) * (1.0 - (1.0 - f_r * f_r) * ramp)


def reserve_ramp(
    v_mps: ca.MX | ca.SX | float, v_r_mps: float, width_mps: float
) -> ca.MX | ca.SX | float:
    """The high-speed reserve's weight [-] at speed `v_mps` [m/s]: the smoothstep ``3 x^2 -
    2 x^3`` of ``x = (v - v_r) / w`` clipped to [0, 1] (0 up to `v_r_mps`, 1 from `v_r_mps` +
    `width_mps` on; C1 in v)."""
    x = ca.fmin(ca.fmax((v_mps - v_r_mps) / width_mps, 0.0), 1.0)
    return x * x * (3.0 - 2.0 * x)


def corner_offset(n: ca.SX, xi: ca.SX, kappa: ca.SX, cx: float, cy: float) -> ca.SX:
    """Offset [m] (left +) from the reference of the body point (cx, cy) [m] (docstring)."""
    d = cx * ca.cos(xi) - cy * ca.sin(xi)
    y = n + cx * ca.sin(xi) + cy * ca.cos(xi)
    q = 1.0 - kappa * y
    return y - kappa * d * d / (ca.sqrt(kappa * kappa * d * d + q * q) + q)


def spatial_model(
    p: DynamicVehicleParams,
    slip_fraction: float = 1.0,
    ellipse_fraction: float = 1.0,
    reserve: tuple[float, float, float] | None = None,
    yaw_pole_per_s: float | None = None,
    rear_reserve_fraction: float | None = None,
    rear_ellipse_fraction: float | None = None,
) -> SpatialModel:
    """The functions of `p`'s car along a reference (module docstring); Pacejka tyres keep
    their slip within `slip_fraction` of the peak slip and their force within
    `ellipse_fraction` of the ellipse, and any friction-limited tyre the high-speed
    `reserve` ``(v_r [m/s], w [m/s], f_r [-])`` (``MinTimeSettings``; None: none) and, with
    it, the yaw's divergence under braking within `yaw_pole_per_s` [1/s] (None: none) and
    the rear's own share `rear_reserve_fraction` (None: the reserve's); Pacejka tyres' rear
    within `rear_ellipse_fraction` of its ellipse (None: `ellipse_fraction`)."""
    x = ca.SX.sym("x", NX)
    u = ca.SX.sym("u", NU)
    kappa = ca.SX.sym("kappa")
    n, xi, v, beta, r, delta = (x[i] for i in range(NX))
    sv, a = u[0], u[1]
    dyn = make_dynamic_derivatives(p, CASADI_OPS, saturate=False)(v, beta, r, delta, a, False)
    course = xi + beta
    s_dot = v * ca.cos(course) / (1.0 - n * kappa)
    x_dot = ca.vertcat(
        v * ca.sin(course), r - kappa * s_dot, dyn.dv, dyn.dbeta, dyn.dr, sv
    )
    ode = ca.Function(
        "mintime_ode",
        [x, u, kappa],
        [x_dot / s_dot, 1.0 / s_dot, dyn.dv, r + dyn.dbeta],
        ["x", "u", "kappa"],
        ["dx_ds", "dt_ds", "v_dot", "chi_dot"],
    )
    mu_f, mu_r = axle_peak_friction(p, "front"), axle_peak_friction(p, "rear")
    limited = math.isfinite(mu_f) and math.isfinite(mu_r)
    use = []
    for axle, mu in ((dyn.front, mu_f), (dyn.rear, mu_r)):
        if limited:
            use.append((axle.fx_n**2 + axle.fy_n**2) / (mu * axle.fz_n) ** 2)
        else:
            use.append(ca.SX(0.0))
    tyres = ca.Function(
        "mintime_tyres",
        [x, u],
        [ca.vertcat(use[0], use[1], dyn.front.alpha_rad, dyn.rear.alpha_rad)],
        ["x", "u"],
        ["tyres"],
    )
    hl, hw = 0.5 * p.length_m, 0.5 * p.width_m
    corners = ((hl, hw), (hl, -hw), (-hl, -hw), (-hl, hw))
    k_front, k_rear = ca.SX.sym("kappa_front"), ca.SX.sym("kappa_rear")
    footprint = ca.Function(
        "mintime_footprint",
        [x, k_front, k_rear],
        [
            ca.vertcat(
                *(
                    corner_offset(n, xi, k_front if cx > 0 else k_rear, cx, cy)
                    for cx, cy in corners
                )
            )
        ],
        ["x", "kappa_front", "kappa_rear"],
        ["offsets"],
    )
    peak = None
    if p.tyre_model == "pacejka":
        peak = (
            slip_fraction * pacejka_peak_slip_rad(p, "front"),
            slip_fraction * pacejka_peak_slip_rad(p, "rear"),
        )
    a_lim = min(p.accel_max_mps2, min(mu_f, mu_r) * GRAVITY_MPS2)
    if p.tyre_model == "pacejka":  # its F_y,max = sqrt((mu F_z)^2 - F_x^2) is steep at 0
        a_lim = min(a_lim, (1.0 - PACEJKA_ACCEL_BACKOFF) * min(mu_f, mu_r) * GRAVITY_MPS2)
    use_max = ellipse_fraction**2 if p.tyre_model == "pacejka" else 1.0
    rear_use_max = (rear_ellipse_fraction**2
                    if p.tyre_model == "pacejka" and rear_ellipse_fraction is not None else None)
    yaw = None
    if limited and reserve is not None and yaw_pole_per_s is not None:
        yaw = ca.Function(
            "mintime_yaw_stability", [x, u],
            [yaw_pole_margin(p, v, a, yaw_pole_per_s, CASADI_OPS)], ["x", "u"], ["margin"],
        )
    return SpatialModel(
        ode, tyres, footprint, limited, peak, a_lim, servo_reach(p), use_max,
        reserve if limited else None, yaw,
        rear_reserve_fraction if limited and reserve is not None else None,
        rear_use_max,
    )


def servo_reach(p: DynamicVehicleParams) -> float | None:
    """The servo's time constant ``tau`` [s] when its reach bounds the steering rate, else None.

    The simulator's servo is proportional, ``sv = (delta_target - delta) / tau``, and its
    target lies within the steering limits, so whatever the command the rate stays within
    ``(delta_min - delta) / tau <= sv <= (delta_max - delta) / tau`` besides the rate limits:
    a slow servo cannot swing the wheels at its rate limit near an end stop. The optimiser
    keeps ``delta + tau sv`` within the limits when that matters
    (``SERVO_REACH_MIN_SHARE``).
    """
    tau = p.steering_time_constant_s
    rate = max(p.steering_rate_max_radps, -p.steering_rate_min_radps)
    half = 0.5 * (p.steering_max_rad - p.steering_min_rad)
    return tau if tau * rate > SERVO_REACH_MIN_SHARE * half else None


def friction_circle_mps2(p: DynamicVehicleParams) -> float:
    """``min_i mu_i g`` [m/s^2], the point mass's friction circle (inf for ``linear``)."""
    return min(axle_peak_friction(p, "front"), axle_peak_friction(p, "rear")) * GRAVITY_MPS2


def point_mass_speed(
    kappa_1pm: np.ndarray,
    ds_m: float,
    v_max_mps: float,
    mu_g_mps2: float,
    accel_mps2: float,
    brake_mps2: float,
) -> np.ndarray:
    """Quasi-steady point-mass speeds (n,) [m/s] on a closed line sampled every `ds_m` [m].

    Friction circle: at speed ``v`` the lateral acceleration ``v^2 |kappa|`` leaves
    ``sqrt((mu g)^2 - (v^2 kappa)^2)`` for the longitudinal one. ``v <= min(v_max,
    sqrt(mu g / |kappa|))``, then forward passes (``v_(i+1)^2 <= v_i^2 + 2 ds a_i``, ``a_i``
    the smaller of `accel_mps2` and what the circle leaves) and backward ones with
    `brake_mps2`, twice around so the loop closes. ``mu_g = inf``: no friction limit.
    """
    k = np.abs(np.asarray(kappa_1pm, dtype=float))
    with np.errstate(divide="ignore"):
        v = np.minimum(v_max_mps, np.sqrt(mu_g_mps2 / np.maximum(k, 1e-12)))
    n = v.size

    def room(vi: float, ki: float, cap: float) -> float:
        if not math.isfinite(mu_g_mps2):
            return cap
        lat = vi * vi * ki
        return min(cap, math.sqrt(max(mu_g_mps2**2 - lat * lat, 0.0)))

    for _ in range(2):
        for i in range(n):
            j = (i + 1) % n
            a = room(v[i], k[i], accel_mps2)
            v[j] = min(v[j], math.sqrt(v[i] ** 2 + 2.0 * ds_m * a))
        for i in range(n - 1, -1, -1):
            j = (i + 1) % n
            a = room(v[j], k[j], brake_mps2)
            v[i] = min(v[i], math.sqrt(v[j] ** 2 + 2.0 * ds_m * a))
    return v


def point_mass_lap_time(speed_mps: np.ndarray, ds_m: float) -> float:
    """Lap time [s] of closed-loop speeds sampled every `ds_m` [m] (trapezoid in 1/v)."""
    v = np.asarray(speed_mps, dtype=float)
    return float(np.sum(ds_m * 0.5 * (1.0 / v + 1.0 / np.roll(v, -1))))
