"""The VESC driver core: commands in, frames out, GET_VALUES replies -> state and odometry.

``VescDriver`` owns a ``SerialLink``, a ``FrameDecoder`` (``shared.vesc``) and a
``CommandWatchdog``. It has no bus code: the Zenoh shell calls ``on_command`` for each drive
command and either calls ``tick`` itself or runs the serial loop ``loop(stop_event, on_tick)``
(``run`` = ``loop`` then close the link) in a thread and publishes what ``on_tick`` receives.
``on_command`` may be called from another thread than ``tick``/``loop``; ``wake()`` makes a
sleeping loop look again at once (e.g. after setting its stop event).

The loop is the only scheduling loop of the VESC driver (the service runs it too): it ticks
when ``services.vesc_driver.schedule.TickScheduler`` says so (fixed rate, watchdog expiry,
and with ``[vesc] write_on_command`` right after a new command) and between ticks sleeps in
``select`` on the serial port and a wake pipe, decoding GET_VALUES replies as they arrive
(their stamps are the decode time).

Per tick, frames are written in this order:

* commands fresh (younger than ``command_timeout_s``): SET_RPM (or SET_CURRENT_BRAKE when the
  command was NaN/inf, or out of range with ``invalid_command = "brake"``), SET_SERVO_POS,
  ALIVE;
* no fresh command: SET_CURRENT_BRAKE ``brake_current_a`` on every tick (the brake is held
  until a command arrives); the servo is left where it was and no ALIVE is sent;
* GET_VALUES when due (``poll_values_rate_hz``);
* GET_IMU_DATA when due (``poll_imu_rate_hz``; mask ``shared.vesc.imu.DRIVER_MASK``:
  accelerations and rates). A reply becomes an ``ImuRecord`` in the car frame (the
  ``[vesc]`` mounting rotation applied, ``shared.vesc.imu.imu_in_car``).

If the driver's process hangs nothing is sent at all, and the VESC's firmware timeout
releases the motor.
"""

from __future__ import annotations

import contextlib
import os
import select
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, fields

from services.vesc_driver.conversions import ActuatorCommand, convert_command
from services.vesc_driver.schedule import WAKE_SLACK_S, TickScheduler
from services.vesc_driver.serial_link import LinkState, SerialLink
from services.vesc_driver.watchdog import CommandWatchdog, WatchdogState
from shared.config.vesc import VescSettings
from shared.messages import VescStatusName
from shared.vesc.conversions import erpm_to_speed, servo_to_steering, yaw_rate_from
from shared.vesc.decoder import FrameDecoder
from shared.vesc.imu import DRIVER_MASK, encode_get_imu_data, imu_in_car, is_imu_reply, parse_imu
from shared.vesc.protocol import (
    encode_alive,
    encode_get_values,
    encode_set_current_brake,
    encode_set_rpm,
    encode_set_servo_pos,
)
from shared.vesc.values import VescValues, is_values_reply, parse_values


@dataclass(frozen=True, slots=True)
class VescStateRecord:
    """Controller values from one GET_VALUES reply.

    Attributes:
        stamp_s: driver clock [s] when the reply was decoded.
        status: "ok" | "fault" (fault_code != 0) | "stale" | "disconnected".
        values: every GET_VALUES field with its unit in the name (None where not sent).
    """

    stamp_s: float
    status: str
    values: VescValues


@dataclass(frozen=True, slots=True)
class OdometryRecord:
    """Wheel odometry from the reported ERPM and the last servo command.

    Attributes:
        stamp_s: driver clock [s] when the reply was decoded.
        speed_mps: car speed [m/s] from the motor ERPM.
        steering_rad: steering angle [rad] of the last servo position sent (0 before any).
        yaw_rate_radps: ``v tan(delta) / wheelbase`` [rad/s].
    """

    stamp_s: float
    speed_mps: float
    steering_rad: float
    yaw_rate_radps: float


