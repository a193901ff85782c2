"""The firmware side of a fake VESC, without I/O: bytes in -> motor state, events, replies out.

``FakeVescModel`` is the device model that ``shared.vesc.fake_pty.FakeVesc`` puts on a
pseudo-terminal (for the driver's tests, the latency benchmark and the simulator's
``actuation = "fake_vesc"``). It is pure: the caller passes the time ``now`` [s] and writes
the returned reply bytes itself; it is not thread-safe (the pty shell holds its own lock).

What it models:

* every decoded command is recorded as a ``FakeEvent`` (time, command id, value);
* SET_RPM / SET_CURRENT_BRAKE / SET_CURRENT / SET_DUTY set the motor mode, SET_SERVO_POS the
  servo position;
* the firmware command timeout: without a SET_* or ALIVE frame (SET_SERVO_POS does not
  count) for ``timeout_s`` the motor is released (mode "released") and status bit 0 is set
  in the replies;
* GET_VALUES is answered with the template ``values`` with the live fields set from the
  motor state (``default_reply_values``: ``erpm`` = the commanded ERPM in RPM mode,
  ``avg_motor_current_a`` = minus the brake current while braking, the timeout status bit).
  The public hook ``reply_values(state, reply) -> VescValues`` replaces that reply, e.g. the
  simulator reports its simulated wheel speed as ``erpm``;
* COMM_GET_IMU_DATA is answered (``shared.vesc.imu`` layout, the request's mask) with the
  board reading ``imu`` (a ``FakeImu``: level and at rest by default), or what the hook
  ``reply_imu(state, imu) -> FakeImu`` returns (the simulator: its yaw rate and
  accelerations); ``imu_replies_enabled = False`` leaves the requests unanswered.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, replace

from shared.vesc.decoder import FrameDecoder
from shared.vesc.imu import encode_imu_payload, imu_request_mask
from shared.vesc.protocol import (
    TIMEOUT_RESETTING_COMMANDS,
    CommandId,
    decode_command_value,
    encode_frame,
)
from shared.vesc.values import STATUS_TIMEOUT_BIT, VescValues, encode_values_payload

#: Default firmware command timeout [s] of the fake (the VESC tool's default is 1 s).
DEFAULT_FIRMWARE_TIMEOUT_S = 1.0
#: Default number of events kept in memory (the oldest are dropped).
MAX_EVENTS = 100_000

#: Motor modes of the model.
MODE_RELEASED = "released"
MODE_RPM = "rpm"
MODE_BRAKE = "brake"
MODE_CURRENT = "current"
MODE_DUTY = "duty"


@dataclass(frozen=True, slots=True)
class FakeEvent:
    """One command seen by the fake.

    Attributes:
        t_s: the fake's clock [s] when the frame was decoded.
        command: the command id (int; compare with ``CommandId``).
        value: the decoded value in encoder units (ERPM, servo [0, 1], current [A], duty), or
            None for commands without one.
    """

    t_s: float
    command: int
    value: float | None


@dataclass(frozen=True, slots=True)
class FakeMotorState:
    """A consistent copy of what the fake's commands applied (times on the fake's clock [s]).

    Attributes:
        mode: "released" | "rpm" | "brake" | "current" | "duty".
        last_erpm, last_erpm_s: newest SET_RPM value [ERPM] and when it arrived.
        last_servo, last_servo_s: newest SET_SERVO_POS value [0, 1] and when it arrived.
        last_brake_a, last_brake_s: newest SET_CURRENT_BRAKE value [A] and when it arrived.
        last_alive_s: newest frame that resets the firmware timeout (SET_* or ALIVE).
        firmware_timed_out: the firmware timeout has released the motor (until the next
            SET_* or ALIVE).
        firmware_timeouts: how many times it did so.
    """

    mode: str = MODE_RELEASED
    last_erpm: float | None = None
    last_erpm_s: float | None = None
    last_servo: float | None = None
    last_servo_s: float | None = None
    last_brake_a: float | None = None
    last_brake_s: float | None = None
    last_alive_s: float | None = None
    firmware_timed_out: bool = False
    firmware_timeouts: int = 0


#: Replaces the GET_VALUES reply: ``(motor state, the reply the fake would send) -> values``.
ReplyValuesHook = Callable[[FakeMotorState, VescValues], VescValues]


@dataclass(frozen=True, slots=True)
class FakeImu:
    """The fake's IMU board reading (board frame, the firmware's units).

    Attributes:
        rpy_rad: roll, pitch, yaw [rad]; accel_g: specific force [g] (+1 on z at rest);
        gyro_dps: rates [deg/s]; mag: field [uT]; quat: q0 (w), q1, q2, q3.
    """

    rpy_rad: tuple[float, float, float] = (0.0, 0.0, 0.0)
    accel_g: tuple[float, float, float] = (0.0, 0.0, 1.0)
    gyro_dps: tuple[float, float, float] = (0.0, 0.0, 0.0)
    mag: tuple[float, float, float] = (0.0, 0.0, 0.0)
    quat: tuple[float, float, float, float] = (1.0, 0.0, 0.0, 0.0)


#: Replaces the IMU reply: ``(motor state, the reading the fake would send) -> reading``.
ReplyImuHook = Callable[[FakeMotorState, FakeImu], FakeImu]

#: The reply template (a sitting car on a 4S battery); the fake overwrites the live fields.
DEFAULT_VALUES = VescValues(
    temp_fet_c=31.5,
    temp_motor_c=28.0,
    avg_motor_current_a=0.0,
    avg_input_current_a=0.0,
    avg_id_a=0.0,
    avg_iq_a=0.0,
    duty=0.0,
    erpm=0.0,
    v_in_v=16.8,
    amp_hours=0.0,
    amp_hours_charged=0.0,
    watt_hours=0.0,
    watt_hours_charged=0.0,
    tachometer=0,
    tachometer_abs=0,
    fault_code=0,
    pid_pos_deg=0.0,
    controller_id=0,
    temp_mos1_c=31.0,
    temp_mos2_c=31.5,
    temp_mos3_c=32.0,
    avg_vd_v=0.0,
    avg_vq_v=0.0,
    status_flags=0,
)


def default_reply_values(template: VescValues, state: FakeMotorState) -> VescValues:
    """The GET_VALUES reply of a fake in ``state``: ``template`` with the live fields set.

    ``erpm`` = the commanded ERPM in RPM mode (else 0), ``avg_motor_current_a`` = minus the
    brake current [A] while braking (else 0), status bit 0 = the firmware timeout.
    """
    rpm = state.mode == MODE_RPM and state.last_erpm is not None
    brake = state.last_brake_a if state.mode == MODE_BRAKE else None
    flags = (template.status_flags or 0) & ~STATUS_TIMEOUT_BIT
    if state.firmware_timed_out:
        flags |= STATUS_TIMEOUT_BIT
    return replace(
        template,
        erpm=state.last_erpm if rpm else 0.0,
        avg_motor_current_a=-(brake or 0.0),
        status_flags=flags,
    )


class FakeVescModel:
    """The fake VESC's firmware: feed it the bytes the driver wrote, write back what it returns.

    Attributes (settable between calls):
        timeout_s: firmware command timeout [s].
        values: template of GET_VALUES replies (see ``default_reply_values``).
        reply_length: truncate replies to this many payload bytes (older firmware), or None.
        replies_enabled: False -> GET_VALUES requests are counted but not answered.
        reply_values: the ``ReplyValuesHook``, or None for ``default_reply_values``.
        imu: the board reading the IMU replies carry (``FakeImu``).
        imu_replies_enabled: False -> GET_IMU_DATA requests are counted but not answered.
        reply_imu: the ``ReplyImuHook``, or None for ``imu`` as is.
    """

    def __init__(
        self,
        *,
        timeout_s: float = DEFAULT_FIRMWARE_TIMEOUT_S,
        values: VescValues = DEFAULT_VALUES,
        reply_length: int | None = None,
        reply_values: ReplyValuesHook | None = None,
        max_events: int = MAX_EVENTS,
        imu: FakeImu | None = None,
        reply_imu: ReplyImuHook | None = None,
    ) -> None:
        """Create the model in the released state (arguments: see the class attributes;
        ``max_events``: events kept, the oldest dropped; 0 keeps none)."""
        self.imu = imu or FakeImu()
        self.imu_replies_enabled = True
        self.reply_imu = reply_imu
        #: GET_IMU_DATA requests seen, and replies returned for them.
        self.imu_requests = 0
        self.imu_replies_sent = 0
        self.timeout_s = timeout_s
        self.values = values
        self.reply_length = reply_length
        self.replies_enabled = True
        self.reply_values = reply_values
        self.decoder = FrameDecoder()
        self.state = FakeMotorState()
        #: GET_VALUES requests seen, and replies returned for them.
        self.values_requests = 0
        self.replies_sent = 0
        self._events: deque[FakeEvent] = deque(maxlen=max_events)

    # -- input ---------------------------------------------------------------------------
    def feed(self, data: bytes | bytearray | memoryview, now: float) -> bytes:
        """Decode ``data`` (any chunking) received at ``now`` [s]; apply every whole frame.

        Returns the bytes to send back (the GET_VALUES replies, in order; b"" for none).
        Each reply reflects the state after the frames before its request.
        """
        out = bytearray()
        for frame in self.decoder.feed(data):
            out += self.apply(frame.payload, now)
        return bytes(out)

    def apply(self, payload: bytes, now: float) -> bytes:
        """Apply one decoded command payload (id first) at ``now`` [s]; its reply or b""."""
        cid = payload[0]
        value = decode_command_value(payload)
        self._events.append(FakeEvent(t_s=now, command=cid, value=value))
        st = self.state
        if cid in TIMEOUT_RESETTING_COMMANDS:
            st = replace(st, last_alive_s=now, firmware_timed_out=False)
        if cid == CommandId.SET_RPM and value is not None:
            st = replace(st, mode=MODE_RPM, last_erpm=value, last_erpm_s=now)
        elif cid == CommandId.SET_CURRENT_BRAKE and value is not None:
            st = replace(st, mode=MODE_BRAKE, last_brake_a=value, last_brake_s=now)
        elif cid == CommandId.SET_SERVO_POS and value is not None:
            st = replace(st, last_servo=value, last_servo_s=now)
        elif cid == CommandId.SET_CURRENT:
            st = replace(st, mode=MODE_CURRENT)
        elif cid == CommandId.SET_DUTY:
            st = replace(st, mode=MODE_DUTY)
        self.state = st
        if cid == CommandId.GET_IMU_DATA:
            return self._imu_reply(payload)
        if cid != CommandId.GET_VALUES:
            return b""
        self.values_requests += 1
        if not self.replies_enabled:
            return b""
        self.replies_sent += 1
        return self.reply_frame()

    def check_timeout(self, now: float) -> bool:
        """Apply the firmware timeout at ``now`` [s]; True when it released the motor now."""
        st = self.state
        if (
            st.mode != MODE_RELEASED
            and st.last_alive_s is not None
            and now - st.last_alive_s > self.timeout_s
        ):
            self.state = replace(
                st,
                mode=MODE_RELEASED,
                firmware_timed_out=True,
                firmware_timeouts=st.firmware_timeouts + 1,
            )
            return True
        return False

    def reset_link(self) -> None:
        """Forget a half-received frame (the cable was re-plugged); the motor state stays."""
        self.decoder.reset()

    # -- output --------------------------------------------------------------------------
    def imu_reading(self) -> FakeImu:
        """The IMU board reading now (the hook's, if one is set)."""
        return self.imu if self.reply_imu is None else self.reply_imu(self.state, self.imu)

    def _imu_reply(self, payload: bytes) -> bytes:
        mask = imu_request_mask(payload)
        self.imu_requests += 1
        if mask is None or not self.imu_replies_enabled:
            return b""
        r = self.imu_reading()
        try:
            body = encode_imu_payload(
                mask,
                rpy_rad=r.rpy_rad,
                accel_g=r.accel_g,
                gyro_dps=r.gyro_dps,
                mag=r.mag,
                quat=r.quat,
                controller_id=self.values.controller_id or 0,
            )
        except ValueError:  # a non-finite reading: the fake stays silent, as on a glitch
            return b""
        self.imu_replies_sent += 1
        return encode_frame(body)

    def reply(self) -> VescValues:
        """The GET_VALUES reply values now (the hook's, if one is set)."""
        base = default_reply_values(self.values, self.state)
        return base if self.reply_values is None else self.reply_values(self.state, base)

    def reply_frame(self) -> bytes:
        """The GET_VALUES reply frame now (payload truncated to ``reply_length``)."""
        return encode_frame(encode_values_payload(self.reply(), self.reply_length))

    # -- events --------------------------------------------------------------------------
    def events(self, command: int | None = None) -> list[FakeEvent]:
        """A copy of the recorded events (only those of ``command`` if given)."""
        return [e for e in self._events if command is None or e.command == command]

    def clear_events(self) -> None:
        """Forget recorded events."""
        self._events.clear()
