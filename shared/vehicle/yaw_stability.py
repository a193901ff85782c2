"""How fast the car's yaw diverges while it brakes: the single-track model's unstable pole.

Pure maths, floats or CasADi (``shared.vehicle.ops``). Braking moves load from the rear
axle to the front (``shared.vehicle.single_track.normal_loads``): the front's cornering
stiffness grows, the rear's shrinks, and past a point the car oversteers. Above its critical
speed an oversteering car's yaw diverges on its own; a tracker must then catch it within its
delays. The gym car (``linear_saturated``, mu 1.0489) oversteers at more than about
1.6 m/s^2 of braking, and braking at 9.3 m/s^2 its critical speed is 4.4 m/s: at 10 m/s the
yaw diverges at 8.2 1/s (its time constant 0.12 s, against the tracker's 60-90 ms from pose
to road wheels); at the paper's 4.18 m/s cap the car is stable at any braking. At
``--v-max 10`` on the generator's tracks the raceline spun braking on straights into bends
(gen-1005: rear slip 0.009 -> 0.2 rad in 0.3 s at -9.3 m/s^2, steering 0.01 rad; issue 21).

Linearised about straight running at speed ``v`` with longitudinal acceleration ``a``
(state ``[beta, r]``; ``C_i`` [N/rad] each axle's small-slip cornering stiffness at its load,
``L = l_f + l_r``)::

    A = [[-(C_f + C_r) / (m v),          (C_r l_r - C_f l_f) / (m v^2) - 1],
         [(C_r l_r - C_f l_f) / I_z,     -(C_f l_f^2 + C_r l_r^2) / (I_z v)]]

Its larger eigenvalue is at most ``lambda`` iff ``lambda >= tr(A) / 2`` (always, for
``lambda >= 0``: the trace is negative) and ``p(lambda) = lambda^2 - tr(A) lambda + det(A)
>= 0``; times ``m I_z v^2 > 0`` that is the polynomial::

    P = lambda^2 m I_z v^2 + lambda v (I_z (C_f + C_r) + m (C_f l_f^2 + C_r l_r^2))
        + C_f C_r L^2 + m v^2 (C_r l_r - C_f l_f)  >=  0

(``yaw_pole_margin`` returns ``P`` over its static value ``C_f0 C_r0 L^2`` at ``a = 0``, so it
is of order one). The stiffnesses: ``mu C_Si F_zi`` (``linear_saturated``, ``linear``), or
the magic formula's slope at zero slip, ``B_i C_i sqrt((mu D_i F_zi)^2 - F_xi^2)`` with the
axle's share of the braking force ``F_xi = F_zi a / g`` (``pacejka``: the ellipse shrinks its
whole curve).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from shared.config.vehicle import DynamicVehicleParams
from shared.vehicle.ops import FLOAT_OPS, Ops
from shared.vehicle.single_track import GRAVITY_MPS2, normal_loads
from shared.vehicle.tyres import axle_peak_friction


def axle_cornering_stiffness(
    p: DynamicVehicleParams, a_mps2: Any, ops: Ops = FLOAT_OPS
) -> tuple[Any, Any]:
    """``(C_f, C_r)`` [N/rad]: each axle's small-slip cornering stiffness at the loads of
    longitudinal acceleration `a_mps2` [m/s^2] (module docstring)."""
    fzf, fzr = normal_loads(p, a_mps2, ops)
    if p.tyre_model != "pacejka":
        return (p.mu * p.cornering_stiffness_front_per_rad * fzf,
                p.mu * p.cornering_stiffness_rear_per_rad * fzr)
    out = []
    for axle, fz, (b, c, _d, _e) in (("front", fzf, p.pacejka_front),
                                     ("rear", fzr, p.pacejka_rear)):
        cap = axle_peak_friction(p, axle) * fz
        fx = fz * a_mps2 / GRAVITY_MPS2
        out.append(b * c * ops.sqrt(ops.fmax(cap * cap - fx * fx, 0.0)))
    return out[0], out[1]


def yaw_pole_margin(
    p: DynamicVehicleParams, v_mps: Any, a_mps2: Any, pole_per_s: float, ops: Ops = FLOAT_OPS
) -> Any:
    """``P / (C_f0 C_r0 L^2)`` [-] (module docstring): >= 0 iff the car's yaw, running
    straight at `v_mps` [m/s] (> 0) with acceleration `a_mps2` [m/s^2], diverges no faster
    than `pole_per_s` [1/s] (>= 0; 0: the car is stable)."""
    if pole_per_s < 0.0:
        raise ValueError(f"the pole bound must be >= 0 1/s, got {pole_per_s}")
    m, iz = p.mass_kg, p.yaw_inertia_kgm2
    lf, lr = p.lf_m, p.lr_m
    wb = lf + lr
    cf, cr = axle_cornering_stiffness(p, a_mps2, ops)
    cf0, cr0 = axle_cornering_stiffness(p, 0.0, FLOAT_OPS)
    lam = float(pole_per_s)
    poly = (lam * lam * m * iz * v_mps * v_mps
            + lam * v_mps * (iz * (cf + cr) + m * (cf * lf * lf + cr * lr * lr))
            + cf * cr * wb * wb
            + m * v_mps * v_mps * (cr * lr - cf * lf))
    return poly / (cf0 * cr0 * wb * wb)


def yaw_pole_per_s(p: DynamicVehicleParams, v_mps: float, a_mps2: float) -> float:
    """The larger real part [1/s] of the linearised yaw modes at `v_mps` [m/s] (> 0) and
    `a_mps2` [m/s^2] (positive: the yaw diverges). Floats only."""
    m, iz, lf, lr = p.mass_kg, p.yaw_inertia_kgm2, p.lf_m, p.lr_m
    cf, cr = axle_cornering_stiffness(p, a_mps2)
    v = float(v_mps)
    a_mat = np.array([
        [-(cf + cr) / (m * v), (cr * lr - cf * lf) / (m * v * v) - 1.0],
        [(cr * lr - cf * lf) / iz, -(cf * lf * lf + cr * lr * lr) / (iz * v)],
    ])
    return float(np.max(np.linalg.eigvals(a_mat).real))