@dataclass(frozen=True, slots=True)
class ImuRecord:
    """The VESC's IMU in the car frame, from one GET_IMU_DATA reply.

    Attributes:
        stamp_s: driver clock [s] when the reply was decoded.
        yaw_rate_radps: yaw rate [rad/s], counter-clockwise positive.
        ax_mps2, ay_mps2: specific force forward / left [m/s^2].
    """

    stamp_s: float
    yaw_rate_radps: float
    ax_mps2: float
    ay_mps2: float


@dataclass(frozen=True, slots=True)
class TickResult:
    """What one tick did and learned.

    Attributes:
        stamp_s: the ``now`` [s] the tick ran at.
        frames_written: the frames handed to the port (empty while disconnected).
        braking: True if this tick commanded the brake current.
        watchdog: the command watchdog's state.
        link: the serial link's state.
        status: "ok" | "fault" | "stale" | "disconnected" (see ``VescStateRecord``).
        state: the newest GET_VALUES reply decoded since the previous tick, or None.
        odometry: odometry from that reply, or None.
        imu: the newest GET_IMU_DATA reply since the previous tick (car frame), or None.
    """

    stamp_s: float
    frames_written: tuple[bytes, ...]
    braking: bool
    watchdog: WatchdogState
    link: LinkState
    status: str
    state: VescStateRecord | None = None
    odometry: OdometryRecord | None = None
    imu: ImuRecord | None = None


@dataclass(slots=True)
class DriverCounters:
    """Driver-level events (decoder, link and watchdog keep their own counters).

    Attributes:
        commands: ``on_command`` calls.
        nonfinite_commands: commands with NaN/inf (braked).
        out_of_range_commands: finite commands beyond the ERPM or servo range (clamped or
            braked per ``invalid_command``).
        ticks: ``tick`` calls; brake_ticks: ticks that sent the brake current.
        frames_written: frames handed to the port; write_failures: ticks whose write failed.
        values_replies: GET_VALUES replies parsed.
        malformed_values: GET_VALUES replies too short for even the first field.
        imu_replies: GET_IMU_DATA replies parsed.
        malformed_imu: GET_IMU_DATA replies whose length does not match their mask, with a
            non-finite value, or without the acceleration and rate vectors (dropped).
        other_frames: decoded frames that are neither reply (ignored).
    """

    commands: int = 0
    nonfinite_commands: int = 0
    out_of_range_commands: int = 0
    ticks: int = 0
    brake_ticks: int = 0
    frames_written: int = 0
    write_failures: int = 0
    values_replies: int = 0
    malformed_values: int = 0
    imu_replies: int = 0
    malformed_imu: int = 0
    other_frames: int = 0

    def as_dict(self) -> dict[str, int]:
        """The counters as a plain dict."""
        return {f.name: getattr(self, f.name) for f in fields(self)}


@dataclass(slots=True)
class _Pending:
    state: VescStateRecord | None = None
    odometry: OdometryRecord | None = None
    imu: ImuRecord | None = None


