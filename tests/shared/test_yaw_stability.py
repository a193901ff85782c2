"""The single-track model's yaw pole under braking (``shared.vehicle.yaw_stability``)."""

from __future__ import annotations

import casadi as ca
import numpy as np
import pytest

from shared.config.vehicle import F1TENTH_GYM, REAL_CAR_IDENTIFIED
from shared.vehicle import CASADI_OPS
from shared.vehicle.yaw_stability import (
    axle_cornering_stiffness,
    yaw_pole_margin,
    yaw_pole_per_s,
)


def test_braking_moves_stiffness_from_the_rear_to_the_front() -> None:
    cf0, cr0 = axle_cornering_stiffness(F1TENTH_GYM, 0.0)
    cf, cr = axle_cornering_stiffness(F1TENTH_GYM, -9.0)
    assert cf > cf0 and cr < cr0
    # the gym's tyres: mu C_S F_z, F_z from the static share plus the load transfer
    p = F1TENTH_GYM
    fzr = p.mass_kg * (9.81 * p.lf_m) / (p.lf_m + p.lr_m)
    assert cr0 == pytest.approx(p.mu * p.cornering_stiffness_rear_per_rad * fzr, rel=1e-3)


def test_the_gym_car_is_stable_at_the_papers_cap_and_diverges_braking_at_ten() -> None:
    """At 4.18 m/s no braking the car can do makes its yaw diverge; at 10 m/s and 9.3
    m/s^2 it diverges at about 8 1/s; unbraked it is stable at any speed (understeer)."""
    p = F1TENTH_GYM
    assert max(yaw_pole_per_s(p, 4.18, a) for a in np.linspace(-9.51, 0.0, 20)) < 0.0
    assert yaw_pole_per_s(p, 10.0, -9.3) == pytest.approx(8.2, abs=0.2)
    assert max(yaw_pole_per_s(p, v, 0.0) for v in (2.0, 5.0, 10.0, 20.0)) < 0.0


@pytest.mark.parametrize("car", [F1TENTH_GYM, REAL_CAR_IDENTIFIED], ids=["gym", "identified"])
def test_the_margin_is_non_negative_exactly_where_the_pole_is_within_the_bound(car) -> None:
    for v in (1.5, 3.0, 5.0, 7.5, 10.0):
        for a in (-9.0, -6.0, -3.0, -1.0, 0.0, 2.0):
            pole = yaw_pole_per_s(car, v, a)
            for bound in (0.0, 1.0, 2.0, 4.0, 8.0):
                if abs(pole - bound) > 1e-6:
                    assert (yaw_pole_margin(car, v, a, bound) >= 0.0) == (pole <= bound)


def test_the_margin_is_the_same_function_in_casadi() -> None:
    v, a = ca.SX.sym("v"), ca.SX.sym("a")
    f = ca.Function("m", [v, a], [yaw_pole_margin(F1TENTH_GYM, v, a, 2.0, CASADI_OPS)])
    for vv, aa in ((3.0, -2.0), (9.0, -7.5), (10.0, 1.0)):
        assert float(f(vv, aa)) == pytest.approx(yaw_pole_margin(F1TENTH_GYM, vv, aa, 2.0))


def test_a_negative_bound_is_rejected() -> None:
    with pytest.raises(ValueError, match="pole bound"):
        yaw_pole_margin(F1TENTH_GYM, 5.0, -3.0, -1.0)
