"""Newton-Euler equations of the dynamic single-track car with physical tyres.

State quantities (SI units): speed ``v`` of the CoG [m/s] (signed, along the velocity
direction ``psi + beta``), slip angle ``beta`` [rad], yaw rate ``r`` [rad/s], front
road-wheel angle ``delta`` [rad]; input the longitudinal acceleration demand ``a``
[m/s^2] (after the actuator limits). ``L = lf + lr``.

Body-frame velocity ``vx = v cos(beta)``, ``vy = v sin(beta)``. Normal loads with
quasi-static load transfer::

    F_zf = m (g lr - a h) / L        F_zr = m (g lf + a h) / L        (each >= 0)

Contact-patch velocities in each wheel frame (front rotated by delta)::

    u_f = vx cos(delta) + (vy + lf r) sin(delta)     w_f = -vx sin(delta) + (vy + lf r) cos(delta)
    u_r = vx                                         w_r = vy - lr r

Each axle's force ``(F_xi, F_yi)`` in its wheel frame comes from ``shared.vehicle.tyres``
(bounded slip angle, friction ellipse). The front force rotated into the body frame::

    F_X = F_xf cos(delta) - F_yf sin(delta) + F_xr
    F_Y = F_xf sin(delta) + F_yf cos(delta) + F_yr
    M_z = lf (F_xf sin(delta) + F_yf cos(delta)) - lr F_yr

and, from ``m (vx' - r vy) = F_X``, ``m (vy' + r vx) = F_Y``, ``I_z r' = M_z``::

    v'    = (F_X cos(beta) + F_Y sin(beta)) / m
    beta' = (F_Y cos(beta) - F_X sin(beta)) / (m v) - r
    r'    = M_z / I_z

Energy: ``d/dt (m v^2 / 2 + I_z r^2 / 2)`` equals the power of the tyre forces at their
contact patches, ``sum_i F_xi u_i + F_yi w_i``. The lateral terms and the braking terms are
never positive (see ``shared.vehicle.tyres``), so without a driving force the car's kinetic
plus rotational energy never grows, however it slides or spins.

To first order in beta and delta these are the CommonRoad single-track equations (the gym's
``linear`` model); the differences that matter at the limit: slip angles stay bounded,
the front force acts in the wheel frame (``cos(delta)`` and the ``-F_yf sin(delta)`` drag
that scrubs speed in a slide), and the friction ellipse.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, NamedTuple

from shared.config.vehicle import DynamicVehicleParams
from shared.vehicle.ops import Ops
from shared.vehicle.tyres import make_axle_force_law

#: Gravitational acceleration [m/s^2].
GRAVITY_MPS2 = 9.81


class AxleForces(NamedTuple):
    """One axle's quantities in its wheel frame: forces [N], slip angle [rad], load [N]."""

    fx_n: Any
    fy_n: Any
    fy_max_n: Any
    alpha_rad: Any
    fz_n: Any


class DynamicDerivatives(NamedTuple):
    """``v'`` [m/s^2], ``beta'`` [rad/s], ``r'`` [rad/s^2] and both axles' forces."""

    dv: Any
    dbeta: Any
    dr: Any
    front: AxleForces
    rear: AxleForces


def normal_loads(p: DynamicVehicleParams, a: Any, ops: Ops) -> tuple[Any, Any]:
    """``(F_zf, F_zr)`` [N] at longitudinal acceleration `a` [m/s^2], each >= 0."""
    g, wb = GRAVITY_MPS2, p.lf_m + p.lr_m
    fzf = p.mass_kg * (g * p.lr_m - a * p.cog_height_m) / wb
    fzr = p.mass_kg * (g * p.lf_m + a * p.cog_height_m) / wb
    return ops.fmax(fzf, 0.0), ops.fmax(fzr, 0.0)


DynamicFn = Callable[..., DynamicDerivatives]


