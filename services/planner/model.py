"""The kinematic bicycle of the paper (eq. 12), written once for CasADi and numpy.

State ``zeta = [X, Y, phi, s]`` (rear-axle position [m], yaw [rad], progress [m]);
input ``u = [v_l, delta, v_p]`` (speed [m/s], steering [rad], progress speed [m/s]).

    X'   = cos(phi) v_l
    Y'   = sin(phi) v_l
    phi' = tan(delta) / L v_l
    s'   = v_p
"""

from __future__ import annotations

from enum import IntEnum

import casadi as ca
import numpy as np


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


def kinematic_bicycle(wheelbase_m: float) -> ca.Function:
    """Continuous dynamics ``f(zeta, u) -> zeta_dot`` as a CasADi Function (SX inside).

    Args:
        wheelbase_m: L [m].

    Returns:
        Function ``f(x[4], u[3]) -> xdot[4]``; callable with numpy arrays too.
    """
    x = ca.SX.sym("x", NX)
    u = ca.SX.sym("u", NU)
    v = u[U.V_L]
    xdot = ca.vertcat(
        ca.cos(x[S.PHI]) * v,
        ca.sin(x[S.PHI]) * v,
        ca.tan(u[U.DELTA]) / wheelbase_m * v,
        u[U.V_P],
    )
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
