"""COMM_GET_IMU_DATA: golden bytes from the firmware layout, float32_auto, the mounting
rotation, the fake's answers and the driver core's ``ImuRecord`` (no threads, no Zenoh)."""

from __future__ import annotations

import math
import struct
from typing import Any

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from services.vesc_driver.driver import VescDriver
from services.vesc_driver.serial_link import SerialLink
from services.vesc_driver.service import imu_message
from shared.config.vesc import VescSettings
from shared.vesc.crc import crc16_xmodem
from shared.vesc.decoder import FrameDecoder
from shared.vesc.fake import FakeImu, FakeVescModel
from shared.vesc.imu import (
    DRIVER_MASK,
    STANDARD_GRAVITY_MPS2,
    CarImu,
    ImuField,
    board_reading,
    encode_get_imu_data,
    encode_imu_payload,
    float32_auto_decode,
    float32_auto_encode,
    imu_in_car,
    parse_imu,
    rotation_from_rpy,
)
from shared.vesc.protocol import CommandId, encode_frame


def _be_f32(x: float) -> bytes:
    """IEEE-754 single, big endian: what float32_auto is for normal numbers."""
    return struct.pack(">f", x)


#: A reply to DRIVER_MASK written out by hand from the firmware's layout (comm/commands.c):
#: id 65, the mask echoed as uint16 BE, acc x y z [g], gyro x y z [deg/s], controller id 7.
GOLDEN_ACC_G = (0.25, -0.5, 1.0)
GOLDEN_GYRO_DPS = (1.5, -2.0, 90.0)
GOLDEN_REPLY = (
    bytes((0x41, 0x01, 0xF8))
    + b"".join(_be_f32(v) for v in (*GOLDEN_ACC_G, *GOLDEN_GYRO_DPS))
    + bytes((7,))
)


def test_command_id_and_request_frame_match_the_firmware() -> None:
    assert CommandId.GET_IMU_DATA == 65  # COMM_GET_IMU_DATA in datatypes.h
    assert DRIVER_MASK == 0x01F8  # bits 3..8: acc x y z, gyro x y z
    frame = encode_get_imu_data(DRIVER_MASK)
    payload = bytes((0x41, 0x01, 0xF8))  # id, mask uint16 big endian
    crc = crc16_xmodem(payload).to_bytes(2, "big")
    assert frame == bytes((0x02, 3)) + payload + crc + b"\x03"
    assert encode_get_imu_data(0xFFFF)[2:5] == b"\x41\xff\xff"
    with pytest.raises(ValueError):
        encode_get_imu_data(0x10000)


def test_golden_reply_parses_and_encodes_back() -> None:
    imu = parse_imu(GOLDEN_REPLY)
    assert imu is not None
    assert imu.mask == 0x01F8 and imu.controller_id == 7
    assert imu.accel_g == GOLDEN_ACC_G and imu.gyro_dps == GOLDEN_GYRO_DPS
    assert imu.rpy_rad is None and imu.mag is None and imu.quat is None
    again = encode_imu_payload(
        DRIVER_MASK, accel_g=GOLDEN_ACC_G, gyro_dps=GOLDEN_GYRO_DPS, controller_id=7
    )
    assert again == GOLDEN_REPLY


def test_every_field_in_bit_order() -> None:
    rpy, acc, gyro, mag, quat = (0.1, 0.2, 0.3), (1, 2, 3), (4, 5, 6), (7, 8, 9), (0.5, 0, 0, 1)
    p = encode_imu_payload(
        int(ImuField.ROLL | ImuField.YAW | ImuField.MAG_Y | ImuField.Q3),
        rpy_rad=rpy,
        accel_g=acc,
        gyro_dps=gyro,
        mag=mag,
        quat=quat,
    )
    words = [struct.unpack_from(">f", p, 3 + 4 * i)[0] for i in range(4)]
    assert words == pytest.approx([0.1, 0.3, 8.0, 1.0])
    full = parse_imu(
        encode_imu_payload(0xFFFF, rpy_rad=rpy, accel_g=acc, gyro_dps=gyro, mag=mag, quat=quat)
    )
    assert full is not None
    assert full.rpy_rad == pytest.approx(rpy) and full.quat == pytest.approx(quat)
    assert full.mag == pytest.approx(mag)


@given(st.floats(width=32, allow_nan=False, allow_infinity=False))
def test_float32_auto_is_ieee_single_for_normal_numbers(x: float) -> None:
    word = float32_auto_encode(x)
    if abs(x) < 1.5e-38:
        assert word == 0  # the firmware flushes subnormals (and tiny normals) to 0
        assert float32_auto_decode(word) == 0.0
    else:
        assert word == struct.unpack(">I", _be_f32(x))[0]
        assert float32_auto_decode(word) == x


