"""Conversions m/s, rad <-> ERPM, servo; invalid commands; odometry."""

from __future__ import annotations

import math

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from services.vesc_driver.conversions import convert_command
from shared.config.vesc import VescSettings
from shared.vesc.conversions import (
    erpm_to_speed,
    servo_to_steering,
    speed_to_erpm,
    steering_to_servo,
    yaw_rate_from,
)
from shared.vesc.protocol import encode_set_rpm, encode_set_servo_pos

DEFAULTS = VescSettings()


def test_known_answer() -> None:
    cmd = convert_command(2.0, 0.1, DEFAULTS)
    assert not cmd.brake and not cmd.out_of_range and not cmd.nonfinite
    assert cmd.erpm == pytest.approx(9228.0)
    assert cmd.servo_pos == pytest.approx(0.40905)
    # wire values: int32 9228, int16 409 (0.40905 * 1e3 = 409.05 rounds to 409)
    assert encode_set_rpm(cmd.erpm)[3:7] == (9228).to_bytes(4, "big")
    assert encode_set_servo_pos(cmd.servo_pos)[3:5] == (409).to_bytes(2, "big")


def test_formulas_and_inverses() -> None:
    assert speed_to_erpm(2.0, 4614.0, 0.0) == 9228.0
    assert speed_to_erpm(2.0, 4614.0, 10.0, -1) == -9218.0
    assert erpm_to_speed(-9218.0, 4614.0, 10.0, -1) == pytest.approx(2.0)
    assert steering_to_servo(0.0, -1.2135, 0.5304) == 0.5304
    assert servo_to_steering(0.40905, -1.2135, 0.5304) == pytest.approx(0.1)
    assert yaw_rate_from(2.0, 0.1, 0.324) == pytest.approx(2.0 * math.tan(0.1) / 0.324)
    assert yaw_rate_from(2.0, 0.0, 0.324) == 0.0


def test_speed_sign_round_trip() -> None:
    s = VescSettings(speed_sign=-1)
    cmd = convert_command(2.0, 0.0, s)
    assert cmd.erpm == pytest.approx(-9228.0)
    assert erpm_to_speed(cmd.erpm, s.speed_to_erpm_gain, 0.0, s.speed_sign) == pytest.approx(2.0)


@pytest.mark.parametrize(
    ("speed", "steer"),
    [(math.nan, 0.0), (1.0, math.nan), (math.inf, 0.0), (-math.inf, 0.0), (1.0, math.inf)],
)
@pytest.mark.parametrize("mode", ["brake", "clamp"])
def test_nonfinite_always_brakes(speed: float, steer: float, mode: str) -> None:
    cmd = convert_command(speed, steer, VescSettings(invalid_command=mode))
    assert cmd.brake and cmd.nonfinite and cmd.erpm is None
    if math.isfinite(steer):
        assert cmd.servo_pos == pytest.approx(0.5304)
    else:
        assert cmd.servo_pos is None  # the servo holds where it was


def test_overflow_to_inf_brakes() -> None:
    cmd = convert_command(1e308, 0.0, DEFAULTS)
    assert cmd.brake and cmd.nonfinite


def test_out_of_range_clamp_mode() -> None:
    s = VescSettings(invalid_command="clamp")
    fast = convert_command(10.0, 0.0, s)  # 46140 ERPM
    assert fast.out_of_range and not fast.brake and fast.erpm == 23250.0
    back = convert_command(-10.0, 0.0, s)
    assert back.erpm == -23250.0
    left = convert_command(1.0, 0.5, s)  # servo 0.5304 - 0.60675 < 0.15
    assert left.out_of_range and not left.brake and left.servo_pos == 0.15
    right = convert_command(1.0, -0.5, s)
    assert right.servo_pos == 0.85


def test_out_of_range_brake_mode() -> None:
    s = VescSettings(invalid_command="brake")
    fast = convert_command(10.0, 0.0, s)
    assert fast.brake and fast.out_of_range and fast.erpm is None
    steer = convert_command(1.0, 0.5, s)
    assert steer.brake and steer.servo_pos == 0.15  # the servo is still clamped and sent
    ok = convert_command(5.0, 0.3, s)  # 23070 ERPM, servo 0.16635: in range
    assert not ok.brake and not ok.out_of_range


@settings(max_examples=300, deadline=None)
@given(
    speed=st.floats(allow_nan=True, allow_infinity=True),
    steer=st.floats(allow_nan=True, allow_infinity=True),
    mode=st.sampled_from(["brake", "clamp"]),
)
def test_never_sends_anything_out_of_range(speed: float, steer: float, mode: str) -> None:
    s = VescSettings(invalid_command=mode)
    cmd = convert_command(speed, steer, s)
    if cmd.erpm is not None:
        assert -s.max_abs_erpm <= cmd.erpm <= s.max_abs_erpm
        encode_set_rpm(cmd.erpm)
    else:
        assert cmd.brake
    if cmd.servo_pos is not None:
        assert s.servo_min <= cmd.servo_pos <= s.servo_max
        encode_set_servo_pos(cmd.servo_pos)
    assert cmd.brake == (cmd.nonfinite or (cmd.out_of_range and mode == "brake"))
