"""Simulator actuation through a fake VESC: the vesc_driver's serial frames drive the car.

With ``[simulator] actuation = "fake_vesc"`` the simulator does not subscribe to
``cmd/drive``. It owns a fake VESC on a pseudo-terminal, reachable at the stable symlink
``[simulator] fake_vesc_link``, and the vesc_driver service's ``[vesc] port`` points at the
same path, so in simulation the whole real chain runs: planner -> ``cmd/drive`` ->
vesc_driver -> SET_RPM / SET_SERVO_POS / SET_CURRENT_BRAKE bytes -> this module -> the
simulated car. GET_VALUES is answered with the simulated wheel speed as ERPM, so the
vesc_driver's ``vehicle/odom`` reflects the simulated car.

Each simulator tick calls ``VescActuation.update(wheel_speed_mps)``; it returns the command
implied by the newest frames (inverse of the ``[vesc]`` conversions), or None when no motor
or servo frame arrived since the previous call (the simulator then keeps the previous command
until its own ``command_timeout_s`` brakes the car, as a VESC's firmware timeout would). A
brake current or the fake firmware's command timeout gives speed 0.
"""

from __future__ import annotations

import contextlib
import os
import time
from collections.abc import Callable
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

from services.vesc_driver.conversions import erpm_to_speed, servo_to_steering, speed_to_erpm
from services.vesc_driver.fake_vesc import DEFAULT_FIRMWARE_TIMEOUT_S, FakeVesc
from services.vesc_driver.protocol import encode_frame
from services.vesc_driver.values import STATUS_TIMEOUT_BIT, encode_values_payload
from shared.config import ConfigError
from shared.config.vesc import VescSettings

#: Largest |ERPM| a GET_VALUES reply can carry (int32).
MAX_REPLY_ERPM = 2**31 - 1
#: The fake's event log is cleared every this many updates (it is not used here).
CLEAR_EVENTS_EVERY = 500


@dataclass(frozen=True, slots=True)
class VescCommand:
    """The car command implied by the fake VESC's newest frames.

    Attributes:
        speed_mps: target speed [m/s] (0 while braking).
        steering_rad: target steering angle [rad] from the newest servo position (0 before
            any).
        braking: True when the speed is 0 because of a brake current, the firmware timeout
            or a released motor.
    """

    speed_mps: float
    steering_rad: float
    braking: bool


@dataclass(frozen=True, slots=True)
class FakeMotorState:
    """A consistent copy of the fake VESC's motor state (times on the fake's clock [s])."""

    mode: str
    last_erpm: float | None
    last_erpm_s: float | None
    last_servo: float | None
    last_servo_s: float | None
    last_brake_s: float | None
    firmware_timed_out: bool
    firmware_timeouts: int


class SimFakeVesc(FakeVesc):
    """A ``FakeVesc`` whose GET_VALUES replies carry the simulated wheel speed [ERPM]."""

    def __init__(self, **kwargs: Any) -> None:
        """Create the fake (see ``FakeVesc``); replies report 0 ERPM until ``set_wheel_erpm``."""
        self.wheel_erpm = 0.0  # before the base class starts its thread
        super().__init__(**kwargs)

    def set_wheel_erpm(self, erpm: float) -> None:
        """The motor speed [ERPM] the next replies report."""
        with self._lock:
            self.wheel_erpm = float(erpm)

    def motor_state(self) -> FakeMotorState:
        """A consistent copy of the motor state."""
        with self._lock:
            return FakeMotorState(
                mode=self.mode,
                last_erpm=self.last_erpm,
                last_erpm_s=self.last_erpm_s,
                last_servo=self.last_servo,
                last_servo_s=self.last_servo_s,
                last_brake_s=self.last_brake_s,
                firmware_timed_out=self.firmware_timed_out,
                firmware_timeouts=self.firmware_timeouts,
            )

    def _reply(self) -> bytes:
        """The GET_VALUES reply: the base reply with ``erpm`` = the simulated wheel speed."""
        with self._lock:
            erpm = self.wheel_erpm
            flags = (self.values.status_flags or 0) & ~STATUS_TIMEOUT_BIT
            if self.firmware_timed_out:
                flags |= STATUS_TIMEOUT_BIT
            brake = self.last_brake_a if self.mode == "brake" else 0.0
        values = replace(
            self.values, erpm=erpm, avg_motor_current_a=-(brake or 0.0), status_flags=flags
        )
        return encode_frame(encode_values_payload(values, self.reply_length))


