"""Simulator actuation through a fake VESC: the vesc_driver's serial frames drive the car.

With ``[simulator] actuation = "fake_vesc"`` the simulator does not subscribe to
``cmd/drive``. It owns a fake VESC on a pseudo-terminal, reachable at the stable symlink
``[simulator] fake_vesc_link``, and the vesc_driver service's ``[vesc] port`` points at the
same path, so in simulation the whole real chain runs: planner -> ``cmd/drive`` ->
vesc_driver -> SET_RPM / SET_SERVO_POS / SET_CURRENT_BRAKE bytes -> this module -> the
simulated car. GET_VALUES is answered with the simulated wheel speed as ERPM, so the
vesc_driver's ``vehicle/odom`` reflects the simulated car. GET_IMU_DATA is answered with the
simulator's truth: ``set_imu(yaw_rate, ax, ay)`` after each step (car frame) is turned into
the board's reading through the inverse of the ``[vesc]`` mounting rotation, so the
vesc_driver's ``vehicle/imu`` (rotation applied) gives back the simulated values. Until the
simulator calls ``set_imu`` the replies carry the kinematic estimate of the commanded motion
(``yaw rate = v tan(delta) / L``, ``ay = v * yaw rate``, ``ax = dv/dt`` from the wheel speeds
of ``update``), so the chain works with a simulator that does not feed the truth.

Each simulator tick calls ``VescActuation.update(wheel_speed_mps)``; it returns the command
implied by the newest frames (inverse of the ``[vesc]`` conversions), or None when no motor
or servo frame arrived since the previous call (the simulator then keeps the previous command
until its own ``command_timeout_s`` brakes the car, as a VESC's firmware timeout would). A
brake current or the fake firmware's command timeout gives speed 0.

The protocol, the conversions and the fake VESC come from ``shared.vesc`` (the fake's
public ``reply_values`` hook puts the wheel speed into the replies, ``motor_state()`` reads
the applied commands); nothing here imports the vesc_driver service.
"""

from __future__ import annotations

import contextlib
import math
import os
import time
from collections.abc import Callable
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

from shared.config import ConfigError
from shared.config.vesc import VescSettings
from shared.vesc.conversions import erpm_to_speed, servo_to_steering, speed_to_erpm
from shared.vesc.fake import DEFAULT_FIRMWARE_TIMEOUT_S, FakeImu, FakeMotorState
from shared.vesc.fake_pty import FakeVesc
from shared.vesc.imu import CarImu, board_reading
from shared.vesc.values import VescValues

#: Largest |ERPM| a GET_VALUES reply can carry (int32).
MAX_REPLY_ERPM = 2**31 - 1
#: Shortest interval of the kinematic estimate's acceleration [s].
ESTIMATE_AX_WINDOW_S = 0.05
#: Largest |acceleration| [m/s^2] the kinematic estimate reports.
ESTIMATE_MAX_AX_MPS2 = 20.0


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
        #: motor speed [ERPM] the replies report (written here, read on the fake's thread)
        self._wheel_erpm = 0.0
        self._clock = clock
        self._mounting = vesc.imu_mounting()
        #: the IMU board reading the replies report (replaced whole, read on the fake's thread)
        self._imu_board = FakeImu()
        self.imu_from_truth = False  #: True once ``set_imu`` was called
        self._prev_speed: tuple[float, float] | None = None  # (t [s], v [m/s]) of update
        self._ax_estimate = 0.0
        self.fake = FakeVesc(
            timeout_s=firmware_timeout_s,
            reply_values=self._reply_values,
            reply_imu=self._reply_imu,
            max_events=0,  # the event log is not used here
            clock=clock,
        )
        try:
            self._point_link()
        except BaseException:
            self.fake.close()
            raise
        self._last_key: tuple[Any, ...] = (None, None, None, 0)  # nothing received yet
        self._steering_rad = 0.0
        self.commands = 0  #: commands returned so far

    def _reply_values(self, state: FakeMotorState, reply: VescValues) -> VescValues:
        """The fake's ``reply_values`` hook: its GET_VALUES reply with ``erpm`` = the simulated
        wheel speed [ERPM] instead of the commanded one."""
        return replace(reply, erpm=self._wheel_erpm)

    def _reply_imu(self, state: FakeMotorState, imu: FakeImu) -> FakeImu:
        """The fake's ``reply_imu`` hook: the newest board reading (truth or estimate)."""
        return self._imu_board

    def set_imu(self, yaw_rate_radps: float, ax_mps2: float, ay_mps2: float) -> None:
        """Report this car-frame reading (the simulator's step truth: yaw rate [rad/s],
        specific force forward / left [m/s^2]) in the next IMU replies, as the VESC board
        mounted per ``[vesc]`` would measure it. Non-finite values are ignored."""
        values = (yaw_rate_radps, ax_mps2, ay_mps2)
        if not all(math.isfinite(v) for v in values):
            return
        self.imu_from_truth = True
        self._set_board(CarImu(*values))

    def _set_board(self, car: CarImu) -> None:
        accel_g, gyro_dps = board_reading(car, self._mounting)
        self._imu_board = FakeImu(accel_g=accel_g, gyro_dps=gyro_dps)

    def _estimate_imu(self, wheel_speed_mps: float) -> None:
        """The kinematic IMU estimate while the simulator feeds no truth: ``ax`` is the
        change of the wheel speed over at least ``ESTIMATE_AX_WINDOW_S`` (a reset's jump
        would otherwise read as a crash), clipped to +-``ESTIMATE_MAX_AX_MPS2``."""
        now = self._clock()
        if self._prev_speed is None:
            self._prev_speed = (now, wheel_speed_mps)
        elif now - self._prev_speed[0] >= ESTIMATE_AX_WINDOW_S:
            ax = (wheel_speed_mps - self._prev_speed[1]) / (now - self._prev_speed[0])
            self._ax_estimate = max(-ESTIMATE_MAX_AX_MPS2, min(ESTIMATE_MAX_AX_MPS2, ax))
            self._prev_speed = (now, wheel_speed_mps)
        r = wheel_speed_mps * math.tan(self._steering_rad) / self.vesc.wheelbase_m
        if all(math.isfinite(v) for v in (r, self._ax_estimate)):
            self._set_board(CarImu(r, self._ax_estimate, wheel_speed_mps * r))

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
        erpm = speed_to_erpm(
            wheel_speed_mps, s.speed_to_erpm_gain, s.speed_to_erpm_offset, s.speed_sign
        )
        self._wheel_erpm = float(max(-MAX_REPLY_ERPM, min(MAX_REPLY_ERPM, erpm)))
        if not self.imu_from_truth:
            self._estimate_imu(wheel_speed_mps)
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
            speed = erpm_to_speed(
                st.last_erpm, s.speed_to_erpm_gain, s.speed_to_erpm_offset, s.speed_sign
            )
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
