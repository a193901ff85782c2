"""COMM_GET_VALUES replies: parse by length into ``VescValues`` (and encode, for the fake VESC).

Layout (byte offsets counting the command id as byte 0, big endian)::

     1 temp_fet int16/10       3 temp_motor int16/10     5 avg_motor_current int32/100
     9 avg_input_current /100 13 avg_id /100             17 avg_iq /100
    21 duty_now int16/1000    23 rpm int32 (ERPM)        27 v_in int16/10
    29 amp_hours int32/1e4    33 amp_hours_charged /1e4  37 watt_hours /1e4
    41 watt_hours_charged /1e4                           45 tachometer int32
    49 tachometer_abs uint32  53 fault code uint8        54 pid_pos int32/1e6
    58 controller_id uint8    59/61/63 temp_mos1..3 int16/10
    65 avg_vd int32/1e3       69 avg_vq int32/1e3        73 status uint8

Older firmware sends fewer fields: every field whose bytes are not all present is None; bytes
after the last known field are ignored. A reply too short for even ``temp_fet`` is malformed.
"""

from __future__ import annotations

import math
import struct
from dataclasses import dataclass, fields

from shared.vesc.protocol import CommandId

#: Bit of ``status_flags``: the firmware's command timeout has released the motor.
STATUS_TIMEOUT_BIT = 0x01
#: Bit of ``status_flags``: the kill switch is active.
STATUS_KILL_SWITCH_BIT = 0x02


@dataclass(frozen=True, slots=True)
class _Field:
    name: str
    offset: int
    fmt: str  # struct format of one big-endian value
    scale: float | None  # raw / scale -> float; None: the raw integer is kept

    @property
    def end(self) -> int:
        return self.offset + struct.calcsize(self.fmt)


#: The reply layout, in wire order (field name, byte offset, struct format, divisor).
VALUES_LAYOUT: tuple[_Field, ...] = (
    _Field("temp_fet_c", 1, ">h", 10.0),
    _Field("temp_motor_c", 3, ">h", 10.0),
    _Field("avg_motor_current_a", 5, ">i", 100.0),
    _Field("avg_input_current_a", 9, ">i", 100.0),
    _Field("avg_id_a", 13, ">i", 100.0),
    _Field("avg_iq_a", 17, ">i", 100.0),
    _Field("duty", 21, ">h", 1000.0),
    _Field("erpm", 23, ">i", 1.0),
    _Field("v_in_v", 27, ">h", 10.0),
    _Field("amp_hours", 29, ">i", 1e4),
    _Field("amp_hours_charged", 33, ">i", 1e4),
    _Field("watt_hours", 37, ">i", 1e4),
    _Field("watt_hours_charged", 41, ">i", 1e4),
    _Field("tachometer", 45, ">i", None),
    _Field("tachometer_abs", 49, ">I", None),
    _Field("fault_code", 53, ">B", None),
    _Field("pid_pos_deg", 54, ">i", 1e6),
    _Field("controller_id", 58, ">B", None),
    _Field("temp_mos1_c", 59, ">h", 10.0),
    _Field("temp_mos2_c", 61, ">h", 10.0),
    _Field("temp_mos3_c", 63, ">h", 10.0),
    _Field("avg_vd_v", 65, ">i", 1e3),
    _Field("avg_vq_v", 69, ">i", 1e3),
    _Field("status_flags", 73, ">B", None),
)

#: Payload length [bytes] (with the id) of a full reply of the newest layout above.
FULL_VALUES_PAYLOAD_LEN = VALUES_LAYOUT[-1].end
#: Shortest payload [bytes] that is not malformed (id + temp_fet).
MIN_VALUES_PAYLOAD_LEN = VALUES_LAYOUT[0].end


