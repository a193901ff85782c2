"""The car-to-car contact response (issue #24): no interpenetration left, momentum along the
normal conserved (up to the speed loss), speed lost at every impact, no response apart."""

from __future__ import annotations

import math

import numpy as np
import pytest

from services.simulator.collision import ContactParams, Motion, respond
from shared.car import CAR
from shared.vehicle.contact import box_contact

P = ContactParams(restitution=0.3, speed_loss=0.2)


def _depth(a: Motion, b: Motion) -> float:
    con = box_contact(np.array([a.x_m, a.y_m, a.yaw_rad]), np.array([b.x_m, b.y_m, b.yaw_rad]))
    return float(con.depth_m[0])


def test_a_rear_end_separates_the_cars_and_costs_speed() -> None:
    behind = Motion(0.0, 0.0, 0.0, 6.0, 0.0)
    ahead = Motion(CAR.length_m - 0.03, 0.01, 0.02, 4.0, 0.0)  # 3 cm into it
    a, b, impact = respond(behind, ahead, P)
    assert impact
    assert _depth(a, b) < 0.0  # apart after the response
    # momentum along the normal: (v_a + v_b) after = (1 - loss) (v_a + v_b) before
    n_before = behind.velocity + ahead.velocity
    n_after = a.velocity + b.velocity
    assert np.linalg.norm(n_after) == pytest.approx(0.8 * np.linalg.norm(n_before), rel=1e-6)
    # the relative normal speed turns round with the restitution, then the loss
    assert b.speed_mps - a.speed_mps == pytest.approx(0.8 * 0.3 * 2.0, abs=0.05)
    assert a.speed_mps + b.speed_mps < behind.speed_mps + ahead.speed_mps  # speed lost
    assert a.speed_mps < behind.speed_mps and b.speed_mps > ahead.speed_mps * 0.8


def test_a_side_swipe_pushes_sideways_and_never_interpenetrates() -> None:
    a0 = Motion(0.0, 0.0, 0.0, 5.0, 0.0)
    b0 = Motion(0.1, CAR.width_m - 0.02, -0.3, 5.0, 0.0)  # steering into a from its left
    a, b, impact = respond(a0, b0, P)
    assert impact and _depth(a, b) < 0.0
    assert a.y_m < a0.y_m and b.y_m > b0.y_m  # pushed apart along the normal
    assert abs(a.slip_rad) > 0.0 and abs(a.slip_rad) <= math.pi / 2
    assert math.hypot(*a.velocity) < 5.0 and math.hypot(*b.velocity) < 5.0


def test_overlap_while_separating_only_pushes_apart() -> None:
    a0 = Motion(0.0, 0.0, 0.0, 3.0, 0.0)
    b0 = Motion(CAR.length_m - 0.02, 0.0, 0.0, 5.0, 0.0)  # ahead and faster: separating
    a, b, impact = respond(a0, b0, P)
    assert not impact and _depth(a, b) < 0.0
    assert (a.speed_mps, b.speed_mps) == pytest.approx((3.0, 5.0))


def test_apart_is_no_contact() -> None:
    assert respond(Motion(0, 0, 0, 5, 0), Motion(2.0, 0, 0, 1, 0), P) is None


def test_a_car_pushed_backwards_gets_a_negative_speed_and_canonical_slip() -> None:
    m = Motion(0.0, 0.0, 0.0, 1.0, 0.0).with_velocity(0.0, 0.0, np.array([-2.0, 0.1]))
    assert m.speed_mps < 0.0 and abs(m.slip_rad) < 0.1
    assert m.velocity == pytest.approx([-2.0, 0.1])