class VescDriver:
    """Drive commands -> VESC frames, GET_VALUES replies -> state and odometry."""

    def __init__(
        self,
        settings: VescSettings,
        link: SerialLink | None = None,
        *,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        """Create the driver.

        Args:
            settings: the ``[vesc]`` configuration section.
            link: the serial link (default: a ``SerialLink`` on ``settings.port``).
            clock: monotonic time source [s], read only by ``run`` and ``now``.
        """
        self.settings = settings
        self._clock = clock
        self.link = link or SerialLink(
            settings.port,
            settings.baudrate,
            backoff_initial_s=settings.reconnect_backoff_initial_s,
            backoff_max_s=settings.reconnect_backoff_max_s,
            clock=clock,
        )
        self.decoder = FrameDecoder(max_payload=settings.max_payload_bytes)
        self.watchdog = CommandWatchdog(settings.command_timeout_s)
        self.counters = DriverCounters()
        self._lock = threading.Lock()
        self._command: ActuatorCommand | None = None
        #: a command arrived that no tick has written yet (guarded by _lock)
        self._command_pending = False
        # the loop's wake pipe (read end, write end) while ``loop`` runs, guarded by _wake_lock
        self._wake_lock = threading.Lock()
        self._wake_fds: tuple[int, int] | None = None
        self._last_servo_sent: float | None = None
        self._last_values_s: float | None = None
        self._last_values: VescValues | None = None
        self._next_poll_s = float("-inf")
        self._next_imu_poll_s = float("-inf")
        self._imu_rotation = settings.imu_mounting()
        self._last_imu_s: float | None = None
        self._link_epoch = self.link.counters.connects
        self._pending = _Pending()
        self._brake_frame = encode_set_current_brake(settings.brake_current_a)
        self._alive_frame = encode_alive()
        self._poll_frame = encode_get_values()
        self._imu_poll_frame = encode_get_imu_data(DRIVER_MASK)

    def now(self) -> float:
        """The driver's clock [s]."""
        return self._clock()

    # -- commands ----------------------------------------------------------------------------
    def on_command(self, speed_mps: float, steering_rad: float, now: float) -> ActuatorCommand:
        """Accept a drive command (speed [m/s], steering [rad]) received at ``now`` [s].

        The command is converted at once (NaN/inf -> brake; out of range -> clamp or brake)
        and sent on the next ticks while it is fresh; with ``write_on_command`` a running
        ``loop`` is woken to write it at once. Thread-safe; never blocks, never raises.
        """
        cmd = convert_command(speed_mps, steering_rad, self.settings)
        with self._lock:
            self.counters.commands += 1
            if cmd.nonfinite:
                self.counters.nonfinite_commands += 1
            if cmd.out_of_range:
                self.counters.out_of_range_commands += 1
            self._command = cmd
            self._command_pending = True
            self.watchdog.feed(now)
        if self.settings.write_on_command:
            self.wake()
        return cmd

    # -- input -------------------------------------------------------------------------------
    def poll_input(self, now: float) -> int:
        """Read and decode whatever the VESC sent; keep the newest reply for the next tick.

        Returns the number of frames decoded.
        """
        data = self.link.read()
        self._check_reconnect()
        if not data:
            return 0
        frames = self.decoder.feed(data)
        for frame in frames:
            if is_imu_reply(frame.payload):
                self._on_imu_payload(frame.payload, now)
                continue
            if not is_values_reply(frame.payload):
                self.counters.other_frames += 1
                continue
            values = parse_values(frame.payload)
            if values is None:
                self.counters.malformed_values += 1
                continue
            self.counters.values_replies += 1
            self._on_values(values, now)
        return len(frames)

    def _check_reconnect(self) -> None:
        epoch = self.link.counters.connects
        if epoch != self._link_epoch:
            self._link_epoch = epoch
            self.decoder.reset()  # drop a half frame from before the port was lost

    def _on_imu_payload(self, payload: bytes, now: float) -> None:
        imu = parse_imu(payload)
        car = imu_in_car(imu, self._imu_rotation) if imu is not None else None
        if car is None:
            self.counters.malformed_imu += 1
            return
        self.counters.imu_replies += 1
        self._last_imu_s = now
        self._pending.imu = ImuRecord(
            stamp_s=now,
            yaw_rate_radps=car.yaw_rate_radps,
            ax_mps2=car.ax_mps2,
            ay_mps2=car.ay_mps2,
        )

    def imu_age_s(self, now: float) -> float | None:
        """Time [s] since the newest valid IMU reply (None before any)."""
        return None if self._last_imu_s is None else now - self._last_imu_s

    def _on_values(self, values: VescValues, now: float) -> None:
        self._last_values = values
        self._last_values_s = now
        status = VescStatusName.FAULT if values.fault_code else VescStatusName.OK
        self._pending.state = VescStateRecord(stamp_s=now, status=status, values=values)
        if values.erpm is not None:
            s = self.settings
            speed = erpm_to_speed(
                values.erpm, s.speed_to_erpm_gain, s.speed_to_erpm_offset, s.speed_sign
            )
            steer = self.steering_rad()
            self._pending.odometry = OdometryRecord(
                stamp_s=now,
                speed_mps=speed,
                steering_rad=steer,
                yaw_rate_radps=yaw_rate_from(speed, steer, s.wheelbase_m),
            )

    def steering_rad(self) -> float:
        """Steering angle [rad] of the last servo position sent (0.0 before any)."""
        if self._last_servo_sent is None:
            return 0.0
        s = self.settings
        return servo_to_steering(
            self._last_servo_sent,
            s.steering_angle_to_servo_gain,
            s.steering_angle_to_servo_offset,
        )

    def status(self, now: float) -> str:
        """ "disconnected" | "stale" (no reply for ``stale_values_s``) | "fault" | "ok"."""
        if not self.link.connected:
            return VescStatusName.DISCONNECTED
        if self._last_values_s is None or now - self._last_values_s > self.settings.stale_values_s:
            return VescStatusName.STALE
        if self._last_values is not None and self._last_values.fault_code:
            return VescStatusName.FAULT
        return VescStatusName.OK

    # -- output ------------------------------------------------------------------------------
    def _frames_for(self, now: float) -> tuple[list[bytes], bool, WatchdogState]:
        with self._lock:
            wd = self.watchdog.state(now)
            cmd = self._command
            self._command_pending = False  # this tick writes the newest command
        frames: list[bytes] = []
        braking = True
        if wd is WatchdogState.FRESH and cmd is not None:
            if cmd.brake or cmd.erpm is None:
                frames.append(self._brake_frame)
            else:
                frames.append(encode_set_rpm(cmd.erpm))
                braking = False
            if cmd.servo_pos is not None:
                frames.append(encode_set_servo_pos(cmd.servo_pos))
            frames.append(self._alive_frame)
        else:
            frames.append(self._brake_frame)
        if self.settings.poll_values_rate_hz > 0.0 and now >= self._next_poll_s:
            frames.append(self._poll_frame)
            period = 1.0 / self.settings.poll_values_rate_hz
            # keep the phase; after a stall do not send a burst of requests
            self._next_poll_s = max(self._next_poll_s + period, now + 0.5 * period)
        if self.settings.poll_imu_rate_hz > 0.0 and now >= self._next_imu_poll_s:
            frames.append(self._imu_poll_frame)
            period = 1.0 / self.settings.poll_imu_rate_hz
            self._next_imu_poll_s = max(self._next_imu_poll_s + period, now + 0.5 * period)
        return frames, braking, wd

    def tick(self, now: float) -> TickResult:
        """Read replies, then write this period's frames (see the module docstring)."""
        self.poll_input(now)
        frames, braking, wd = self._frames_for(now)
        ok = self.link.write(b"".join(frames))
        self._check_reconnect()
        self.counters.ticks += 1
        if braking:
            self.counters.brake_ticks += 1
        if ok:
            self.counters.frames_written += len(frames)
            with self._lock:
                cmd = self._command
            if wd is WatchdogState.FRESH and cmd is not None and cmd.servo_pos is not None:
                self._last_servo_sent = cmd.servo_pos
        else:
            self.counters.write_failures += 1
        pending, self._pending = self._pending, _Pending()
        return TickResult(
            stamp_s=now,
            frames_written=tuple(frames) if ok else (),
            braking=braking,
            watchdog=wd,
            link=self.link.state,
            status=self.status(now),
            state=pending.state,
            odometry=pending.odometry,
            imu=pending.imu,
        )

    # -- loop --------------------------------------------------------------------------------
    def loop(
        self,
        stop_event: threading.Event,
        on_tick: Callable[[TickResult], None] | None = None,
    ) -> None:
        """The serial loop: tick as ``TickScheduler`` says until ``stop_event`` is set.

        Ticks at ``command_rate_hz``, right when the watchdog expires, and - with
        ``write_on_command`` - right after a new command (at most one such extra tick per
        ``MIN_COMMAND_WRITE_GAP_S``). Between ticks it sleeps in ``select`` on the port and
        a wake pipe (``on_command``, ``wake``), decoding replies as they arrive.
        ``on_tick`` receives every ``TickResult`` (from this thread; keep it short). An
        exception from ``on_tick`` ends the loop and propagates. The link stays open (see
        ``run``); call ``wake()`` after setting ``stop_event`` for a prompt return.
        """
        s = self.settings
        sched = TickScheduler(
            1.0 / s.command_rate_hz, self._clock(), write_on_command=s.write_on_command
        )
        wake_r, wake_w = os.pipe()
        os.set_blocking(wake_r, False)
        os.set_blocking(wake_w, False)
        with self._wake_lock:
            self._wake_fds = (wake_r, wake_w)
        try:
            while not stop_event.is_set():
                now = self._clock()
                deadline = self.watchdog.deadline()
                pending = self._command_pending
                reason = sched.due(now, deadline, pending)
                if reason:
                    result = self.tick(now)
                    sched.ticked(now, reason)
                    if on_tick is not None:
                        on_tick(result)
                    continue
                wake = sched.wake_at(deadline, pending)
                self._wait(wake_r, max(0.0, wake - now) + WAKE_SLACK_S)
        finally:
            with self._wake_lock:
                self._wake_fds = None
            for fd in (wake_r, wake_w):
                with contextlib.suppress(OSError):
                    os.close(fd)

    def run(
        self,
        stop_event: threading.Event,
        on_tick: Callable[[TickResult], None] | None = None,
    ) -> None:
        """``loop`` until ``stop_event`` is set, then close the link (also on an exception:
        with no more frames the VESC's firmware timeout then releases the motor)."""
        try:
            self.loop(stop_event, on_tick)
        finally:
            self.link.close()

    def wake(self) -> None:
        """Make a sleeping ``loop`` look again now (no-op when no loop runs). Never blocks."""
        with self._wake_lock:
            if self._wake_fds is not None:
                with contextlib.suppress(OSError):  # a full pipe already wakes the loop
                    os.write(self._wake_fds[1], b"\x00")

    def _wait(self, wake_r: int, timeout_s: float) -> None:
        """Sleep up to ``timeout_s`` [s] on the port and the wake pipe; decode what arrived."""
        fds = [wake_r]
        port_fd = self.link.fileno()
        if port_fd is not None:
            fds.append(port_fd)
        try:
            ready, _, _ = select.select(fds, [], [], timeout_s)
        except (OSError, ValueError):  # the port vanished under us: let the read report it
            ready = [port_fd] if port_fd is not None else []
            if port_fd is None:
                time.sleep(min(timeout_s, 0.01))
        if wake_r in ready:
            with contextlib.suppress(OSError):
                while os.read(wake_r, 4096):
                    pass
        if port_fd is not None and port_fd in ready:
            self.poll_input(self._clock())

    def diagnostics(self) -> dict[str, int]:
        """All counters in one flat dict: ``driver.*``, ``decoder.*``, ``link.*``, watchdog."""
        out = {f"driver.{k}": v for k, v in self.counters.as_dict().items()}
        out |= {f"decoder.{k}": v for k, v in self.decoder.counters.as_dict().items()}
        out |= {f"link.{k}": v for k, v in self.link.counters.as_dict().items()}
        out["watchdog.expiries"] = self.watchdog.expiries
        return out

    def close(self) -> None:
        """Close the serial link."""
        self.link.close()

    def __enter__(self) -> VescDriver:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