class VescActuation:
    """Owns the simulator's fake VESC and its symlink; turns its frames into car commands."""

    def __init__(
        self,
        link_path: str | Path,
        vesc: VescSettings,
        *,
        firmware_timeout_s: float = DEFAULT_FIRMWARE_TIMEOUT_S,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        """Start the fake VESC and point ``link_path`` at its pty.

        Args:
            link_path: the stable symlink the vesc_driver opens (``[simulator]
                fake_vesc_link``); an existing symlink there is replaced.
            vesc: the ``[vesc]`` settings (conversion gains, offset, sign).
            firmware_timeout_s: the fake firmware's command timeout [s].
            clock: time source [s] of the fake.

        Raises:
            ConfigError: ``link_path`` is an existing non-symlink, or its folder is missing.
        """
        self.link_path = Path(link_path)
        self.vesc = vesc
        self.fake = SimFakeVesc(timeout_s=firmware_timeout_s, clock=clock)
        try:
            self._point_link()
        except BaseException:
            self.fake.close()
            raise
        self._last_key: tuple[Any, ...] = (None, None, None, 0)  # nothing received yet
        self._steering_rad = 0.0
        self._updates = 0
        self.commands = 0  #: commands returned so far

    def _point_link(self) -> None:
        p = self.link_path
        if p.exists() and not p.is_symlink():
            raise ConfigError(
                f"[simulator] fake_vesc_link: {p} exists and is not a symlink; not replacing it"
            )
        tmp = p.with_name(f".{p.name}.{os.getpid()}.tmp")
        try:
            with contextlib.suppress(FileNotFoundError):
                os.unlink(tmp)
            os.symlink(self.fake.path, tmp)
            os.replace(tmp, p)
        except OSError as exc:
            raise ConfigError(f"[simulator] fake_vesc_link: cannot create {p}: {exc}") from None

    @property
    def path(self) -> str:
        """The symlink path the vesc_driver opens."""
        return str(self.link_path)

    def update(self, wheel_speed_mps: float) -> VescCommand | None:
        """Report ``wheel_speed_mps`` [m/s] in the next replies; the newest command or None.

        Returns None when no SET_RPM, SET_SERVO_POS or brake frame (and no firmware
        timeout) arrived since the previous call.
        """
        s = self.vesc
        erpm = speed_to_erpm(wheel_speed_mps, s.speed_to_erpm_gain, s.speed_to_erpm_offset,
                             s.speed_sign)
        self.fake.set_wheel_erpm(max(-MAX_REPLY_ERPM, min(MAX_REPLY_ERPM, erpm)))
        self._updates += 1
        if self._updates % CLEAR_EVENTS_EVERY == 0:
            self.fake.clear_events()
        st = self.fake.motor_state()
        key = (st.last_erpm_s, st.last_servo_s, st.last_brake_s, st.firmware_timeouts)
        if key == self._last_key:
            return None
        self._last_key = key
        if st.last_servo is not None:
            self._steering_rad = servo_to_steering(
                st.last_servo, s.steering_angle_to_servo_gain, s.steering_angle_to_servo_offset
            )
        braking = st.mode != "rpm" or st.firmware_timed_out or st.last_erpm is None
        speed = 0.0
        if not braking and st.last_erpm is not None:
            speed = erpm_to_speed(st.last_erpm, s.speed_to_erpm_gain, s.speed_to_erpm_offset,
                                  s.speed_sign)
        self.commands += 1
        return VescCommand(speed_mps=speed, steering_rad=self._steering_rad, braking=braking)

    def close(self) -> None:
        """Remove the symlink (if it still points at this fake) and stop the fake."""
        with contextlib.suppress(OSError):
            if os.readlink(self.link_path) == self.fake.path:
                os.unlink(self.link_path)
        self.fake.close()

    def __enter__(self) -> VescActuation:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