def test_float32_auto_decoder_follows_the_firmware_formula_off_ieee() -> None:
    # e == 0 with a significand: the firmware reads (sig / 2^24 + 0.5) * 2^-126 (no subnormal)
    assert float32_auto_decode(0x00000001) == pytest.approx((1 / 2**24 + 0.5) * 2.0**-126)
    assert math.isfinite(float32_auto_decode(0x7FC00000))  # an IEEE NaN pattern: finite here
    with pytest.raises(ValueError):
        float32_auto_encode(float("nan"))
    with pytest.raises(ValueError):
        float32_auto_encode(1e39)


@pytest.mark.parametrize(
    "payload",
    [
        b"",
        b"\x41",
        b"\x41\x01",
        GOLDEN_REPLY[:-2],  # truncated inside the last value
        GOLDEN_REPLY + b"\x00\x00",  # longer than the mask says
        b"\x04" + GOLDEN_REPLY[1:],  # not the IMU id
        b"\x41\xff\xff" + bytes(8),  # mask says 16 values, 2 present
    ],
)
def test_malformed_replies_parse_to_none(payload: bytes) -> None:
    assert parse_imu(payload) is None


def test_reply_without_controller_id_is_accepted() -> None:
    imu = parse_imu(GOLDEN_REPLY[:-1])
    assert imu is not None and imu.controller_id is None and imu.accel_g == GOLDEN_ACC_G


def test_mounting_rotation_to_the_car_frame() -> None:
    imu = parse_imu(GOLDEN_REPLY)
    assert imu is not None
    level = imu_in_car(imu, np.eye(3))
    assert level is not None
    assert level.yaw_rate_radps == pytest.approx(math.radians(90.0))
    assert level.ax_mps2 == pytest.approx(0.25 * STANDARD_GRAVITY_MPS2)
    assert level.ay_mps2 == pytest.approx(-0.5 * STANDARD_GRAVITY_MPS2)
    # board yawed +90 deg in the car: board x points to the car's left, board y backwards
    r = rotation_from_rpy(0.0, 0.0, math.radians(90.0))
    car = imu_in_car(imu, r)
    assert car is not None
    assert car.ax_mps2 == pytest.approx(0.5 * STANDARD_GRAVITY_MPS2)
    assert car.ay_mps2 == pytest.approx(0.25 * STANDARD_GRAVITY_MPS2)
    assert car.yaw_rate_radps == pytest.approx(math.radians(90.0))
    # board upside down (rolled 180 deg): its z is the car's -z, its y the car's -y
    flip = imu_in_car(imu, rotation_from_rpy(math.pi, 0.0, 0.0))
    assert flip is not None
    assert flip.yaw_rate_radps == pytest.approx(-math.radians(90.0))
    assert flip.ay_mps2 == pytest.approx(0.5 * STANDARD_GRAVITY_MPS2)


@given(
    st.floats(-math.pi, math.pi),
    st.floats(-1.5, 1.5),
    st.floats(-math.pi, math.pi),
    st.floats(-20.0, 20.0),
    st.floats(-30.0, 30.0),
    st.floats(-30.0, 30.0),
)
def test_board_reading_inverts_imu_in_car(
    roll: float, pitch: float, yaw: float, r: float, ax: float, ay: float
) -> None:
    rot = rotation_from_rpy(roll, pitch, yaw)
    assert rot @ rot.T == pytest.approx(np.eye(3), abs=1e-12)
    acc, gyro = board_reading(CarImu(r, ax, ay), rot)
    imu = parse_imu(encode_imu_payload(DRIVER_MASK, accel_g=acc, gyro_dps=gyro))
    assert imu is not None
    back = imu_in_car(imu, rot)
    assert back is not None
    assert back.yaw_rate_radps == pytest.approx(r, abs=1e-4)
    assert back.ax_mps2 == pytest.approx(ax, abs=1e-4)
    assert back.ay_mps2 == pytest.approx(ay, abs=1e-4)


def test_mounting_settings() -> None:
    assert VescSettings().poll_imu_rate_hz == 0.0  # off unless configured
    s = VescSettings(imu_yaw_deg=90.0)
    assert s.imu_mounting() == pytest.approx(rotation_from_rpy(0, 0, math.pi / 2))
    m = ((0.0, -1.0, 0.0), (1.0, 0.0, 0.0), (0.0, 0.0, 1.0))
    assert VescSettings(imu_rotation=m).imu_mounting() == pytest.approx(np.array(m))
    with pytest.raises(ValueError, match="rotation"):
        VescSettings(imu_rotation=((1, 0, 0), (0, 1, 0), (0, 0, -1)))  # a reflection
    with pytest.raises(ValueError, match="not both"):
        VescSettings(imu_rotation=m, imu_roll_deg=5.0)
    with pytest.raises(ValueError):
        VescSettings(imu_pitch_deg=120.0)


