"""The dynamic single-track model of the simulated car (the one definition of the equations).

State ``s = [x, y, delta, v, psi, psi_dot, beta]`` (``state.StateIndex``), inputs steering
rate ``sv`` [rad/s] and longitudinal acceleration ``a`` [m/s^2]. Map frame, SI units, angles
counter-clockwise. ``L = lf + lr``, ``g = 9.81 m/s^2``.

Input limits (applied inside the right-hand side, as in the F1TENTH gym):

- steering rate: ``sv`` clipped to ``[sv_min, sv_max]``, and 0 when ``delta`` is at a
  steering limit and ``sv`` pushes further;
- acceleration: ``a`` clipped to ``[-a_max, a_max]``, above ``v_switch`` the drive limit is
  ``a_max * v_switch / v``, ``a = 0`` when ``v`` is at ``v_min`` / ``v_max`` and ``a`` pushes
  further; with a friction-limited tyre model also ``|a| <= mu_peak g`` (a tyre cannot
  transmit more).

Kinematics (both regimes, so the pose is continuous across the switch)::

    x' = v cos(psi + beta)     y' = v sin(psi + beta)     delta' = sv     psi' = psi_dot

Dynamic regime (|v| >= v_kin + blend). Normal loads with load transfer and slip angles
(small angles, signed speed ``sg = sign(v)`` so that the tyre force always opposes the tyre's
lateral sliding, also in reverse)::

    F_zf = m (g lr - a h) / L            F_zr = m (g lf + a h) / L
    alpha_f = sg (delta - beta) - lf psi_dot / |v|
    alpha_r = -sg beta + lr psi_dot / |v|

Tyre model ``linear`` (the gym's, exactly the CommonRoad ST equations for v > 0), with
``F_yi = mu C_Si F_zi alpha_i``::

    v' = a     psi_dot' = (lf F_yf - lr F_yr) / I_z     beta' = (F_yf + F_yr) / (m v) - psi_dot

Linear tyres bound nothing: that model corners at any lateral acceleration.

Tyre models ``linear_saturated`` (default) and ``pacejka`` are physical for any slip and
speed: bounded slip angles from the contact-patch velocities (atan2), forces in the wheel
frame, a friction ellipse (braking or driving reduces lateral grip) and brakes that oppose
each wheel's rolling. Their equations, and where they come from, are in
``shared.vehicle.single_track`` and ``shared.vehicle.tyres``, written once for this
simulator and for the minimum-time optimal control problem. To first order in the angles
they are the equations above; without a driving force the kinetic plus rotational energy
never grows.

Kinematic regime (|v| <= v_kin): the kinematic single-track at the CoG,
``beta_k = atan(lr tan(delta) / L)``, ``psi_dot_k = v cos(beta_k) tan(delta) / L``. The gym
freezes beta there (``beta' = 0``) and integrates the yaw with ``psi_dot_k`` while positions
ignore beta, which makes beta and psi_dot jump at the switch. Here the states follow the
kinematic values instead: ``beta' = d(beta_k)/dt + (beta_k - beta) / tau`` and
``psi_dot' = d(psi_dot_k)/dt + (psi_dot_k - psi_dot) / tau`` (``tau`` =
``KINEMATIC_RELAX_S``), so they equal the kinematic values in steady state and are continuous
when the dynamic model takes over. Between ``v_kin`` and ``v_kin + blend`` the two
derivatives of ``psi_dot`` and ``beta`` are blended with ``w = 3u^2 - 2u^3``,
``u = (|v| - v_kin) / blend``.

In the kinematic regime the tyres roll without slipping, a workless constraint: when the
yaw rate has to grow to follow the kinematic value, its energy comes out of the speed,
``v' = a - max(I_z psi_dot psi_dot'_kin, 0) / (m v)``, so no regime creates energy
without a driving force. The blend applies to ``v'`` as well.

The state is kept canonical after every step (``Simulator``): ``|beta| <= pi/2``, a car
sliding backwards has ``v < 0`` (``(v, beta)`` and ``(-v, beta -+ pi)`` are the same
velocity).

Limitations: no wheel-spin states (the speed loop acts on the CoG speed through the tyres'
friction ellipse), no aerodynamic drag or rolling resistance, as in the gym; ``linear``
keeps the gym's small-angle equations, valid for small slip only.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from services.simulator.state import NX, StateIndex, StateTuple
from shared.config.vehicle import DynamicVehicleParams
from shared.vehicle import FLOAT_OPS, GRAVITY_MPS2, axle_peak_friction, make_dynamic_derivatives

#: Time constant [s] with which psi_dot and beta follow the kinematic values at low speed.
KINEMATIC_RELAX_S = 0.02
#: Below this speed [m/s] the kinematic blend takes no yaw energy out of the speed (p / v would
#: overflow at a speed that is only a rounding error away from standing still).
ENERGY_MIN_SPEED_MPS = 1e-6
#: RK4's stability region contains the left half-disc of radius 2.61; keep h |lambda| below.
RK4_STABLE_HLAMBDA = 2.5


def friction_accel_limit(p: DynamicVehicleParams) -> float:
    """Largest |a| [m/s^2] the tyres transmit: mu_peak g (inf for ``linear`` tyres)."""
    if p.tyre_model == "linear":
        return math.inf
    return min(axle_peak_friction(p, "front"), axle_peak_friction(p, "rear")) * GRAVITY_MPS2


def blend_weight(speed_abs: float, v_kin: float, blend: float) -> float:
    """Weight of the dynamic model in [0, 1] at |v| = `speed_abs` [m/s] (smoothstep)."""
    if speed_abs <= v_kin:
        return 0.0
    if blend <= 0.0 or speed_abs >= v_kin + blend:
        return 1.0
    u = (speed_abs - v_kin) / blend
    return u * u * (3.0 - 2.0 * u)


@dataclass(frozen=True, slots=True)
class TyreState:
    """Diagnostic axle quantities at one state (forces [N], slip angles [rad])."""

    normal_front_n: float
    normal_rear_n: float
    slip_front_rad: float
    slip_rear_rad: float
    lateral_front_n: float
    lateral_rear_n: float
    lateral_max_front_n: float
    lateral_max_rear_n: float

    @property
    def saturated_front(self) -> bool:
        """The front axle force is at its friction limit."""
        return abs(self.lateral_front_n) >= self.lateral_max_front_n * (1.0 - 1e-9)

    @property
    def saturated_rear(self) -> bool:
        """The rear axle force is at its friction limit."""
        return abs(self.lateral_rear_n) >= self.lateral_max_rear_n * (1.0 - 1e-9)


class SingleTrackModel:
    """The dynamic single-track model with its input limits (see the module docstring).

    Args:
        params: the simulated car.
        kinematic_below_mps: v_kin [m/s]; below it the kinematic model applies (> 0).
        kinematic_blend_mps: width of the blend above v_kin [m/s] (0: hard switch).

    Attributes:
        rhs: ``rhs(s, sv, a) -> s_dot``: state tuple (7 floats, ``StateIndex`` order), raw
            steering rate [rad/s] and acceleration [m/s^2] (limits applied inside) -> time
            derivative tuple. Plain floats, no numpy: this is the integrator's hot path.
    """

    def __init__(
        self,
        params: DynamicVehicleParams,
        kinematic_below_mps: float = 0.5,
        kinematic_blend_mps: float = 0.2,
    ) -> None:
        if not kinematic_below_mps > 0.0 or kinematic_blend_mps < 0.0:
            raise ValueError("kinematic_below_mps must be > 0 and kinematic_blend_mps >= 0")
        self.params = params
        self.kinematic_below_mps = float(kinematic_below_mps)
        self.kinematic_blend_mps = float(kinematic_blend_mps)
        self._dynamic = make_dynamic_derivatives(params, FLOAT_OPS)
        self._dynamic_raw = make_dynamic_derivatives(params, FLOAT_OPS, raw=True)
        self.rhs: Callable[[StateTuple, float, float], StateTuple] = self._make_rhs()
        self._stiff = self._stiffness_constants()

    # ------------------------------------------------------------------ the equations
    def _make_rhs(self) -> Callable[[StateTuple, float, float], StateTuple]:
        p = self.params
        m, iz = p.mass_kg, p.yaw_inertia_kgm2
        wb = p.lf_m + p.lr_m
        lr_over_l = p.lr_m / wb
        tau_inv = 1.0 / KINEMATIC_RELAX_S
        v_kin, blend = self.kinematic_below_mps, self.kinematic_blend_mps
        s_min, s_max = p.steering_min_rad, p.steering_max_rad
        sv_min, sv_max = p.steering_rate_min_radps, p.steering_rate_max_radps
        v_min, v_max = p.v_min_mps, p.v_max_mps
        a_max, v_switch = p.accel_max_mps2, p.v_switch_mps
        a_fric = friction_accel_limit(p)
        a_hi_const = min(a_max, a_fric)
        a_lo = -min(a_max, a_fric)
        gym_exact = p.tyre_model == "linear"
        dynamic = self._dynamic_raw
        cos, sin, tan, sqrt = math.cos, math.sin, math.tan, math.sqrt

        def rhs(s: StateTuple, sv: float, a: float) -> StateTuple:
            _x, _y, delta, v, psi, r, beta = s  # StateIndex order (checked in state.py)
            # input limits: steering rate and end stops, acceleration (gym + friction)
            if (delta <= s_min and sv <= 0.0) or (delta >= s_max and sv >= 0.0):
                sv = 0.0
            elif sv < sv_min:
                sv = sv_min
            elif sv > sv_max:
                sv = sv_max
            if (v <= v_min and a <= 0.0) or (v >= v_max and a >= 0.0):
                a = 0.0
            else:
                a_hi = a_max * v_switch / v if v > v_switch else a_max
                if a_hi > a_hi_const:
                    a_hi = a_hi_const
                if a > a_hi:
                    a = a_hi
                elif a < a_lo:
                    a = a_lo
            heading = psi + beta
            dx = v * cos(heading)
            dy = v * sin(heading)
            speed = v if v >= 0.0 else -v
            # blend weight of the dynamic model
            if speed <= v_kin:
                w = 0.0
            elif blend <= 0.0 or speed >= v_kin + blend:
                w = 1.0
            else:
                u = (speed - v_kin) / blend
                w = u * u * (3.0 - 2.0 * u)
            dr = 0.0
            dbeta = 0.0
            dv = 0.0
            if w < 1.0:
                tan_d = tan(delta)
                sec2 = 1.0 + tan_d * tan_d
                q = lr_over_l * tan_d
                cb = 1.0 / sqrt(1.0 + q * q)  # cos(beta_k)
                sb = q * cb  # sin(beta_k)
                beta_k = math.atan(q)
                dbeta_k = lr_over_l * sec2 * sv * cb * cb
                r_k = v * cb * tan_d / wb
                dr_k = (a * cb * tan_d - v * sb * dbeta_k * tan_d + v * cb * sec2 * sv) / wb
                dr_kin = dr_k + (r_k - r) * tau_inv
                dr = (1.0 - w) * dr_kin
                dbeta = (1.0 - w) * (dbeta_k + (beta_k - beta) * tau_inv)
                dv_kin = a
                if not gym_exact:
                    # rolling without slip is workless: yaw energy comes out of the speed
                    p_yaw = iz * r * dr_kin
                    if p_yaw > 0.0 and speed > ENERGY_MIN_SPEED_MPS:
                        dv_kin = a - p_yaw / (m * v)
                dv = (1.0 - w) * dv_kin
            if w > 0.0:
                d_v, d_beta, d_r, _front, _rear = dynamic(v, beta, r, delta, a, a * v < 0.0)
                dr += w * d_r
                dbeta += w * d_beta
                dv += w * d_v
            return (dx, dy, sv, dv, r, dr, dbeta)  # d/dt of X, Y, DELTA, V, PSI, PSI_DOT, BETA

        return rhs

    # ------------------------------------------------------------------ helpers
    def derivative(self, state: np.ndarray, steering_rate: float, accel: float) -> np.ndarray:
        """``rhs`` with numpy in and out: (7,) state -> (7,) time derivative."""
        s = tuple(float(v) for v in np.asarray(state, dtype=float).reshape(NX))
        return np.array(self.rhs(s, float(steering_rate), float(accel)))  # type: ignore[arg-type]

    def tyre_state(self, state: StateTuple, accel: float) -> TyreState:
        """Axle loads, slip angles and lateral forces at `state` with acceleration `accel`.

        Diagnostic (telemetry, tests); the same tyre laws as ``rhs``. `accel` is taken as
        given (no limits). For ``linear`` tyres the gym's small-angle slips and no limit
        (inf); slip angles are 0 below ``kinematic_below_mps``.
        """
        delta = state[StateIndex.DELTA]
        v = state[StateIndex.V]
        r = state[StateIndex.PSI_DOT]
        beta = state[StateIndex.BETA]
        d = self._dynamic(v if v != 0.0 else 1e-9, beta, r, delta, accel, accel * v < 0.0)
        f, b = d.front, d.rear
        if abs(v) <= self.kinematic_below_mps:
            return TyreState(f.fz_n, b.fz_n, 0.0, 0.0, 0.0, 0.0, f.fy_max_n, b.fy_max_n)
        return TyreState(
            f.fz_n, b.fz_n, f.alpha_rad, b.alpha_rad, f.fy_n, b.fy_n, f.fy_max_n, b.fy_max_n
        )

    def kinematic_slip_and_yaw_rate(self, delta: float, v: float) -> tuple[float, float]:
        """(beta_k [rad], psi_dot_k [rad/s]) of the kinematic single-track at the CoG."""
        p = self.params
        beta_k = math.atan(p.lr_m * math.tan(delta) / p.wheelbase_m)
        return beta_k, v * math.cos(beta_k) * math.tan(delta) / p.wheelbase_m

    def _stiffness_constants(self) -> tuple[float, float, float, float, float]:
        p = self.params
        g = GRAVITY_MPS2
        wb = p.wheelbase_m
        if p.tyre_model == "pacejka":
            slope_f = p.mu * math.prod(p.pacejka_front[:3])
            slope_r = p.mu * math.prod(p.pacejka_rear[:3])
        else:
            slope_f = p.mu * p.cornering_stiffness_front_per_rad
            slope_r = p.mu * p.cornering_stiffness_rear_per_rad
        # cornering stiffness [N/rad] at the largest axle load under +-a_max
        a = p.accel_max_mps2
        cf = slope_f * p.mass_kg * (g * p.lr_m + a * p.cog_height_m) / wb
        cr = slope_r * p.mass_kg * (g * p.lf_m + a * p.cog_height_m) / wb
        return cf, cr, p.mass_kg, p.yaw_inertia_kgm2, wb

    def stiffness_bound(self, speed_abs: float) -> float:
        """Estimate [1/s] of the largest |eigenvalue| of the lateral/yaw dynamics at |v| [m/s].

        Eigenvalues of the linear-tyre Jacobian of (beta, psi_dot) on a straight line (the
        stiffest case: saturation only lowers the slope) at the larger axle load under
        +-a_max, scaled by the blend weight, plus the kinematic relaxation rate.
        """
        p = self.params
        w = blend_weight(speed_abs, self.kinematic_below_mps, self.kinematic_blend_mps)
        bound = (1.0 - w) / KINEMATIC_RELAX_S
        if w > 0.0:
            cf, cr, m, iz, _wb = self._stiff
            v = speed_abs
            lf, lr = p.lf_m, p.lr_m
            a11 = -(cf + cr) / (m * v)
            a12 = (lr * cr - lf * cf) / (m * v * v) - 1.0
            a21 = (lr * cr - lf * cf) / iz
            a22 = -(lf * lf * cf + lr * lr * cr) / (iz * v)
            half_trace = 0.5 * (a11 + a22)
            det = a11 * a22 - a12 * a21
            disc = half_trace * half_trace - det
            lam = abs(half_trace) + math.sqrt(disc) if disc >= 0.0 else math.sqrt(max(det, 0.0))
            bound += w * lam
        return bound
