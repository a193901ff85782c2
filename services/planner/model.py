"""The kinematic bicycle of the paper (eq. 12), written once for CasADi and numpy.

State ``zeta = [X, Y, phi, s]`` (rear-axle position [m], yaw [rad], progress [m]);
input ``u = [v_l, delta, v_p]`` (speed [m/s], steering [rad], progress speed [m/s]).

    X'   = cos(phi) v_l
    Y'   = sin(phi) v_l
    phi' = tan(delta) / L v_l
    s'   = v_p

``SlipModel`` extends it with the single-track car's steady-state tyre slip (linear tyres,
small angles; e.g. Rajamani, *Vehicle Dynamics and Control*, sec. 3.3): at lateral
acceleration ``a_y = v_l^2 kappa`` the axles slip by ``alpha_i = a_y / (g C_i)`` (C_i: the
axle's cornering stiffness per unit load), so the same steering turns less,
``tan(delta) = kappa (L + K_us v_l^2)`` with ``K_us = (1/C_f - 1/C_r) / g``, and the rear
axle moves at ``-alpha_r`` to the car's heading (it slides outwards)::

    kappa = tan(delta) / (L + K_us v_l^2)        beta_r = -c_r v_l^2 kappa,  c_r = 1 / (g C_r)
    X'    = cos(phi + beta_r) v_l
    Y'    = sin(phi + beta_r) v_l
    phi'  = kappa v_l
    s'    = v_p

With ``K_us = c_r = 0`` it is the paper's model (and ``kinematic_bicycle`` builds exactly
that expression then).
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import IntEnum

import casadi as ca
import numpy as np

from shared.config.vehicle import DynamicVehicleParams

#: Standard gravity [m/s^2].
GRAVITY_MPS2 = 9.81


class S(IntEnum):
    """Index of each element of the model state."""

    X = 0
    Y = 1
    PHI = 2
    PROGRESS = 3


class U(IntEnum):
    """Index of each element of the model input."""

    V_L = 0
    DELTA = 1
    V_P = 2


NX = len(S)
NU = len(U)


@dataclass(frozen=True)
class SlipModel:
    """The kinematic bicycle's parameters with steady-state tyre slip (module docstring).

    Attributes:
        wheelbase_m: L [m].
        understeer_s2pm: K_us [s^2/m]: the understeer gradient, the extra steering
            ``K_us a_y`` [rad] at lateral acceleration ``a_y`` [m/s^2] (0: none).
        rear_slip_s2pm: c_r [s^2/m]: the rear axle's slip angle ``c_r a_y`` [rad]
            (0: none).
    """

    wheelbase_m: float
    understeer_s2pm: float = 0.0
    rear_slip_s2pm: float = 0.0

    @classmethod
    def for_vehicle(cls, vehicle: DynamicVehicleParams) -> SlipModel:
        """The slip of `vehicle`'s tyres at small angles: ``C_i = mu C_Si`` (linear tyres)
        or ``mu D_i C_i B_i`` (the magic formula's slope at zero slip)."""
        if vehicle.tyre_model == "pacejka":
            b_f, c_f, d_f, _ = vehicle.pacejka_front
            b_r, c_r, d_r, _ = vehicle.pacejka_rear
            front, rear = vehicle.mu * b_f * c_f * d_f, vehicle.mu * b_r * c_r * d_r
        else:
            front = vehicle.mu * vehicle.cornering_stiffness_front_per_rad
            rear = vehicle.mu * vehicle.cornering_stiffness_rear_per_rad
        g = GRAVITY_MPS2
        return cls(vehicle.wheelbase_m, (1.0 / front - 1.0 / rear) / g, 1.0 / (g * rear))

    @property
    def is_kinematic(self) -> bool:
        """No slip: the paper's kinematic bicycle."""
        return self.understeer_s2pm == 0.0 and self.rear_slip_s2pm == 0.0


def kinematic_bicycle(wheelbase_m: float, slip: SlipModel | None = None) -> ca.Function:
    """Continuous dynamics ``f(zeta, u) -> zeta_dot`` as a CasADi Function (SX inside).

    Args:
        wheelbase_m: L [m] (of the paper's model; ignored when `slip` is given).
        slip: the steady-state slip extension (module docstring); None or no slip: the
            paper's model, eq. 12.

    Returns:
        Function ``f(x[4], u[3]) -> xdot[4]``; callable with numpy arrays too.
    """
    x = ca.SX.sym("x", NX)
    u = ca.SX.sym("u", NU)
    v = u[U.V_L]
    if slip is None or slip.is_kinematic:
        L = wheelbase_m if slip is None else slip.wheelbase_m
        xdot = ca.vertcat(
            ca.cos(x[S.PHI]) * v,
            ca.sin(x[S.PHI]) * v,
            ca.tan(u[U.DELTA]) / L * v,
            u[U.V_P],
        )
    else:
        kappa = ca.tan(u[U.DELTA]) / (slip.wheelbase_m + slip.understeer_s2pm * v**2)
        course = x[S.PHI] - slip.rear_slip_s2pm * v**2 * kappa
        xdot = ca.vertcat(ca.cos(course) * v, ca.sin(course) * v, kappa * v, u[U.V_P])
    return ca.Function("kinematic_bicycle", [x, u], [xdot], ["x", "u"], ["xdot"])


def discretise(f: ca.Function, dt_s: float, integrator: str = "rk4") -> ca.Function:
    """One step ``F(x_k, u_k) -> x_{k+1}`` of `f` over `dt_s` [s], input held constant.

    Args:
        f: continuous dynamics ``f(x, u)``.
        dt_s: step Ts [s].
        integrator: ``"rk4"`` (classic 4-stage Runge-Kutta) or ``"euler"`` (forward Euler, as
            the authors' code).
    """
    x = ca.SX.sym("x", f.size1_in(0))
    u = ca.SX.sym("u", f.size1_in(1))
    if integrator == "euler":
        x_next = x + dt_s * f(x, u)
    elif integrator == "rk4":
        k1 = f(x, u)
        k2 = f(x + dt_s / 2 * k1, u)
        k3 = f(x + dt_s / 2 * k2, u)
        k4 = f(x + dt_s * k3, u)
        x_next = x + dt_s / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
    else:
        raise ValueError(f"unknown integrator {integrator!r}")
    return ca.Function("F", [x, u], [x_next], ["x", "u"], ["x_next"])


def step_numpy(F: ca.Function, x: np.ndarray, u: np.ndarray) -> np.ndarray:
    """Evaluate a discrete step with numpy in and out: (4,) state, (3,) input -> (4,) state."""
    return np.asarray(F(x, u), dtype=float).reshape(-1)
