"""CRC, golden frames and command encoders of the VESC protocol."""

from __future__ import annotations

import struct

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from shared.vesc.crc import CRC16_CHECK, crc16_xmodem
from shared.vesc.protocol import (
    END_BYTE,
    MAX_LONG_PAYLOAD,
    MAX_SHORT_PAYLOAD,
    START_LONG,
    START_SHORT,
    CommandId,
    decode_command_value,
    encode_alive,
    encode_frame,
    encode_get_values,
    encode_set_current,
    encode_set_current_brake,
    encode_set_duty,
    encode_set_rpm,
    encode_set_servo_pos,
)


def test_crc_check_value() -> None:
    assert crc16_xmodem(b"123456789") == 0x31C3 == CRC16_CHECK
    assert crc16_xmodem(b"") == 0
    # running checksum in pieces equals the one-shot checksum
    assert crc16_xmodem(b"6789", crc16_xmodem(b"12345")) == 0x31C3


def test_golden_frames() -> None:
    assert encode_get_values() == bytes.fromhex("02 01 04 40 84 03")
    assert encode_alive() == bytes.fromhex("02 01 1e f3 ff 03")


def _unframe(frame: bytes) -> bytes:
    if frame[0] == START_SHORT:
        n, body = frame[1], frame[2:]
    else:
        assert frame[0] == START_LONG
        n, body = int.from_bytes(frame[1:3], "big"), frame[3:]
    payload, crc, end = body[:n], body[n : n + 2], body[n + 2 :]
    assert end == bytes((END_BYTE,))
    assert int.from_bytes(crc, "big") == crc16_xmodem(payload)
    return payload


@pytest.mark.parametrize(
    ("frame", "cid", "fmt", "raw"),
    [
        (encode_set_rpm(9228), CommandId.SET_RPM, ">i", 9228),
        (encode_set_rpm(-23250.4), CommandId.SET_RPM, ">i", -23250),
        (encode_set_servo_pos(0.40905), CommandId.SET_SERVO_POS, ">h", 409),
        (encode_set_current_brake(20.0), CommandId.SET_CURRENT_BRAKE, ">i", 20000),
        (encode_set_current(-1.5), CommandId.SET_CURRENT, ">i", -1500),
        (encode_set_duty(0.25), CommandId.SET_DUTY, ">i", 25000),
    ],
)
def test_encoders(frame: bytes, cid: CommandId, fmt: str, raw: int) -> None:
    payload = _unframe(frame)
    assert payload[0] == cid
    assert struct.unpack(fmt, payload[1:]) == (raw,)


def test_set_rpm_golden_bytes() -> None:
    # id 8, int32 BE 9228 = 0x0000240C
    assert encode_set_rpm(9228)[:7] == bytes.fromhex("02 05 08 00 00 24 0c")
    assert encode_set_servo_pos(0.409)[:5] == bytes.fromhex("02 03 0c 01 99")


def test_decode_command_value_inverts_encoders() -> None:
    assert decode_command_value(_unframe(encode_set_rpm(-4614))) == -4614.0
    assert decode_command_value(_unframe(encode_set_servo_pos(0.85))) == pytest.approx(0.85)
    assert decode_command_value(_unframe(encode_set_current_brake(20))) == 20.0
    assert decode_command_value(_unframe(encode_set_duty(-0.5))) == -0.5
    assert decode_command_value(_unframe(encode_alive())) is None
    assert decode_command_value(b"") is None
    assert decode_command_value(bytes((CommandId.SET_RPM, 1, 2))) is None  # wrong length


def test_length_forms() -> None:
    short = encode_frame(bytes(MAX_SHORT_PAYLOAD))
    assert short[0] == START_SHORT and short[1] == MAX_SHORT_PAYLOAD
    assert len(short) == 2 + MAX_SHORT_PAYLOAD + 3
    long = encode_frame(bytes(MAX_SHORT_PAYLOAD + 1))
    assert long[0] == START_LONG and long[1:3] == (MAX_SHORT_PAYLOAD + 1).to_bytes(2, "big")
    assert _unframe(long) == bytes(MAX_SHORT_PAYLOAD + 1)
    biggest = encode_frame(bytes(MAX_LONG_PAYLOAD))
    assert biggest[1:3] == b"\xff\xff" and len(biggest) == 3 + MAX_LONG_PAYLOAD + 3


def test_bad_payloads_raise_value_error() -> None:
    with pytest.raises(ValueError, match="exceeds"):
        encode_frame(bytes(MAX_LONG_PAYLOAD + 1))
    with pytest.raises(ValueError):
        encode_frame(b"")
    for bad in (float("nan"), float("inf"), -float("inf")):
        with pytest.raises(ValueError, match="finite"):
            encode_set_rpm(bad)
    with pytest.raises(ValueError, match="wire range"):
        encode_set_rpm(2.0**31)
    with pytest.raises(ValueError, match="wire range"):
        encode_set_servo_pos(40.0)  # 40000 does not fit an int16


def _crc16_xmodem_bitwise(data: bytes) -> int:
    """Reference CRC-16/XMODEM, bit by bit (poly 0x1021, init 0, no reflection, no xor)."""
    crc = 0
    for byte in data:
        crc ^= byte << 8
        for _ in range(8):
            crc = ((crc << 1) ^ 0x1021) if crc & 0x8000 else (crc << 1)
            crc &= 0xFFFF
    return crc


@settings(max_examples=200, deadline=None)
@given(st.binary(max_size=300))
def test_crc_matches_a_bitwise_reference(data: bytes) -> None:
    assert crc16_xmodem(data) == _crc16_xmodem_bitwise(data)
    assert crc16_xmodem(bytearray(data)) == crc16_xmodem(memoryview(data))