def make_dynamic_derivatives(
    p: DynamicVehicleParams, ops: Ops, saturate: bool = True, raw: bool = False
) -> DynamicFn:
    """``f(v, beta, r, delta, a, braking=False) -> DynamicDerivatives`` (module docstring).

    ``tyre_model = "linear"`` gives the F1TENTH gym's small-angle equations exactly
    (CommonRoad single-track, ``F_yi = mu C_Si F_zi alpha_i``, ``v' = a``; with signed
    speed ``sg = sign(v)``: ``alpha_f = sg (delta - beta) - lf r / |v|``,
    ``alpha_r = -sg beta + lr r / |v|``; ``beta' = (F_yf + F_yr) / (m v) - r``,
    ``r' = (lf F_yf - lr F_yr) / I_z``): unbounded forces, valid for small slip only.

    Args:
        p: the vehicle.
        ops: float or CasADi functions.
        saturate: False for the smooth tyre laws (an optimiser's constraints keep the forces
            inside the friction ellipse; see ``shared.vehicle.tyres``).
        raw: return plain tuples in the same order instead of the named records (the
            simulator's hot path: a named tuple costs more than the equations).

    ``v`` must not be 0 (the slip angle's rate has ``1 / v``); ``braking`` is a Python bool.
    """
    m, iz = p.mass_kg, p.yaw_inertia_kgm2
    lf, lr = p.lf_m, p.lr_m
    g, wb, h = GRAVITY_MPS2, p.lf_m + p.lr_m, p.cog_height_m
    cos, sin, fmax, fabs = ops.cos, ops.sin, ops.fmax, ops.fabs
    if p.tyre_model == "linear":
        kf = p.mu * p.cornering_stiffness_front_per_rad
        kr = p.mu * p.cornering_stiffness_rear_per_rad
        inf = float("inf")

        def gym(v: Any, beta: Any, r: Any, delta: Any, a: Any, braking: bool = False):
            fzf = fmax(m * (g * lr - a * h) / wb, 0.0)
            fzr = fmax(m * (g * lf + a * h) / wb, 0.0)
            inv = 1.0 / fabs(v)
            sg = v * inv
            alpha_f = sg * (delta - beta) - lf * r * inv
            alpha_r = -sg * beta + lr * r * inv
            fyf = kf * fzf * alpha_f
            fyr = kr * fzr * alpha_r
            return (
                a,
                (fyf + fyr) / (m * v) - r,
                (lf * fyf - lr * fyr) / iz,
                (0.0, fyf, inf, alpha_f, fzf),
                (0.0, fyr, inf, alpha_r, fzr),
            )

        return gym if raw else _named(gym)
    front = make_axle_force_law(p, "front", ops, saturate)
    rear = make_axle_force_law(p, "rear", ops, saturate)

    def f(v: Any, beta: Any, r: Any, delta: Any, a: Any, braking: bool = False):
        fzf = fmax(m * (g * lr - a * h) / wb, 0.0)
        fzr = fmax(m * (g * lf + a * h) / wb, 0.0)
        cb, sb = cos(beta), sin(beta)
        cd, sd = cos(delta), sin(delta)
        vx, vy = v * cb, v * sb
        vyf = vy + lf * r
        fxf, fyf, fyf_max, alpha_f = front(
            vx * cd + vyf * sd, vyf * cd - vx * sd, fzf, fzf * a / g, braking
        )
        fxr, fyr, fyr_max, alpha_r = rear(vx, vy - lr * r, fzr, fzr * a / g, braking)
        fyb_f = fxf * sd + fyf * cd
        fx_body = fxf * cd - fyf * sd + fxr
        fy_body = fyb_f + fyr
        return (
            (fx_body * cb + fy_body * sb) / m,
            (fy_body * cb - fx_body * sb) / (m * v) - r,
            (lf * fyb_f - lr * fyr) / iz,
            (fxf, fyf, fyf_max, alpha_f, fzf),
            (fxr, fyr, fyr_max, alpha_r, fzr),
        )

    return f if raw else _named(f)


def _named(f: Callable[..., tuple]) -> DynamicFn:
    """Wrap a raw derivative function so that it returns ``DynamicDerivatives``."""

    def named(v: Any, beta: Any, r: Any, delta: Any, a: Any, braking: bool = False):
        dv, dbeta, dr, front, rear = f(v, beta, r, delta, a, braking)
        return DynamicDerivatives(dv, dbeta, dr, AxleForces(*front), AxleForces(*rear))

    return named