@dataclass(frozen=True, slots=True)
class VescValues:
    """One COMM_GET_VALUES reply; None where the firmware did not send the field.

    Attributes:
        temp_fet_c, temp_motor_c, temp_mos1_c, temp_mos2_c, temp_mos3_c: temperatures [deg C].
        avg_motor_current_a, avg_input_current_a, avg_id_a, avg_iq_a: currents [A].
        duty: duty cycle now [-1, 1].
        erpm: electrical rpm [1/min].
        v_in_v: input (battery) voltage [V].
        amp_hours, amp_hours_charged: charge drawn / regenerated [Ah].
        watt_hours, watt_hours_charged: energy drawn / regenerated [Wh].
        tachometer, tachometer_abs: tachometer [counts] (signed / absolute).
        fault_code: mc_fault_code (0 = none).
        pid_pos_deg: position of the PID position controller [deg].
        controller_id: CAN id of the controller.
        avg_vd_v, avg_vq_v: d / q axis voltages [V].
        status_flags: bit 0 firmware command timeout active, bit 1 kill switch active.
    """

    temp_fet_c: float
    temp_motor_c: float | None = None
    avg_motor_current_a: float | None = None
    avg_input_current_a: float | None = None
    avg_id_a: float | None = None
    avg_iq_a: float | None = None
    duty: float | None = None
    erpm: float | None = None
    v_in_v: float | None = None
    amp_hours: float | None = None
    amp_hours_charged: float | None = None
    watt_hours: float | None = None
    watt_hours_charged: float | None = None
    tachometer: int | None = None
    tachometer_abs: int | None = None
    fault_code: int | None = None
    pid_pos_deg: float | None = None
    controller_id: int | None = None
    temp_mos1_c: float | None = None
    temp_mos2_c: float | None = None
    temp_mos3_c: float | None = None
    avg_vd_v: float | None = None
    avg_vq_v: float | None = None
    status_flags: int | None = None

    @property
    def firmware_timeout(self) -> bool | None:
        """True when the firmware's command timeout released the motor (None: not sent)."""
        if self.status_flags is None:
            return None
        return bool(self.status_flags & STATUS_TIMEOUT_BIT)

    @property
    def kill_switch(self) -> bool | None:
        """True when the kill switch is active (None: not sent)."""
        if self.status_flags is None:
            return None
        return bool(self.status_flags & STATUS_KILL_SWITCH_BIT)

    def as_dict(self) -> dict[str, float | int | None]:
        """All fields as a plain dict (names carry the units)."""
        return {f.name: getattr(self, f.name) for f in fields(self)}


def is_values_reply(payload: bytes) -> bool:
    """True if the payload is a COMM_GET_VALUES reply (by its command id)."""
    return len(payload) > 0 and payload[0] == CommandId.GET_VALUES


def parse_values(payload: bytes) -> VescValues | None:
    """Parse a COMM_GET_VALUES reply payload (command id first); never raises.

    Returns None (malformed) when the payload is not a GET_VALUES reply or too short for even
    ``temp_fet_c``; otherwise every field fully present in the payload, the rest None.
    """
    if not is_values_reply(payload) or len(payload) < MIN_VALUES_PAYLOAD_LEN:
        return None
    n = len(payload)
    kwargs: dict[str, float | int] = {}
    for f in VALUES_LAYOUT:
        if f.end > n:
            break
        (raw,) = struct.unpack_from(f.fmt, payload, f.offset)
        kwargs[f.name] = raw if f.scale is None else raw / f.scale
    return VescValues(**kwargs)  # type: ignore[arg-type]


def encode_values_payload(values: VescValues, length: int | None = None) -> bytes:
    """Encode ``values`` as a GET_VALUES reply payload (the inverse of ``parse_values``).

    ``length`` truncates the payload to that many bytes (to mimic older firmware); fields
    that are None are sent as 0. Values are rounded to the wire resolution.

    Raises:
        ValueError: a value is not finite or does not fit its wire type.
    """
    out = bytearray(FULL_VALUES_PAYLOAD_LEN)
    out[0] = CommandId.GET_VALUES
    for f in VALUES_LAYOUT:
        value = getattr(values, f.name)
        if value is None:
            continue
        if isinstance(value, float) and not math.isfinite(value):
            raise ValueError(f"{f.name} must be finite, got {value!r}")
        raw = int(value) if f.scale is None else round(value * f.scale)
        try:
            struct.pack_into(f.fmt, out, f.offset, raw)
        except struct.error as exc:
            raise ValueError(f"{f.name} = {value!r} does not fit {f.fmt}") from exc
    if length is not None:
        if not 1 <= length <= FULL_VALUES_PAYLOAD_LEN:
            raise ValueError(f"length must be in [1, {FULL_VALUES_PAYLOAD_LEN}], got {length}")
        return bytes(out[:length])
    return bytes(out)
