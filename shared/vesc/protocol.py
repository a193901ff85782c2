"""VESC serial protocol (firmware 3+): command ids, framing and command encoders.

Pure functions, no I/O. A frame is::

    short form:  0x02, len (1 byte),       payload, crc16 (2 bytes BE), 0x03   (len <= 255)
    long form:   0x03, len (2 bytes BE),   payload, crc16 (2 bytes BE), 0x03   (len <= 65535)

The CRC (CRC-16/XMODEM) covers the payload only. The first payload byte is the command id;
multi-byte values are big endian.
"""

from __future__ import annotations

import math
import struct
from enum import IntEnum

from shared.vesc.crc import crc16_xmodem

#: Start byte of a frame with a 1-byte length.
START_SHORT = 0x02
#: Start byte of a frame with a 2-byte big-endian length.
START_LONG = 0x03
#: Last byte of every frame.
END_BYTE = 0x03
#: Largest payload [bytes] of the short form.
MAX_SHORT_PAYLOAD = 0xFF
#: Largest payload [bytes] of the long form (and of any frame).
MAX_LONG_PAYLOAD = 0xFFFF
#: Header size [bytes] of the short / long form (start byte + length).
SHORT_HEADER_LEN = 2
LONG_HEADER_LEN = 3
#: Trailer size [bytes]: CRC (2) + end byte (1).
TRAILER_LEN = 3

#: Scale of SET_DUTY: duty cycle [-1, 1] * 1e5 -> int32.
DUTY_SCALE = 1e5
#: Scale of SET_CURRENT and SET_CURRENT_BRAKE: current [A] * 1e3 -> int32 (mA).
CURRENT_SCALE = 1e3
#: Scale of SET_SERVO_POS: position [0, 1] * 1e3 -> int16.
SERVO_SCALE = 1e3

_INT32_MIN, _INT32_MAX = -(2**31), 2**31 - 1
_INT16_MIN, _INT16_MAX = -(2**15), 2**15 - 1


class CommandId(IntEnum):
    """Command ids of the VESC protocol (first payload byte) used by racestack."""

    GET_VALUES = 4
    SET_DUTY = 5
    SET_CURRENT = 6
    SET_CURRENT_BRAKE = 7
    SET_RPM = 8
    SET_SERVO_POS = 12
    ALIVE = 30
    GET_IMU_DATA = 65


#: Commands that reset the firmware's command timeout (SET_SERVO_POS does not).
TIMEOUT_RESETTING_COMMANDS = frozenset(
    {
        CommandId.SET_DUTY,
        CommandId.SET_CURRENT,
        CommandId.SET_CURRENT_BRAKE,
        CommandId.SET_RPM,
        CommandId.ALIVE,
    }
)


def encode_frame(payload: bytes | bytearray) -> bytes:
    """Wrap ``payload`` into a frame (short form up to 255 bytes, long form above).

    Raises:
        ValueError: the payload is empty or longer than 65535 bytes.
    """
    n = len(payload)
    if n == 0:
        raise ValueError("a VESC payload needs at least the command id byte")
    if n > MAX_LONG_PAYLOAD:
        raise ValueError(f"payload of {n} bytes exceeds the protocol limit {MAX_LONG_PAYLOAD}")
    if n <= MAX_SHORT_PAYLOAD:
        header = bytes((START_SHORT, n))
    else:
        header = bytes((START_LONG,)) + n.to_bytes(2, "big")
    return header + bytes(payload) + crc16_xmodem(payload).to_bytes(2, "big") + bytes((END_BYTE,))


def _scaled_int(value: float, scale: float, lo: int, hi: int, what: str) -> int:
    if not math.isfinite(value):
        raise ValueError(f"{what} must be finite, got {value!r}")
    raw = round(value * scale)
    if not lo <= raw <= hi:
        raise ValueError(f"{what} = {value!r} does not fit the wire range")
    return raw


def encode_get_values() -> bytes:
    """The COMM_GET_VALUES request frame (``02 01 04 40 84 03``)."""
    return encode_frame(bytes((CommandId.GET_VALUES,)))


def encode_alive() -> bytes:
    """The COMM_ALIVE frame (``02 01 1e f3 ff 03``); resets the firmware's command timeout."""
    return encode_frame(bytes((CommandId.ALIVE,)))


def encode_set_rpm(erpm: float) -> bytes:
    """COMM_SET_RPM: electrical rpm [ERPM], rounded to an int32."""
    raw = _scaled_int(erpm, 1.0, _INT32_MIN, _INT32_MAX, "erpm")
    return encode_frame(struct.pack(">Bi", CommandId.SET_RPM, raw))


def encode_set_servo_pos(position: float) -> bytes:
    """COMM_SET_SERVO_POS: servo position [0, 1] (sent as int16 of position * 1e3)."""
    raw = _scaled_int(position, SERVO_SCALE, _INT16_MIN, _INT16_MAX, "servo position")
    return encode_frame(struct.pack(">Bh", CommandId.SET_SERVO_POS, raw))


def encode_set_current_brake(current_a: float) -> bytes:
    """COMM_SET_CURRENT_BRAKE: brake current [A] (sent as int32 mA)."""
    raw = _scaled_int(current_a, CURRENT_SCALE, _INT32_MIN, _INT32_MAX, "brake current")
    return encode_frame(struct.pack(">Bi", CommandId.SET_CURRENT_BRAKE, raw))


def encode_set_current(current_a: float) -> bytes:
    """COMM_SET_CURRENT: motor current [A] (sent as int32 mA)."""
    raw = _scaled_int(current_a, CURRENT_SCALE, _INT32_MIN, _INT32_MAX, "current")
    return encode_frame(struct.pack(">Bi", CommandId.SET_CURRENT, raw))


def encode_set_duty(duty: float) -> bytes:
    """COMM_SET_DUTY: duty cycle [-1, 1] (sent as int32 of duty * 1e5)."""
    raw = _scaled_int(duty, DUTY_SCALE, _INT32_MIN, _INT32_MAX, "duty")
    return encode_frame(struct.pack(">Bi", CommandId.SET_DUTY, raw))


def decode_command_value(payload: bytes) -> float | None:
    """The value a command payload carries, in the encoder's units (None if it has none).

    ERPM for SET_RPM, position [0, 1] for SET_SERVO_POS, [A] for the currents, [-1, 1] for
    SET_DUTY; None for ALIVE, GET_VALUES, unknown ids and payloads of the wrong length.
    """
    if not payload:
        return None
    cid = payload[0]
    body = payload[1:]
    if cid == CommandId.SET_RPM and len(body) == 4:
        return float(struct.unpack(">i", body)[0])
    if cid == CommandId.SET_SERVO_POS and len(body) == 2:
        return struct.unpack(">h", body)[0] / SERVO_SCALE
    if cid in (CommandId.SET_CURRENT, CommandId.SET_CURRENT_BRAKE) and len(body) == 4:
        return struct.unpack(">i", body)[0] / CURRENT_SCALE
    if cid == CommandId.SET_DUTY and len(body) == 4:
        return struct.unpack(">i", body)[0] / DUTY_SCALE
    return None
