"""GET_VALUES replies: parsing by length, older firmware, malformed replies."""

from __future__ import annotations

import itertools
import math
import struct
from dataclasses import fields

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from shared.vesc.fake import DEFAULT_VALUES
from shared.vesc.protocol import CommandId
from shared.vesc.values import (
    FULL_VALUES_PAYLOAD_LEN,
    MIN_VALUES_PAYLOAD_LEN,
    VALUES_LAYOUT,
    VescValues,
    encode_values_payload,
    parse_values,
)


def full_reply() -> bytes:
    """A hand-packed reply of the documented layout (independent of the encoder)."""
    return struct.pack(
        ">BhhiiiihihiiiiiIBiBhhhiiB",
        CommandId.GET_VALUES,
        455,  # temp_fet 45.5 C
        -52,  # temp_motor -5.2 C
        1234,  # avg_motor_current 12.34 A
        -250,  # avg_input_current -2.5 A
        10,  # id 0.1 A
        -20,  # iq -0.2 A
        -125,  # duty -0.125
        -9228,  # rpm
        168,  # v_in 16.8 V
        12345,  # amp_hours 1.2345
        5,  # amp_hours_charged 0.0005
        200000,  # watt_hours 20.0
        10000,  # watt_hours_charged 1.0
        -4242,  # tachometer
        4242,  # tachometer_abs
        3,  # fault code
        90_000_000,  # pid_pos 90 deg
        7,  # controller id
        401,
        402,
        403,  # temp_mos 40.1 .. 40.3
        -1500,  # vd -1.5 V
        2500,  # vq 2.5 V
        0b11,  # status: timeout + kill switch
    )


def test_layout_is_contiguous_and_matches_doc() -> None:
    assert VALUES_LAYOUT[0].offset == 1
    for a, b in itertools.pairwise(VALUES_LAYOUT):
        assert a.end == b.offset, (a.name, b.name)
    assert FULL_VALUES_PAYLOAD_LEN == 74 and MIN_VALUES_PAYLOAD_LEN == 3
    assert [f.name for f in VALUES_LAYOUT] == [f.name for f in fields(VescValues)]
    assert len(full_reply()) == FULL_VALUES_PAYLOAD_LEN


def test_parse_full_reply() -> None:
    v = parse_values(full_reply())
    assert v is not None
    assert v.temp_fet_c == pytest.approx(45.5) and v.temp_motor_c == pytest.approx(-5.2)
    assert v.avg_motor_current_a == pytest.approx(12.34)
    assert v.avg_input_current_a == pytest.approx(-2.5)
    assert (v.avg_id_a, v.avg_iq_a) == (pytest.approx(0.1), pytest.approx(-0.2))
    assert v.duty == pytest.approx(-0.125) and v.erpm == -9228.0
    assert v.v_in_v == pytest.approx(16.8)
    assert v.amp_hours == pytest.approx(1.2345) and v.amp_hours_charged == pytest.approx(5e-4)
    assert v.watt_hours == pytest.approx(20.0) and v.watt_hours_charged == pytest.approx(1.0)
    assert (v.tachometer, v.tachometer_abs, v.fault_code, v.controller_id) == (-4242, 4242, 3, 7)
    assert v.pid_pos_deg == pytest.approx(90.0)
    assert (v.temp_mos1_c, v.temp_mos2_c, v.temp_mos3_c) == pytest.approx((40.1, 40.2, 40.3))
    assert (v.avg_vd_v, v.avg_vq_v) == (pytest.approx(-1.5), pytest.approx(2.5))
    assert v.status_flags == 3 and v.firmware_timeout and v.kill_switch


def test_extra_trailing_bytes_ignored() -> None:
    assert parse_values(full_reply() + b"\x01\x02\x03") == parse_values(full_reply())


@pytest.mark.parametrize("length", [3, 5, 23, 27, 29, 53, 54, 58, 59, 73])
def test_older_firmware_sends_fewer_fields(length: int) -> None:
    v = parse_values(full_reply()[:length])
    assert v is not None
    for f in VALUES_LAYOUT:
        got = getattr(v, f.name)
        assert (got is None) == (f.end > length), f.name
    if length < FULL_VALUES_PAYLOAD_LEN:
        assert v.firmware_timeout is None and v.kill_switch is None


def test_cut_inside_a_field_drops_that_field() -> None:
    v = parse_values(full_reply()[:25])  # rpm (23-26) is cut
    assert v is not None and v.duty is not None and v.erpm is None


@pytest.mark.parametrize("payload", [b"", b"\x04", b"\x04\x01", b"\x08\x00\x00\x24\x0c"])
def test_malformed_is_none(payload: bytes) -> None:
    assert parse_values(payload) is None


def test_encode_round_trip_and_truncation() -> None:
    assert parse_values(encode_values_payload(DEFAULT_VALUES)) == DEFAULT_VALUES
    assert encode_values_payload(parse_values(full_reply())) == full_reply()  # type: ignore[arg-type]
    assert len(encode_values_payload(DEFAULT_VALUES, 27)) == 27
    with pytest.raises(ValueError):
        encode_values_payload(VescValues(temp_fet_c=math.nan))
    with pytest.raises(ValueError):
        encode_values_payload(VescValues(temp_fet_c=1e9))
    with pytest.raises(ValueError):
        encode_values_payload(DEFAULT_VALUES, 0)


@settings(max_examples=200, deadline=None)
@given(payload=st.binary(max_size=100))
def test_parse_never_raises(payload: bytes) -> None:
    v = parse_values(payload)
    if v is not None:
        assert payload[0] == CommandId.GET_VALUES and len(payload) >= MIN_VALUES_PAYLOAD_LEN


@settings(max_examples=100, deadline=None)
@given(payload=st.binary(min_size=FULL_VALUES_PAYLOAD_LEN, max_size=FULL_VALUES_PAYLOAD_LEN))
def test_parse_encode_round_trip(payload: bytes) -> None:
    payload = bytes((CommandId.GET_VALUES,)) + payload[1:]
    v = parse_values(payload)
    assert v is not None
    assert encode_values_payload(v) == payload
