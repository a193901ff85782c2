"""The car in steady state on a path: the linear single-track model's steering, slip angle
and acceleration demand at a curvature and speed, with the axle loads of that demand.

Per unit mass, the moment balance puts ``l_r / L`` of ``a_y`` on the front axle::

    f_zf = (g l_r - a h) / L,        f_zr = (g l_f + a h) / L
    alpha_f = a_y l_r / (L mu C_Sf f_zf),   alpha_r = a_y l_f / (L mu C_Sr f_zr)
    delta = atan(L kappa) + alpha_f - alpha_r          (kinematic + understeer)
    beta  = atan(l_r kappa) - alpha_r

with ``a_y = v^2 kappa``, ``h`` the CoG height and ``C_Si`` the cornering stiffness per unit
load (``F_yi = mu C_Si F_zi alpha_i``, the gym's tyres). The raceline's tracker feeds this
steering forward; the MPC's slip model fits its understeer to it near the limit.

With ``tyre_law=True`` a car on Pacejka tyres (``shared.vehicle.tyres``) takes each axle's
slip from its own magic formula instead: the axle's share of the lateral force its friction
ellipse leaves beside the acceleration demand (split by the loads, ``F_xi = F_zi a / g``),

    u_i = |F_yi| / sqrt((mu_i F_zi)^2 - F_xi^2),   alpha_i = sign(F_yi) x_i / B_i,
    x_i - E_i (x_i - atan x_i) = tan(asin(u_i) / C_i)      (the rising branch, u_i < 1)

which is the linear law at small slip (``B C D`` is the cornering stiffness) and more slip
near the peak, where the linear law asks too little steering (the identified car's line at
its own speeds steered 0.03 rad more than the linear steady state in map416's bends).
"""

from __future__ import annotations

import numpy as np

from shared.config.vehicle import GRAVITY_MPS2, DynamicVehicleParams
from shared.vehicle.tyres import Axle, axle_peak_friction, pacejka_slip_for_share

#: Fixed-point iterations of the steady-state steering (loads <-> acceleration demand).
STEADY_STATE_ITERATIONS = 4
#: Largest share of an axle's peak force the steady state asks of Pacejka tyres (at the
#: peak the inverse has no slope; a path asking more keeps the slip at this share's).
PACEJKA_MAX_SHARE = 0.999


def steady_state_steering(
    kappa_1pm: np.ndarray,
    v_mps: np.ndarray,
    v_dot_mps2: np.ndarray,
    vehicle: DynamicVehicleParams,
    iterations: int = STEADY_STATE_ITERATIONS,
    tyre_law: bool = False,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(delta, beta, a) of the car on a path of curvature `kappa_1pm` at `v_mps`, speeding
    up at `v_dot_mps2`: the linear single-track model in steady state (module docstring),
    by fixed-point iteration (the loads depend on ``a``, ``a`` on the drag). `tyre_law`:
    Pacejka tyres slip as their magic formula says (module docstring); other tyres and
    False: the linear law.

    Returns:
        steering [rad], slip angle [rad], acceleration demand [m/s^2], each like `v_mps`.
    """
    g, h = GRAVITY_MPS2, vehicle.cog_height_m
    lf, lr, wb = vehicle.lf_m, vehicle.lr_m, vehicle.wheelbase_m
    c_f = vehicle.mu * vehicle.cornering_stiffness_front_per_rad
    c_r = vehicle.mu * vehicle.cornering_stiffness_rear_per_rad
    a_y = v_mps**2 * kappa_1pm
    accel = np.asarray(v_dot_mps2, dtype=float)
    for _ in range(iterations):
        # axle loads per unit mass and the slips that carry a_y (moment balance: l_r / L
        # of it on the front axle, l_f / L on the rear)
        fz_f = np.maximum(g * lr - accel * h, 1e-3 * g * lr) / wb
        fz_r = np.maximum(g * lf + accel * h, 1e-3 * g * lf) / wb
        if tyre_law and vehicle.tyre_model == "pacejka":
            alpha_f = _axle_slip(vehicle, "front", a_y * lr / wb, fz_f, accel)
            alpha_r = _axle_slip(vehicle, "rear", a_y * lf / wb, fz_r, accel)
        else:
            alpha_f = a_y * lr / wb / (c_f * fz_f)
            alpha_r = a_y * lf / wb / (c_r * fz_r)
        delta = np.arctan(wb * kappa_1pm) + alpha_f - alpha_r
        beta = np.arctan(lr * kappa_1pm) - alpha_r
        accel = v_dot_mps2 * np.cos(beta) - a_y * np.sin(beta) + a_y * lr / wb * np.tan(delta)
    return delta, beta, accel


def _axle_slip(
    vehicle: DynamicVehicleParams, axle: Axle, fy: np.ndarray, fz: np.ndarray,
    accel: np.ndarray,
) -> np.ndarray:
    """Slip angle [rad] of a Pacejka `axle` carrying lateral force `fy` on load `fz` (both
    per unit mass [m/s^2]) with the car's acceleration demand `accel` [m/s^2] split by the
    loads: the share of the friction ellipse's lateral room the force takes, inverted on
    the rising branch (``PACEJKA_MAX_SHARE`` at most)."""
    cap = axle_peak_friction(vehicle, axle) * fz
    fx = fz * accel / GRAVITY_MPS2
    room = np.sqrt(np.maximum(cap * cap - fx * fx, (1e-3 * cap) ** 2))
    share = fy / room
    return np.sign(share) * pacejka_slip_for_share(
        vehicle, axle, np.minimum(np.abs(share), PACEJKA_MAX_SHARE))
