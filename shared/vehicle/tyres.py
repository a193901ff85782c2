"""Tyre force laws of one axle, valid for any slip and speed (floats or CasADi).

Frames and signs. Each axle sees the velocity of its contact patch in its own wheel frame:
``u`` along the wheel [m/s] and ``w`` across it (left positive) [m/s]. The slip angle is

    alpha = atan2(-w, |u|)            in [-pi/2, pi/2]  (bounded for any velocity)

(for small angles ``alpha = -w / u``, the single-track model's ``delta - beta - lf r / v`` at
the front and ``-beta + lr r / v`` at the rear). The lateral force has the sign of alpha, so
it always opposes the lateral sliding of the patch: its power ``F_y w`` is never positive.

Longitudinal force. The drive or brake force of the whole car, ``m a``, is split in
proportion to the normal loads (``F_x,dem = F_z a / g``: both axles use the same fraction of
their grip, as on the 4WD F1TENTH chassis). A driving force pushes along the wheel. A
braking force (``a`` reduces ``|v|``) opposes the patch's rolling velocity ``u``:
``F_x = -|F_x,dem| sat(u / u_0)`` with ``sat`` a linear ramp inside ``|u| < u_0``
(``BRAKE_SIGN_RAMP_MPS``), so a brake never pushes a wheel that rolls backwards in a spin and
its power ``F_x u`` is never positive either. ``|F_x| <= mu_i F_z``.

Combined slip (friction ellipse, longitudinal first): what the longitudinal force leaves,

    F_y,max = sqrt((mu_i F_z)^2 - F_x^2)

bounds the lateral force, so braking or driving reduces lateral grip. ``mu_i`` is the axle's
peak friction: ``mu`` (``linear_saturated``) or ``mu D_i`` (``pacejka``).

Lateral laws:

- ``linear_saturated`` (the default): ``F_y = clip(mu C_Si F_z alpha, -F_y,max, F_y,max)``,
  the gym's linear tyre (CommonRoad single-track, Althoff et al., "CommonRoad: Vehicle
  Models", 2020) clipped to the friction ellipse. A sliding axle keeps its full friction
  force, Coulomb-like, against the sliding direction.
- ``pacejka``: Pacejka's magic formula (Pacejka, "Tire and Vehicle Dynamics", 3rd ed.,
  ch. 4) ``F_y = F_y,max sin(phi)``, ``phi = C atan(B alpha - E (B alpha - atan(B alpha)))``,
  scaled to the ellipse. With ``C > 1`` it falls past its peak towards ``D sin(C pi / 2)``;
  with ``C > 2`` (the identified car's front, C = 2.16, fitted on small slips only) it would
  reverse sign at large slip and push the car along its slide, creating energy. ``phi`` is
  therefore capped at ``PACEJKA_PHI_MAX_RAD = 3 pi / 4``: past that slip the force stays at
  ``F_y,max / sqrt(2)``, the sliding level of the identified rear tyre (C = 1.5) and a usual
  sliding-to-peak friction ratio. Curves with ``C <= 1.5`` are unchanged.

``saturate=False`` gives the smooth laws for an optimiser, which then keeps ``|F_y| <=
F_y,max`` (and, for Pacejka, ``|alpha|`` below the peak slip) as constraints: inside those,
the smooth and the saturated laws are the same function.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any, Literal

from shared.config.vehicle import DynamicVehicleParams
from shared.vehicle.ops import Ops

#: Half-width [m/s] of the ramp that turns a braking force's sign with the wheel's rolling
#: velocity (see the module docstring).
BRAKE_SIGN_RAMP_MPS = 0.1
#: Cap on the magic formula's angle phi [rad] (see the module docstring).
PACEJKA_PHI_MAX_RAD = 0.75 * math.pi

Axle = Literal["front", "rear"]
#: ``law(u, w, fz, fx_demand, braking) -> (fx, fy, fy_max, alpha)`` (see make_axle_force_law).
AxleForceLaw = Callable[[Any, Any, Any, Any, bool], tuple[Any, Any, Any, Any]]


def axle_peak_friction(p: DynamicVehicleParams, axle: Axle) -> float:
    """Peak friction coefficient ``mu_i`` [-] of an axle (inf for the gym's linear tyres)."""
    if p.tyre_model == "linear":
        return math.inf
    if p.tyre_model == "pacejka":
        return p.mu * (p.pacejka_front if axle == "front" else p.pacejka_rear)[2]
    return p.mu


def pacejka_peak_slip_rad(p: DynamicVehicleParams, axle: Axle) -> float:
    """Slip angle [rad] at which the magic formula peaks (``phi = pi / 2``)."""
    b, c, _d, e = p.pacejka_front if axle == "front" else p.pacejka_rear
    target = math.tan(0.5 * math.pi / c)  # x_eff at the peak
    lo, hi = 0.0, 50.0
    for _ in range(200):  # x_eff(x) = x - E (x - atan x) is increasing
        mid = 0.5 * (lo + hi)
        if mid - e * (mid - math.atan(mid)) < target:
            lo = mid
        else:
            hi = mid
    return 0.5 * (lo + hi) / b


#: Newton steps of the magic formula's inverse (``pacejka_slip_for_share``): from ``x = t``
#: the rising ``x - E (x - atan x) = t`` (E < 1) is solved to rounding in fewer.
PACEJKA_NEWTON_STEPS = 8


def pacejka_slip_for_share(p: DynamicVehicleParams, axle: Axle, share: Any) -> Any:
    """Slip angle(s) [rad] below the peak at which the magic formula gives `share` (in [0, 1],
    numpy array or float) of the axle's peak force: the inverse of ``sin(phi(alpha))`` on
    its rising branch (``share`` 1: the peak slip), by Newton's method. Pure lateral force,
    no longitudinal."""
    import numpy as np

    b, c, _d, e = p.pacejka_front if axle == "front" else p.pacejka_rear
    u = np.clip(np.asarray(share, dtype=float), 0.0, 1.0)
    target = np.tan(np.arcsin(u) / c)  # x_eff = x - E (x - atan x), increasing in x
    x = target.copy()
    for _ in range(PACEJKA_NEWTON_STEPS):
        f = x - e * (x - np.arctan(x)) - target
        x = np.maximum(x - f / (1.0 - e + e / (1.0 + x * x)), 0.0)
    out = x / b
    return float(out) if np.ndim(out) == 0 else out


def make_axle_force_law(
    p: DynamicVehicleParams, axle: Axle, ops: Ops, saturate: bool = True
) -> AxleForceLaw:
    """The force law of one axle (see the module docstring).

    Args:
        p: the vehicle (``tyre_model`` ``linear_saturated`` or ``pacejka``).
        axle: which axle.
        ops: float or CasADi functions.
        saturate: False gives the smooth law for an optimiser (no clip, no phi cap).

    Returns:
        ``law(u, w, fz, fx_demand, braking) -> (fx, fy, fy_max, alpha)``: patch velocity
        along / across the wheel [m/s], normal load [N], longitudinal force demand [N],
        whether it brakes (a Python bool; an optimiser driving forwards passes False) ->
        longitudinal and lateral force [N], the lateral limit [N], the slip angle [rad].
    """
    if p.tyre_model == "linear":
        raise ValueError("the gym's linear tyres use the small-angle equations, not this law")
    mu_i = axle_peak_friction(p, axle)
    atan, atan2, sqrt = ops.atan, ops.atan2, ops.sqrt
    fmin, fmax, fabs, sin = ops.fmin, ops.fmax, ops.fabs, ops.sin
    ramp = BRAKE_SIGN_RAMP_MPS

    def longitudinal(u: Any, fz: Any, fx_dem: Any, braking: bool) -> tuple[Any, Any]:
        cap = mu_i * fz
        if braking:
            sat = fmin(fmax(u / ramp, -1.0), 1.0)
            fx = -fmin(fabs(fx_dem), cap) * sat
        else:
            fx = fmin(fmax(fx_dem, -cap), cap) if saturate else fx_dem
        fy_max = sqrt(fmax(cap * cap - fx * fx, 0.0)) if saturate else sqrt(cap * cap - fx * fx)
        return fx, fy_max

    if p.tyre_model == "linear_saturated":
        k = p.mu * (
            p.cornering_stiffness_front_per_rad
            if axle == "front"
            else p.cornering_stiffness_rear_per_rad
        )

        def saturated(u: Any, w: Any, fz: Any, fx_dem: Any, braking: bool):
            fx, fy_max = longitudinal(u, fz, fx_dem, braking)
            alpha = atan2(-w, fabs(u))
            fy = k * fz * alpha
            if saturate:
                fy = fmin(fmax(fy, -fy_max), fy_max)
            return fx, fy, fy_max, alpha

        return saturated

    b, c, _d, e = p.pacejka_front if axle == "front" else p.pacejka_rear
    phi_max = PACEJKA_PHI_MAX_RAD

    def magic(u: Any, w: Any, fz: Any, fx_dem: Any, braking: bool):
        fx, fy_max = longitudinal(u, fz, fx_dem, braking)
        alpha = atan2(-w, fabs(u))
        x = b * alpha
        phi = c * atan(x - e * (x - atan(x)))
        if saturate:
            phi = fmin(fmax(phi, -phi_max), phi_max)
        return fx, fy_max * sin(phi), fy_max, alpha

    return magic