# --------------------------------------------------------------------------- the fake
def test_fake_answers_imu_requests_with_the_requested_mask() -> None:
    fake = FakeVescModel(imu=FakeImu(accel_g=(0.1, 0.2, 1.0), gyro_dps=(0.0, 0.0, 45.0)))
    out = fake.feed(encode_get_imu_data(DRIVER_MASK), now=0.0)
    frames = FrameDecoder().feed(out)
    assert len(frames) == 1
    imu = parse_imu(frames[0].payload)
    assert imu is not None and imu.mask == DRIVER_MASK
    assert imu.accel_g == pytest.approx((0.1, 0.2, 1.0)) and imu.gyro_dps == (0.0, 0.0, 45.0)
    assert fake.imu_requests == fake.imu_replies_sent == 1
    fake.reply_imu = lambda state, r: FakeImu(gyro_dps=(0.0, 0.0, -10.0))
    imu = parse_imu(FrameDecoder().feed(fake.feed(encode_get_imu_data(0x01C0), 0.1))[0].payload)
    assert imu is not None and imu.gyro_dps == (0.0, 0.0, -10.0) and imu.accel_g is None
    fake.imu_replies_enabled = False
    assert fake.feed(encode_get_imu_data(), 0.2) == b""
    assert fake.feed(encode_frame(b"\x41\x01"), 0.3) == b""  # a request without its mask
    assert fake.imu_requests == 4 and fake.imu_replies_sent == 2


# --------------------------------------------------------------------------- driver core
def make_driver(clock: Any, factory: Any, **overrides: Any) -> VescDriver:
    s = VescSettings(port="/dev/fake", **{"poll_imu_rate_hz": 50.0, **overrides})
    link = SerialLink(s.port, clock=clock, serial_factory=factory)
    return VescDriver(s, link, clock=clock)


def _imu_requests(frames: tuple[bytes, ...]) -> int:
    return sum(f == encode_get_imu_data(DRIVER_MASK) for f in frames)


def test_driver_polls_the_imu_at_its_rate(clock: Any, factory: Any) -> None:
    drv = make_driver(clock, factory, poll_imu_rate_hz=25.0)
    n = sum(_imu_requests(drv.tick(clock.advance(0.02)).frames_written) for _ in range(50))
    assert 24 <= n <= 26  # 1 s of 50 Hz ticks at 25 Hz
    off = make_driver(clock, factory, poll_imu_rate_hz=0.0)
    assert sum(_imu_requests(off.tick(clock.advance(0.02)).frames_written) for _ in range(5)) == 0


def test_driver_imu_record_is_the_reply_in_the_car_frame(clock: Any, factory: Any) -> None:
    drv = make_driver(clock, factory, imu_yaw_deg=90.0)
    assert drv.tick(clock()).imu is None
    factory.current.rx += encode_frame(GOLDEN_REPLY)
    r = drv.tick(clock.advance(0.02))
    assert r.imu is not None and r.imu.stamp_s == clock()
    assert r.imu.ax_mps2 == pytest.approx(0.5 * STANDARD_GRAVITY_MPS2)
    assert r.imu.ay_mps2 == pytest.approx(0.25 * STANDARD_GRAVITY_MPS2)
    assert r.imu.yaw_rate_radps == pytest.approx(math.pi / 2)
    assert drv.tick(clock.advance(0.02)).imu is None  # each reply reported once
    assert drv.counters.imu_replies == 1 and drv.imu_age_s(clock()) == pytest.approx(0.02)


def test_driver_counts_and_drops_garbage_and_short_imu_replies(clock: Any, factory: Any) -> None:
    drv = make_driver(clock, factory)
    drv.tick(clock())
    port = factory.current
    port.rx += b"\x41\x41\x02\x02\x03"  # noise
    port.rx += encode_frame(GOLDEN_REPLY[:-3])  # short: mask says 6 values
    port.rx += encode_frame(b"\x41")  # no mask
    port.rx += encode_frame(encode_imu_payload(int(ImuField.GYRO_Z)))  # no acceleration
    bad_crc = bytearray(encode_frame(GOLDEN_REPLY))
    bad_crc[-2] ^= 0xFF
    port.rx += bytes(bad_crc)
    r = drv.tick(clock.advance(0.02))
    assert r.imu is None
    assert drv.counters.malformed_imu == 3 and drv.counters.imu_replies == 0
    assert drv.decoder.counters.crc_errors == 1 and drv.decoder.counters.garbage_bytes > 0
    port.rx += encode_frame(GOLDEN_REPLY)  # a good one after all that is still decoded
    assert drv.tick(clock.advance(0.02)).imu is not None
    assert drv.diagnostics()["driver.malformed_imu"] == 3


def test_imu_message_rejects_values_beyond_the_contract() -> None:
    from services.vesc_driver.driver import ImuRecord

    ok, bad = imu_message(ImuRecord(1.0, 0.5, 1.0, -2.0), stamp_s=1e9)
    assert ok is not None and bad == ()
    assert (ok.yaw_rate_radps, ok.ax_mps2, ok.ay_mps2) == (0.5, 1.0, -2.0)
    none, bad = imu_message(ImuRecord(1.0, 0.5, 1e6, 0.0), stamp_s=1e9)
    assert none is None and bad == ("ax_mps2",)
