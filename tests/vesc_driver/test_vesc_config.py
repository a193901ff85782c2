"""The [vesc] configuration section."""

from __future__ import annotations

import pytest
from pydantic import ValidationError

from shared.config.vesc import VescSettings


def test_defaults() -> None:
    s = VescSettings()
    assert s.port == "/dev/sensors/vesc"
    assert (s.speed_to_erpm_gain, s.speed_to_erpm_offset, s.speed_sign) == (4614.0, 0.0, 1)
    assert (s.steering_angle_to_servo_gain, s.steering_angle_to_servo_offset) == (-1.2135, 0.5304)
    assert (s.servo_min, s.servo_max, s.max_abs_erpm) == (0.15, 0.85, 23250.0)
    assert s.wheelbase_m == 0.324 and s.command_rate_hz == 50 and s.command_timeout_s == 0.1
    assert s.brake_current_a == 20.0 and s.invalid_command == "clamp"


@pytest.mark.parametrize(
    "bad",
    [
        {"unknown_key": 1},
        {"speed_sign": 0},
        {"speed_sign": 2},
        {"command_rate_hz": 0},
        {"command_timeout_s": -0.1},
        {"command_timeout_s": float("nan")},
        {"brake_current_a": 500},
        {"wheelbase_m": 0},
        {"servo_min": 0.9, "servo_max": 0.1},
        {"steering_angle_to_servo_gain": 0.0},
        {"reconnect_backoff_initial_s": 5.0, "reconnect_backoff_max_s": 1.0},
        {"invalid_command": "ignore"},
        {"port": ""},
        {"speed_to_erpm_gain": -4614.0},
        {"speed_to_erpm_offset": 30000.0},
        {"max_payload_bytes": 10},
    ],
)
def test_rejects_bad_values(bad: dict[str, object]) -> None:
    with pytest.raises(ValidationError):
        VescSettings(**bad)


def test_frozen() -> None:
    s = VescSettings()
    with pytest.raises(ValidationError):
        s.port = "/dev/null"  # type: ignore[misc]


def test_from_dict() -> None:
    s = VescSettings.model_validate(
        {"port": "/tmp/vesc", "speed_sign": -1, "invalid_command": "brake"}
    )
    assert s.port == "/tmp/vesc" and s.speed_sign == -1 and s.invalid_command == "brake"


def test_vesc_and_lidar_ports_default_to_distinct_stable_names_and_must_differ() -> None:
    """Two drivers on one /dev/ttyACM0 would talk the wrong protocol to each other's device:
    the defaults are the udev links of each, and one path for both is a configuration error."""
    from shared.config import ConfigError, config_from_dict

    cfg = config_from_dict({})
    assert (cfg.vesc.port, cfg.lidar_driver.port) == ("/dev/sensors/vesc", "/dev/sensors/hokuyo")
    with pytest.raises(ConfigError, match="both '/dev/ttyACM0'"):
        config_from_dict(
            {"vesc": {"port": "/dev/ttyACM0"}, "lidar_driver": {"port": "/dev/ttyACM0"}}
        )
    by_id = "/dev/serial/by-id/usb-STMicroelectronics_ChibiOS_RT_Virtual_COM_Port_301-if00"
    assert config_from_dict({"vesc": {"port": by_id}}).vesc.port == by_id
