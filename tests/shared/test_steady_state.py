"""The car in steady state on a path (``shared.vehicle.steady_state``): the linear law, and
Pacejka tyres slipping as their own magic formula says (``tyre_law=True``)."""

from __future__ import annotations

import numpy as np
import pytest

from shared.config.vehicle import F1TENTH_GYM, GRAVITY_MPS2, REAL_CAR_IDENTIFIED
from shared.vehicle.steady_state import PACEJKA_MAX_SHARE, steady_state_steering
from shared.vehicle.tyres import axle_peak_friction, pacejka_peak_slip_rad

CAR = REAL_CAR_IDENTIFIED


def _magic_share(alpha: np.ndarray, bcde: tuple[float, float, float, float]) -> np.ndarray:
    """sin(phi(alpha)): the share of the friction ellipse's lateral room the slip gives."""
    b, c, _d, e = bcde
    x = b * np.abs(alpha)
    return np.sin(c * np.arctan(x - e * (x - np.arctan(x))))


def test_the_gym_car_s_linear_tyres_are_the_same_either_way() -> None:
    kappa = np.linspace(-1.2, 1.2, 9)
    v = np.full(9, 3.5)
    v_dot = np.linspace(-3.0, 3.0, 9)
    for a, b in zip(steady_state_steering(kappa, v, v_dot, F1TENTH_GYM),
                    steady_state_steering(kappa, v, v_dot, F1TENTH_GYM, tyre_law=True),
                    strict=True):
        np.testing.assert_array_equal(a, b)


def test_pacejka_tyres_are_linear_at_small_slip_and_slip_more_near_their_peak() -> None:
    """``B C D`` is the cornering stiffness: a gentle bend steers as the linear law says;
    near the rear's peak the magic formula needs more slip on both axles, and the car
    (front D 0.65, rear 0.618, the rear stiffer) more steering."""
    kappa = np.array([0.5, 0.5])
    g = GRAVITY_MPS2
    v = np.sqrt(np.array([0.05, 0.85]) * 0.618 * g / kappa)  # 5 % and 85 % of the rear's mu
    zero = np.zeros(2)
    lin_d, lin_b, _ = steady_state_steering(kappa, v, zero, CAR)
    tyre_d, tyre_b, _ = steady_state_steering(kappa, v, zero, CAR, tyre_law=True)
    assert tyre_d[0] == pytest.approx(lin_d[0], rel=2e-3)
    assert tyre_b[0] == pytest.approx(lin_b[0], rel=2e-3, abs=1e-5)
    assert tyre_d[1] > lin_d[1] + 0.01  # the front's extra slip near the limit
    assert tyre_b[1] < lin_b[1]  # the rear slips more: the car points further in


def test_each_axle_s_slip_gives_the_force_the_bend_asks_within_its_ellipse() -> None:
    """Fed back into the magic formula, each axle's slip gives the share of the lateral room
    its ellipse leaves beside the acceleration demand (split by the loads) that the bend's
    lateral force takes, braking, coasting and driving."""
    lf, lr, wb, h = CAR.lf_m, CAR.lr_m, CAR.wheelbase_m, CAR.cog_height_m
    g = GRAVITY_MPS2
    kappa = np.full(3, 0.8)
    v = np.full(3, 2.0)
    v_dot = np.array([-2.0, 0.0, 1.5])
    delta, beta, accel = steady_state_steering(kappa, v, v_dot, CAR, tyre_law=True)
    a_y = v**2 * kappa
    alpha_r = np.arctan(lr * kappa) - beta
    alpha_f = delta - np.arctan(wb * kappa) + alpha_r
    for axle, alpha, fy, fz in (
        ("front", alpha_f, a_y * lr / wb, (g * lr - accel * h) / wb),
        ("rear", alpha_r, a_y * lf / wb, (g * lf + accel * h) / wb),
    ):
        cap = axle_peak_friction(CAR, axle) * fz
        room = np.sqrt(cap**2 - (fz * accel / g) ** 2)
        bcde = CAR.pacejka_front if axle == "front" else CAR.pacejka_rear
        np.testing.assert_allclose(_magic_share(alpha, bcde), fy / room, rtol=1e-6)
        assert np.all(np.abs(alpha) < pacejka_peak_slip_rad(CAR, axle))


def test_a_bend_beyond_the_peak_keeps_the_slip_just_below_it() -> None:
    """A path asking more lateral force than an axle has: its slip stops at the share
    ``PACEJKA_MAX_SHARE`` (the inverse has no slope at the peak), finite and signed."""
    kappa = np.array([-1.5, 1.5])
    v = np.full(2, 4.0)  # 24 m/s^2: far past either axle
    delta, beta, _ = steady_state_steering(kappa, v, np.zeros(2), CAR, tyre_law=True)
    assert np.all(np.isfinite(delta)) and np.all(np.isfinite(beta))
    assert np.sign(delta[0]) == -1 and np.sign(delta[1]) == 1
    alpha_r = np.arctan(CAR.lr_m * kappa) - beta
    np.testing.assert_allclose(_magic_share(alpha_r, CAR.pacejka_rear), PACEJKA_MAX_SHARE,
                               rtol=1e-6)
