"""Settings of the VESC driver: serial port, conversions, limits, rates and safety timeouts.

Conversion conventions are those of the F1TENTH VESC driver
(``../shared/docs/vehicle-and-vesc.md``)::

    erpm  = speed_to_erpm_gain * (speed_sign * v) + speed_to_erpm_offset
    servo = steering_angle_to_servo_gain * delta + steering_angle_to_servo_offset
    v     = speed_sign * (erpm - speed_to_erpm_offset) / speed_to_erpm_gain    (odometry)

``speed_sign`` applies in both directions, so a commanded speed reads back with its own sign;
set it to -1 when the motor is wired so that positive ERPM drives the car backwards.

The VESC's IMU (``COMM_GET_IMU_DATA``, ``shared.vesc.imu``) is polled at ``poll_imu_rate_hz``
(0 = off, the default: a VESC without an IMU chip answers zeros) and published on
``vehicle/imu``. Its mounting is the board's orientation in the car, ``imu_roll_deg``,
``imu_pitch_deg``, ``imu_yaw_deg`` (``R = Rz(yaw) Ry(pitch) Rx(roll)``, ``v_car = R v_board``)
or a full ``imu_rotation`` (3x3, rows of ``R``; then the angles must stay 0). These act on top
of the rotation set in the VESC Tool (the firmware applies that one before it answers).

``port`` defaults to ``/dev/sensors/vesc``, a stable name made by a udev rule (the README's
"The real car" has the rule: the VESC's USB id 0483:5740), distinct from the lidar's
``/dev/sensors/hokuyo``: ``/dev/ttyACM0`` and ``/dev/ttyACM1`` are handed out in the order the
devices enumerate, so the two would swap between boots. ``/dev/serial/by-id/usb-...`` (made
by udev with no rule of ours) works as well. The user needs the ``dialout`` group.
"""

from __future__ import annotations

import math
from typing import Literal

import numpy as np
from pydantic import Field, model_validator

from shared.car import CAR
from shared.config.base import Section

__all__ = ["VescSettings"]


