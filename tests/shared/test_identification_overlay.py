"""The identified car's ``[vehicle]`` overlay: which estimates it writes."""

from __future__ import annotations

import math

import numpy as np

from shared.config.vehicle import vehicle_preset
from shared.vehicle.identification import (
    FRICTION_UNUSED,
    PRODUCT_ONLY,
    Estimate,
    SysidResult,
)

BASE = vehicle_preset("f1tenth_gym", tyre_model="pacejka", mu=1.0,
                      pacejka_front=(10.0, 1.5, 1.0, 0.373), pacejka_rear=(10.0, 1.5, 1.0, 0.0))


def _result(**notes: tuple[float, float, bool, str]) -> SysidResult:
    est = {k: Estimate(k, v, s, ok, "", note) for k, (v, s, ok, note) in notes.items()}
    return SysidResult("pacejka", est, 60.0, np.zeros(2))


def test_a_friction_never_used_up_but_told_by_the_curve_is_written() -> None:
    """The neutral base D (1.0) would tell the planner twice the grip of a 0.46 g car."""
    res = _result(pacejka_rear_D=(0.46, 0.001, False, f"{FRICTION_UNUSED} (0.3 % ...)"),
                  pacejka_front_D=(0.49, 0.5, False, f"{FRICTION_UNUSED} (0.3 % ...)"))
    out = res.vehicle_overlay(BASE)
    assert out["pacejka_rear"][2] == 0.46
    assert out["pacejka_front"][2] == 1.0  # sigma beyond the identifiable share: the base's


def test_b_and_c_of_a_told_product_are_written_and_the_rest_keeps_the_base() -> None:
    res = _result(pacejka_rear_B=(14.0, 1.0, False, f"{PRODUCT_ONLY} (0.99)"),
                  pacejka_rear_C=(1.8, 0.2, False, f"{PRODUCT_ONLY} (0.99)"),
                  pacejka_front_B=(3.0, math.inf, False, "at its search bound"))
    out = res.vehicle_overlay(BASE)
    assert out["pacejka_rear"][:2] == [14.0, 1.8]
    assert out["pacejka_front"][0] == 10.0


def test_an_axle_s_curve_is_written_whole_once_any_of_it_is() -> None:
    """A rear B too uncertain to be identified on its own, beside a C and D that are: the
    fitted B goes with them (the base's neutral B = 10 beside C 1.6 would halve the tyre's
    stiffness); an axle none of whose letters is written keeps the base."""
    res = _result(pacejka_rear_B=(18.3, 11.0, False, "uncertainty 60 % of the value"),
                  pacejka_rear_C=(1.6, 0.26, True, ""),
                  pacejka_rear_D=(0.61, 0.001, True, ""),
                  pacejka_front_B=(5.0, 9.0, False, "uncertainty 180 % of the value"))
    out = res.vehicle_overlay(BASE)
    assert out["pacejka_rear"] == [18.3, 1.6, 0.61, 0.0]
    assert out["pacejka_front"] == [10.0, 1.5, 1.0, 0.373]


def _rate(value: float, identifiable: bool, seen: float) -> SysidResult:
    est = Estimate("steering_rate_max_radps", value, 0.1 if identifiable else math.inf,
                   identifiable, "rad/s", "" if identifiable else
                   f"never reached: at least {seen:.2f} rad/s seen",
                   lower_bound=math.nan if identifiable else seen)
    return SysidResult("pacejka", {est.name: est}, 60.0, np.zeros(2))


def test_a_rate_limit_not_told_is_planned_no_faster_than_seen() -> None:
    """The grippier benchmark car's servo slews at 2.24 rad/s, which the run saw but could
    not tell from its lag: the base's 3.2 rad/s would plan steering it cannot follow."""
    out = _rate(2.27, False, 2.2398).vehicle_overlay(BASE)
    assert out["steering_rate_max_radps"] == 2.24
    assert out["steering_rate_min_radps"] == -2.24


def test_a_rate_seen_above_the_base_keeps_the_base_and_a_told_rate_is_written() -> None:
    out = _rate(3.5, False, 3.4).vehicle_overlay(BASE)
    assert "steering_rate_max_radps" not in out  # the base's 3.2 stays
    out = _rate(2.5, True, math.nan).vehicle_overlay(BASE)
    assert out["steering_rate_max_radps"] == 2.5
    assert out["steering_rate_min_radps"] == -2.5
