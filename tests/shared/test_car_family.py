"""The robustness family's cars: the named ones and the seeded variants of the identified car
(``shared.evaluation.car_family``)."""

from __future__ import annotations

import pytest

from shared.config import config_from_dict
from shared.config.vehicle import REAL_CAR_IDENTIFIED
from shared.evaluation.car_family import (
    CARS,
    VARIED_RANGES,
    UnknownCarError,
    car_names,
    car_spec,
    varied_car,
    varied_factors,
)


def test_a_varied_car_is_the_same_for_the_same_seed_and_differs_between_seeds() -> None:
    assert varied_car(7) == varied_car(7)
    assert varied_factors(7) == varied_factors(7)
    assert varied_factors(7) != varied_factors(8)
    assert car_spec("varied:7") == varied_car(7)


@pytest.mark.parametrize("seed", [0, 1, 2, 3, 1001, 1002, 1003])
def test_a_varied_car_scales_the_identified_car_within_its_ranges(seed: int) -> None:
    """Each factor within ``VARIED_RANGES``; the car is a valid ``[vehicle]`` the planners
    are told; geometry, mass and the lock are the identified car's."""
    f = varied_factors(seed)
    assert set(f) == {name for name, _, _ in VARIED_RANGES}
    for name, lo, hi in VARIED_RANGES:
        assert lo <= f[name] <= hi, name
    spec = car_spec(f"varied:{seed}")
    assert spec.knows_car and spec.name == f"varied:{seed}"
    assert "simulator" not in spec.tables  # the planners' car is the simulated one
    car = config_from_dict(spec.tables).vehicle
    base = REAL_CAR_IDENTIFIED
    for field in ("mass_kg", "yaw_inertia_kgm2", "lf_m", "lr_m", "steering_max_rad", "mu"):
        assert getattr(car, field) == getattr(base, field)
    assert car.tyre_model == "pacejka"
    assert car.pacejka_front[2] == pytest.approx(base.pacejka_front[2] * f["front_D"])
    assert car.pacejka_rear[0] == pytest.approx(base.pacejka_rear[0] * f["rear_B"])
    assert car.pacejka_front[3] == base.pacejka_front[3]  # E is kept
    assert car.steering_time_constant_s == pytest.approx(
        base.steering_time_constant_s * f["steering_time_constant"])
    assert car.steering_rate_min_radps == -car.steering_rate_max_radps
    assert car.speed_gain_brake_per_s / car.speed_gain_accel_per_s == pytest.approx(
        base.speed_gain_brake_per_s / base.speed_gain_accel_per_s)


def test_car_names_take_varied_seeds_and_name_the_wrong_ones() -> None:
    assert car_names("varied:3, identified,varied:3") == ["varied:3", "identified"]
    for bad in ("varied:", "varied:x", "varied:-1", "tank"):
        with pytest.raises(UnknownCarError, match="varied:SEED"):
            car_names(f"default,{bad}")
    with pytest.raises(UnknownCarError):
        car_spec("varied:1.5")
    assert all(car_spec(name) is CARS[name] for name in CARS)