class VescSettings(Section):
    """The VESC driver's settings (units in the names)."""

    port: str = Field(
        "/dev/sensors/vesc",
        min_length=1,
        description=(
            "serial device path: the udev link /dev/sensors/vesc (README, 'The real car'), "
            "or /dev/serial/by-id/usb-...; never a bare /dev/ttyACMn, whose number changes"
        ),
    )
    baudrate: int = Field(115200, gt=0, le=4_000_000, description="serial baud rate [bit/s]")

    speed_to_erpm_gain: float = Field(
        4614.0, gt=0.0, le=1e6, allow_inf_nan=False, description="ERPM per m/s"
    )
    speed_to_erpm_offset: float = Field(
        0.0, ge=-1e5, le=1e5, allow_inf_nan=False, description="ERPM at 0 m/s"
    )
    speed_sign: Literal[1, -1] = Field(1, description="+1 or -1: direction of the wiring")
    max_abs_erpm: float = Field(
        23250.0, gt=0.0, le=1e6, allow_inf_nan=False, description="ERPM clamp (symmetric)"
    )

    steering_angle_to_servo_gain: float = Field(
        -1.2135, ge=-100.0, le=100.0, allow_inf_nan=False, description="servo units per rad"
    )
    steering_angle_to_servo_offset: float = Field(
        0.5304, ge=0.0, le=1.0, allow_inf_nan=False, description="servo position at 0 rad"
    )
    servo_min: float = Field(0.15, ge=0.0, le=1.0, description="lowest servo position [0, 1]")
    servo_max: float = Field(0.85, ge=0.0, le=1.0, description="highest servo position [0, 1]")

    wheelbase_m: float = Field(
        CAR.wheelbase_m,
        gt=0.0,
        le=5.0,
        allow_inf_nan=False,
        description="odometry yaw rate wheelbase [m]",
    )

    command_rate_hz: float = Field(
        50.0, gt=0.0, le=1000.0, allow_inf_nan=False, description="rate of motor frames"
    )
    poll_values_rate_hz: float = Field(
        50.0, ge=0.0, le=1000.0, allow_inf_nan=False, description="GET_VALUES rate (0 = off)"
    )
    command_timeout_s: float = Field(
        0.1, gt=0.0, le=10.0, allow_inf_nan=False, description="no command for this -> brake"
    )
    brake_current_a: float = Field(
        20.0, ge=0.0, le=200.0, allow_inf_nan=False, description="brake current on timeout"
    )
    stale_values_s: float = Field(
        0.5, gt=0.0, le=60.0, allow_inf_nan=False, description="no reply for this -> stale"
    )
    reconnect_backoff_initial_s: float = Field(
        0.05, gt=0.0, le=60.0, allow_inf_nan=False, description="first reopen delay"
    )
    reconnect_backoff_max_s: float = Field(
        2.0, gt=0.0, le=600.0, allow_inf_nan=False, description="longest reopen delay"
    )
    max_payload_bytes: int = Field(
        512, ge=80, le=65535, description="longest reply payload accepted by the decoder"
    )
    write_on_command: bool = Field(
        True,
        description=(
            "the Zenoh shell writes a newly received command to the port at once (at most "
            "one such extra write per 5 ms) instead of waiting for the next fixed-rate tick; "
            "the fixed-rate frames are sent either way"
        ),
    )
    event_interval_s: float = Field(
        2.0,
        gt=0.0,
        le=3600.0,
        allow_inf_nan=False,
        description="shortest interval between two events/log records of one kind [s]",
    )
    poll_imu_rate_hz: float = Field(
        0.0,
        ge=0.0,
        le=1000.0,
        allow_inf_nan=False,
        description=(
            "GET_IMU_DATA rate (0 = off); at most one request per tick, so the rate is "
            "capped by command_rate_hz"
        ),
    )
    imu_roll_deg: float = Field(
        0.0, ge=-180.0, le=180.0, allow_inf_nan=False, description="board roll in the car [deg]"
    )
    imu_pitch_deg: float = Field(
        0.0, ge=-90.0, le=90.0, allow_inf_nan=False, description="board pitch in the car [deg]"
    )
    imu_yaw_deg: float = Field(
        0.0, ge=-180.0, le=180.0, allow_inf_nan=False, description="board yaw in the car [deg]"
    )
    imu_rotation: tuple[
        tuple[float, float, float], tuple[float, float, float], tuple[float, float, float]
    ] | None = Field(
        None,
        description=(
            "board-to-car rotation matrix (3 rows of 3; orthonormal, det +1); overrides the "
            "three angles, which must then be 0"
        ),
    )
    stale_imu_s: float = Field(
        0.5, gt=0.0, le=60.0, allow_inf_nan=False, description="no IMU reply for this -> warn"
    )
    invalid_command: Literal["brake", "clamp"] = Field(
        "clamp",
        description=(
            "an out-of-range command (ERPM beyond max_abs_erpm or servo outside "
            "[servo_min, servo_max]) is clamped, or turned into braking; NaN/inf always brakes"
        ),
    )

    @model_validator(mode="after")
    def _check_ranges(self) -> VescSettings:
        if self.servo_min >= self.servo_max:
            raise ValueError("servo_min must be below servo_max")
        if self.steering_angle_to_servo_gain == 0.0:
            raise ValueError("steering_angle_to_servo_gain must not be zero")
        if self.reconnect_backoff_max_s < self.reconnect_backoff_initial_s:
            raise ValueError("reconnect_backoff_max_s must be >= reconnect_backoff_initial_s")
        if abs(self.speed_to_erpm_offset) >= self.max_abs_erpm:
            raise ValueError("|speed_to_erpm_offset| must be below max_abs_erpm")
        if self.imu_rotation is not None:
            if (self.imu_roll_deg, self.imu_pitch_deg, self.imu_yaw_deg) != (0.0, 0.0, 0.0):
                raise ValueError("give either imu_rotation or the imu_*_deg angles, not both")
            r = np.asarray(self.imu_rotation, dtype=float)
            if not np.all(np.isfinite(r)):
                raise ValueError("imu_rotation must be finite")
            if not np.allclose(r @ r.T, np.eye(3), atol=1e-3) or np.linalg.det(r) < 0.0:
                raise ValueError("imu_rotation must be a rotation (orthonormal rows, det +1)")
        return self

    def imu_mounting(self) -> np.ndarray:
        """(3, 3) board-to-car rotation ``R`` (``v_car = R v_board``) of the VESC's IMU."""
        from shared.vesc.imu import rotation_from_rpy

        if self.imu_rotation is not None:
            return np.asarray(self.imu_rotation, dtype=float)
        return rotation_from_rpy(
            math.radians(self.imu_roll_deg),
            math.radians(self.imu_pitch_deg),
            math.radians(self.imu_yaw_deg),
        )
