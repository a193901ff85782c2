"""What the driver sends for a car command: the formulas of ``shared.vesc.conversions`` plus
the driver's safety policy (NaN/inf -> brake, out of range -> clamp or brake).

See ``shared.config.vesc`` for the formulas and the meaning of ``speed_sign``. Nothing here
reads a clock or does I/O.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from shared.config.vesc import VescSettings
from shared.vesc.conversions import clamp, speed_to_erpm, steering_to_servo


@dataclass(frozen=True, slots=True)
class ActuatorCommand:
    """A car command turned into what is safe to send.

    Attributes:
        brake: True -> send the brake current instead of an ERPM (``erpm`` is None then).
        erpm: motor speed [ERPM] within +-max_abs_erpm, or None when braking.
        servo_pos: servo position within [servo_min, servo_max], or None when the steering
            was NaN/inf (the previous servo position is held).
        nonfinite: the speed or the steering was NaN or infinite (always brakes).
        out_of_range: a finite value was beyond the ERPM clamp or the servo range.
    """

    brake: bool
    erpm: float | None
    servo_pos: float | None
    nonfinite: bool = False
    out_of_range: bool = False


def convert_command(speed_mps: float, steering_rad: float, s: VescSettings) -> ActuatorCommand:
    """Convert a (speed [m/s], steering [rad]) command per the settings; never raises.

    NaN/inf in either input -> brake. A finite value out of range (ERPM beyond
    ``max_abs_erpm``, servo outside ``[servo_min, servo_max]``) is clamped when
    ``invalid_command == "clamp"`` and turns into braking (servo still clamped) when
    ``"brake"``. With the defaults, 2.0 m/s and 0.1 rad give 9228 ERPM and servo 0.40905.
    """
    speed_ok = math.isfinite(speed_mps)
    steer_ok = math.isfinite(steering_rad)
    erpm = math.nan
    if speed_ok:
        erpm = speed_to_erpm(speed_mps, s.speed_to_erpm_gain, s.speed_to_erpm_offset, s.speed_sign)
    servo = math.nan
    if steer_ok:
        gain, offset = s.steering_angle_to_servo_gain, s.steering_angle_to_servo_offset
        servo = steering_to_servo(steering_rad, gain, offset)
    # a finite but huge input can overflow to inf
    nonfinite = not (math.isfinite(erpm) and math.isfinite(servo))
    servo_c = clamp(servo, s.servo_min, s.servo_max) if math.isfinite(servo) else None
    if nonfinite:
        return ActuatorCommand(brake=True, erpm=None, servo_pos=servo_c, nonfinite=True)
    out_of_range = abs(erpm) > s.max_abs_erpm or not s.servo_min <= servo <= s.servo_max
    if out_of_range and s.invalid_command == "brake":
        return ActuatorCommand(brake=True, erpm=None, servo_pos=servo_c, out_of_range=True)
    erpm_c = clamp(erpm, -s.max_abs_erpm, s.max_abs_erpm)
    return ActuatorCommand(brake=False, erpm=erpm_c, servo_pos=servo_c, out_of_range=out_of_range)
