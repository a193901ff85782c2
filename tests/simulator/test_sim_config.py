"""Simulator and vehicle settings: F1TENTH defaults, the identified preset, validation."""

from __future__ import annotations

import pytest
from pydantic import ValidationError

from shared.config.simulator import SimulatorSettings
from shared.config.vehicle import (
    F1TENTH_GYM,
    REAL_CAR_IDENTIFIED,
    DynamicVehicleParams,
    vehicle_preset,
)


def test_vehicle_defaults_are_the_f1tenth_gym_table() -> None:
    p = DynamicVehicleParams()
    assert p == F1TENTH_GYM
    assert (p.mu, p.cornering_stiffness_front_per_rad, p.cornering_stiffness_rear_per_rad) == (
        1.0489,
        4.718,
        5.4562,
    )
    assert (p.lf_m, p.lr_m, p.cog_height_m, p.mass_kg, p.yaw_inertia_kgm2) == (
        0.15875,
        0.17145,
        0.074,
        3.74,
        0.04712,
    )
    assert (p.steering_min_rad, p.steering_max_rad) == (-0.4189, 0.4189)
    assert (p.steering_rate_min_radps, p.steering_rate_max_radps) == (-3.2, 3.2)
    assert (p.v_switch_mps, p.accel_max_mps2, p.v_min_mps, p.v_max_mps) == (7.319, 9.51, -5.0, 20.0)
    assert (p.width_m, p.length_m) == (0.31, 0.58)
    assert p.tyre_model == "linear_saturated"
    assert p.wheelbase_m == pytest.approx(0.3302)


def test_real_car_preset_and_overrides() -> None:
    p = REAL_CAR_IDENTIFIED
    assert p.preset == "real_car_identified"
    assert (p.mass_kg, p.yaw_inertia_kgm2, p.lf_m, p.lr_m, p.cog_height_m) == (
        3.54,
        0.05797,
        0.162,
        0.145,
        0.014,
    )
    assert p.steering_time_constant_s == 0.158
    assert p.tyre_model == "pacejka"
    assert p.pacejka_front == (4.80, 2.16, 0.650, 0.373)
    assert p.pacejka_rear == (20.0, 1.5, 0.618, 0.0)
    # not identified: kept at the gym values
    assert (p.v_switch_mps, p.accel_max_mps2, p.width_m) == (7.319, 9.51, 0.31)
    q = vehicle_preset("real_car_identified", mass_kg=3.9)
    assert q.mass_kg == 3.9 and q.lf_m == 0.162
    # a dump validates back to the same object (preset + explicit values)
    assert DynamicVehicleParams.model_validate(q.model_dump()) == q


def test_simulator_defaults() -> None:
    s = SimulatorSettings()
    assert s.integration_step_s == 0.01
    assert s.steering_delay_s == 0.02 and s.command_timeout_s == 0.1
    assert (s.pose.rate_hz, s.pose.latency_s) == (40.0, 0.02)
    assert (s.lidar.rate_hz, s.lidar.beams, s.lidar.fov_rad, s.lidar.range_max_m) == (
        20.0,
        1080,
        4.7,
        30.0,
    )
    assert s.lidar.noise_std_m == 0.01
    assert s.kinematic_below_mps == 0.5
    assert s.off_track_policy == "continue"
    assert s.vehicle == F1TENTH_GYM
    nested = SimulatorSettings.model_validate({"vehicle": {"preset": "real_car_identified"}})
    assert nested.vehicle == REAL_CAR_IDENTIFIED


@pytest.mark.parametrize(
    "data",
    [
        {"integration_step_s": 0.02},
        {"integration_step_s": 0.0},
        {"steering_delay_s": -0.01},
        {"command_timeout_s": 0.005},
        {"unknown": 1},
        {"pose": {"rate_hz": 0}},
        {"lidar": {"beams": 1}},
        {"off_track_policy": "explode"},
        {"vehicle": {"mu": float("nan")}},
        {"vehicle": {"preset": "go-kart"}},
        {"vehicle": {"v_min_mps": 1.0}},
        {"vehicle": {"cog_height_m": 0.9}},
        {"vehicle": {"pacejka_front": [1.0, 1.0, 1.0]}},
    ],
)
def test_invalid_settings_are_rejected(data: dict) -> None:
    with pytest.raises(ValidationError):
        SimulatorSettings.model_validate(data)


def test_settings_are_frozen() -> None:
    s = SimulatorSettings()
    with pytest.raises(ValidationError):
        s.integration_step_s = 0.005  # type: ignore[misc]
