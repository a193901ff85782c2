"""Car units (m/s, rad) <-> VESC units (ERPM, servo position [0, 1]): the pure formulas.

The conventions are the F1TENTH VESC driver's (``shared.config.vesc`` has the settings and
their defaults, ``../shared/docs/vehicle-and-vesc.md`` the source)::

    erpm  = gain * (sign * v) + offset            v     = sign * (erpm - offset) / gain
    servo = gain * delta + offset                 delta = (servo - offset) / gain

Nothing here clamps (the driver's ``convert_command`` decides what is safe to send), reads a
clock or does I/O. Used by the vesc_driver (commands out, odometry in) and by the
simulator's fake VESC (frames in, wheel speed out).
"""

from __future__ import annotations

import math


def speed_to_erpm(speed_mps: float, gain: float, offset: float, sign: int = 1) -> float:
    """Motor speed [ERPM] for a car speed [m/s]: ``gain * (sign * v) + offset`` (unclamped).

    ``gain`` [ERPM per m/s], ``offset`` [ERPM], ``sign`` +1 or -1 (direction of the wiring).
    """
    return gain * (sign * speed_mps) + offset


def erpm_to_speed(erpm: float, gain: float, offset: float, sign: int = 1) -> float:
    """Car speed [m/s] from a motor speed [ERPM]: ``sign * (erpm - offset) / gain``."""
    return sign * (erpm - offset) / gain


def steering_to_servo(steering_rad: float, gain: float, offset: float) -> float:
    """Servo position [0, 1] for a steering angle [rad]: ``gain * delta + offset`` (unclamped).

    ``gain`` [servo units per rad], ``offset`` [servo units] (the position at 0 rad).
    """
    return gain * steering_rad + offset


def servo_to_steering(servo_pos: float, gain: float, offset: float) -> float:
    """Steering angle [rad] for a servo position [0, 1] (inverse of ``steering_to_servo``)."""
    return (servo_pos - offset) / gain


def yaw_rate_from(speed_mps: float, steering_rad: float, wheelbase_m: float) -> float:
    """Kinematic yaw rate [rad/s]: ``v * tan(delta) / wheelbase``."""
    return speed_mps * math.tan(steering_rad) / wheelbase_m


def clamp(value: float, lo: float, hi: float) -> float:
    """``value`` limited to [lo, hi]."""
    return lo if value < lo else hi if value > hi else value
