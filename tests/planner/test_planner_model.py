"""The kinematic bicycle (paper eq. 12) against hand-computed values and derivatives."""

from __future__ import annotations

import casadi as ca
import numpy as np
import pytest

from services.planner.mpc.model import S, U, discretise, kinematic_bicycle, step_numpy

L = 0.324


def test_dynamics_values() -> None:
    f = kinematic_bicycle(L)
    x = np.array([1.0, 2.0, 0.3, 5.0])
    u = np.array([2.0, 0.1, 1.8])
    xdot = np.asarray(f(x, u)).ravel()
    np.testing.assert_allclose(
        xdot, [2.0 * np.cos(0.3), 2.0 * np.sin(0.3), 2.0 * np.tan(0.1) / L, 1.8]
    )


def test_jacobians_match_hand_derivatives() -> None:
    f = kinematic_bicycle(L)
    xs = ca.SX.sym("x", 4)
    us = ca.SX.sym("u", 3)
    jac = ca.Function("j", [xs, us], [ca.jacobian(f(xs, us), xs), ca.jacobian(f(xs, us), us)])
    phi, v, d = 0.7, 3.0, -0.2
    A, B = (np.asarray(m) for m in jac([0.0, 0.0, phi, 0.0], [v, d, 2.0]))
    A_hand = np.zeros((4, 4))
    A_hand[S.X, S.PHI] = -np.sin(phi) * v
    A_hand[S.Y, S.PHI] = np.cos(phi) * v
    B_hand = np.zeros((4, 3))
    B_hand[S.X, U.V_L] = np.cos(phi)
    B_hand[S.Y, U.V_L] = np.sin(phi)
    B_hand[S.PHI, U.V_L] = np.tan(d) / L
    B_hand[S.PHI, U.DELTA] = v / (L * np.cos(d) ** 2)
    B_hand[S.PROGRESS, U.V_P] = 1.0
    np.testing.assert_allclose(A, A_hand, atol=1e-12)
    np.testing.assert_allclose(B, B_hand, atol=1e-12)


def test_rk4_follows_the_exact_circle() -> None:
    v, d, dt = 2.0, 0.2, 0.05
    radius = L / np.tan(d)
    F = discretise(kinematic_bicycle(L), dt, "rk4")
    x = np.zeros(4)
    for _ in range(40):
        x = step_numpy(F, x, np.array([v, d, v]))
    t = 40 * dt
    phi = v * t / radius
    exact = [radius * np.sin(phi), radius * (1 - np.cos(phi)), phi, v * t]
    np.testing.assert_allclose(x, exact, atol=1e-6)


def test_euler_is_first_order() -> None:
    F = discretise(kinematic_bicycle(L), 0.1, "euler")
    x = step_numpy(F, np.array([0.0, 0.0, 0.5, 1.0]), np.array([2.0, 0.1, 1.5]))
    np.testing.assert_allclose(
        x, [0.2 * np.cos(0.5), 0.2 * np.sin(0.5), 0.5 + 0.2 * np.tan(0.1) / L, 1.15]
    )
    with pytest.raises(ValueError):
        discretise(kinematic_bicycle(L), 0.1, "midpoint")


def test_rk2_is_the_midpoint_rule_and_second_order() -> None:
    """``rk2``: one step is the midpoint rule; on the exact circle its error over a fixed
    time shrinks 4x when the step halves (euler's: 2x)."""
    f = kinematic_bicycle(L)
    x0, u = np.array([0.0, 0.0, 0.5, 1.0]), np.array([2.0, 0.2, 1.5])
    mid = x0 + 0.05 * np.asarray(f(x0, u)).ravel()
    np.testing.assert_allclose(
        step_numpy(discretise(f, 0.1, "rk2"), x0, u),
        x0 + 0.1 * np.asarray(f(mid, u)).ravel(),
        atol=1e-12,
    )
    v, d, t_end = 2.0, 0.2, 1.0
    radius = L / np.tan(d)
    phi = v * t_end / radius
    exact = np.array([radius * np.sin(phi), radius * (1 - np.cos(phi))])

    def error(method: str, dt: float) -> float:
        F, x = discretise(f, dt, method), np.zeros(4)
        for _ in range(round(t_end / dt)):
            x = step_numpy(F, x, np.array([v, d, v]))
        return float(np.hypot(*(x[:2] - exact)))

    assert error("rk2", 0.05) / error("rk2", 0.025) == pytest.approx(4.0, rel=0.1)
    assert error("euler", 0.05) / error("euler", 0.025) == pytest.approx(2.0, rel=0.1)
    assert error("rk2", 0.05) < 1e-3
