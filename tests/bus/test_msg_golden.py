"""Wire compatibility: the encoder produces byte for byte what the first codec produced.

The payloads below were recorded from the hand-written codec (``shared/messages/codec.py``
before it moved onto msgspec) by encoding the records that ``CASES`` builds; each case must
encode to exactly those bytes and decode back to an equal record, so senders and receivers
of either implementation interoperate. Short payloads are kept as hex; long ones (a
1080-beam scan, a 10-stage plan) as length and SHA-256 of the bytes.
"""

from __future__ import annotations

import hashlib
import math
from collections.abc import Callable

import msgpack
import numpy as np
import pytest

from shared.messages import (
    MESSAGE_TYPES,
    DriveCmd,
    Imu,
    LapEvent,
    LogEvent,
    Message,
    Odom,
    Opponents,
    OpponentTrack,
    Plan,
    Pose,
    Scan,
    SimControl,
    SimTruth,
    State,
    Teleport,
    VescState,
    decode,
    decode_any,
    encode,
)


def _plan(n: int) -> Plan:
    horizon = np.zeros((n + 1, 4))
    horizon[:, 0] = np.linspace(0.0, 1.0, n + 1)
    horizon[:, 1] = np.linspace(-2.0, 3.0, n + 1)
    horizon[:, 2] = np.linspace(0.1, -0.4, n + 1)
    horizon[:, 3] = np.linspace(10.0, 11.0, n + 1)
    return Plan(
        stamp_s=1_700_000_000.25,
        seq=2**40 + 3,
        horizon=horizon,
        inputs=np.tile([3.0, 0.1, 3.0], (n, 1)),
        beta=np.linspace(0.2, 0.8, n),
        status="fallback",
        solver_status="Solve_Succeeded",
        iterations=7,
        solve_time_ms=0.72,
        method="cimpcc",
        s_m=10.0,
        e_con_m=-0.05,
        source_stamp_s=1_700_000_000.2,
        consecutive_failures=1,
    )


def _scan(n: int) -> Scan:
    ranges = np.linspace(0.05, 30.0, n).astype(np.float32)
    ranges[::7] = np.inf
    return Scan(
        stamp_s=12.0, seq=9, angle_min_rad=-2.35, angle_increment_rad=4.7 / n, ranges_m=ranges
    )


#: name -> a record built the way services build them (ints and numpy scalars included).
CASES: dict[str, Callable[[], Message]] = {
    "pose_cov": lambda: Pose(
        stamp_s=1.0, seq=1, x_m=1.5, y_m=-2.0, yaw_rad=0.3, cov=np.diag([0.01, 0.02, 0.003])
    ),
    "pose_no_cov": lambda: Pose(stamp_s=1.0, x_m=-1e4, y_m=1e4, yaw_rad=-0.0),
    "pose_numpy_scalars": lambda: Pose(
        stamp_s=np.float64(3.5), seq=np.int64(12), x_m=np.float32(0.1), y_m=2, yaw_rad=0
    ),
    "imu": lambda: Imu(stamp_s=1.0, seq=127, yaw_rate_radps=0.5, ax_mps2=1.2, ay_mps2=-0.4),
    "odom": lambda: Odom(stamp_s=1.0, seq=128, speed_mps=3.1, steering_rad=-0.2,
                         yaw_rate_radps=0.7),
    "odom_no_yaw_rate": lambda: Odom(stamp_s=0, seq=65536, speed_mps=-1, steering_rad=1.0),
    "scan_4": lambda: Scan(
        stamp_s=1.0,
        angle_min_rad=-2.35,
        angle_increment_rad=0.0043,
        ranges_m=np.array([1.0, 2.5, np.inf, 0.3], dtype=np.float32),
    ),
    "scan_from_list": lambda: Scan(
        stamp_s=1.0, angle_min_rad=0, angle_increment_rad=-0.1, ranges_m=[1, 2.5, 0]
    ),
    "scan_1080": lambda: _scan(1080),
    "state": lambda: State(
        stamp_s=1_700_000_000.123456,
        seq=2**63 - 1,
        x_m=1.0,
        y_m=2.0,
        yaw_rad=-3.0,
        speed_mps=2.2,
        yaw_rate_radps=0.1,
        steering_rad=0.05,
        source_stamp_s=1_700_000_000.1,
        valid=True,
    ),
    "state_invalid": lambda: State(
        stamp_s=2.0, x_m=0, y_m=0, yaw_rad=0, speed_mps=0, yaw_rate_radps=0, steering_rad=0,
        source_stamp_s=0, valid=False,
    ),
    "drive_cmd": lambda: DriveCmd(stamp_s=2.0, seq=41, speed_mps=3.3, steering_rad=0.21),
    "drive_cmd_edges": lambda: DriveCmd(stamp_s=1e10, seq=2**32, speed_mps=-50.0,
                                        steering_rad=-1),
    "plan_2": lambda: _plan(2),
    "plan_10": lambda: _plan(10),
    "lap_event": lambda: LapEvent(
        stamp_s=30.0, seq=3, kind="lap", lap=1, lap_time_s=9.87, mean_speed_mps=3.4,
        off_track_events=0, max_abs_e_con_m=0.12,
    ),
    "lap_event_start": lambda: LapEvent(stamp_s=0.0, kind="start", lap=0, off_track_events=0),
    "vesc_state": lambda: VescState(
        stamp_s=3.0,
        seq=5,
        status="ok",
        temp_fet_c=35.0,
        temp_motor_c=40.0,
        avg_motor_current_a=3.2,
        avg_input_current_a=1.1,
        duty=0.2,
        erpm=12000,
        v_in_v=11.8,
        amp_hours=0.05,
        tachometer=-1234,
        tachometer_abs=2**32 - 1,
        fault_code=0,
        controller_id=255,
        temp_mos3_c=-100,
    ),
    "vesc_state_status_only": lambda: VescState(stamp_s=3.0, status="disconnected"),
    "sim_truth": lambda: SimTruth(
        stamp_s=4.0, seq=300, x_m=1.0, y_m=1.0, yaw_rad=0.0, speed_mps=3.0,
        yaw_rate_radps=0.2, slip_rad=-math.pi, steering_rad=0.1, s_m=42.0, e_con_m=0.1,
        off_track=True, lap=2,
    ),
    "log_event": lambda: LogEvent(stamp_s=5.0, seq=6, level="warning", source="planner",
                                  text="slow solve"),
    "log_event_unicode": lambda: LogEvent(stamp_s=5.0, level="error", source="ü" * 64,
                                          text="Δt > 100 ms ✓\n" + "x" * 300),
    "sim_control": lambda: SimControl(stamp_s=6.0, action="reset"),
    # added with the type (no first-codec payload): the bytes of msgpack.packb of its map
    "teleport": lambda: Teleport(stamp_s=7.0, seq=9, x_m=-0.3, y_m=1.2, yaw_rad=0.1),
    # added with the type (no first-codec payload): the bytes of msgpack.packb of its map
    "opponents": lambda: Opponents(
        stamp_s=8.0, seq=2, source_stamp_s=7.5,
        tracks=[OpponentTrack(id=1, x_m=4.0, y_m=-1.5, vx_mps=2.5, vy_mps=0.5, yaw_rad=0.25,
                              length_m=0.5, width_m=0.25, cov_xx_m2=0.25, cov_xy_m2=0.0,
                              cov_yy_m2=0.125, speed_var_m2ps2=0.5, age_s=1.5, hits=7)],
    ),
    "opponents_empty": lambda: Opponents(stamp_s=8.0, seq=3, source_stamp_s=7.5),
}

#: name -> hex of the payload, or (length, SHA-256 hex) for long payloads.
GOLDEN: dict[str, str | tuple[int, str]] = {
    "pose_cov": (
        "88a474797065a4706f7365a17601a77374616d705f73cb3ff0000000000000a373657101a3785f6d"
        "cb3ff8000000000000a3795f6dcbc000000000000000a77961775f726164cb3fd3333333333333a3"
        "636f7683a56474797065a33c6638a57368617065920303a464617461c4487b14ae47e17a843f0000"
        "000000000000000000000000000000000000000000007b14ae47e17a943f00000000000000000000"
        "0000000000000000000000000000fa7e6abc7493683f"
    ),
    "pose_no_cov": (
        "88a474797065a4706f7365a17601a77374616d705f73cb3ff0000000000000a373657100a3785f6d"
        "cbc0c3880000000000a3795f6dcb40c3880000000000a77961775f726164cb8000000000000000a3"
        "636f76c0"
    ),
    "pose_numpy_scalars": (
        "88a474797065a4706f7365a17601a77374616d705f73cb400c000000000000a37365710ca3785f6d"
        "cb3fb99999a0000000a3795f6dcb4000000000000000a77961775f726164cb0000000000000000a3"
        "636f76c0"
    ),
    "imu": (
        "87a474797065a3696d75a17601a77374616d705f73cb3ff0000000000000a37365717fae7961775f"
        "726174655f7261647073cb3fe0000000000000a761785f6d707332cb3ff3333333333333a761795f"
        "6d707332cbbfd999999999999a"
    ),
    "odom": (
        "87a474797065a46f646f6da17601a77374616d705f73cb3ff0000000000000a3736571cc80a97370"
        "6565645f6d7073cb4008cccccccccccdac7374656572696e675f726164cbbfc999999999999aae79"
        "61775f726174655f7261647073cb3fe6666666666666"
    ),
    "odom_no_yaw_rate": (
        "87a474797065a46f646f6da17601a77374616d705f73cb0000000000000000a3736571ce00010000"
        "a973706565645f6d7073cbbff0000000000000ac7374656572696e675f726164cb3ff00000000000"
        "00ae7961775f726174655f7261647073c0"
    ),
    "scan_4": (
        "87a474797065a47363616ea17601a77374616d705f73cb3ff0000000000000a373657100ad616e67"
        "6c655f6d696e5f726164cbc002cccccccccccdb3616e676c655f696e6372656d656e745f726164cb"
        "3f719ce075f6fd22a872616e6765735f6d83a56474797065a33c6634a573686170659104a4646174"
        "61c4100000803f000020400000807f9a99993e"
    ),
    "scan_from_list": (
        "87a474797065a47363616ea17601a77374616d705f73cb3ff0000000000000a373657100ad616e67"
        "6c655f6d696e5f726164cb0000000000000000b3616e676c655f696e6372656d656e745f726164cb"
        "bfb999999999999aa872616e6765735f6d83a56474797065a33c6634a573686170659103a4646174"
        "61c40c0000803f0000204000000000"
    ),
    "scan_1080": (4446, "786f7e6722f0bca5dda7f5cf8562a1af7a3dc85827466d6e57044a5965a47df0"),
    "state": (
        "8ca474797065a57374617465a17601a77374616d705f73cb41d954fc4007e6b4a3736571cf7fffff"
        "ffffffffffa3785f6dcb3ff0000000000000a3795f6dcb4000000000000000a77961775f726164cb"
        "c008000000000000a973706565645f6d7073cb400199999999999aae7961775f726174655f726164"
        "7073cb3fb999999999999aac7374656572696e675f726164cb3fa999999999999aae736f75726365"
        "5f7374616d705f73cb41d954fc40066666a576616c6964c3"
    ),
    "state_invalid": (
        "8ca474797065a57374617465a17601a77374616d705f73cb4000000000000000a373657100a3785f"
        "6dcb0000000000000000a3795f6dcb0000000000000000a77961775f726164cb0000000000000000"
        "a973706565645f6d7073cb0000000000000000ae7961775f726174655f7261647073cb0000000000"
        "000000ac7374656572696e675f726164cb0000000000000000ae736f757263655f7374616d705f73"
        "cb0000000000000000a576616c6964c2"
    ),
    "drive_cmd": (
        "86a474797065a964726976655f636d64a17601a77374616d705f73cb4000000000000000a3736571"
        "29a973706565645f6d7073cb400a666666666666ac7374656572696e675f726164cb3fcae147ae14"
        "7ae1"
    ),
    "drive_cmd_edges": (
        "86a474797065a964726976655f636d64a17601a77374616d705f73cb4202a05f20000000a3736571"
        "cf0000000100000000a973706565645f6d7073cbc049000000000000ac7374656572696e675f7261"
        "64cbbff0000000000000"
    ),
    "plan_2": (
        "de0010a474797065a4706c616ea17601a77374616d705f73cb41d954fc40100000a3736571cf0000"
        "010000000003a7686f72697a6f6e83a56474797065a33c6638a57368617065920304a464617461c4"
        "60000000000000000000000000000000c09a9999999999b93f0000000000002440000000000000e0"
        "3f000000000000e03f333333333333c3bf0000000000002540000000000000f03f00000000000008"
        "409a9999999999d9bf0000000000002640a6696e7075747383a56474797065a33c6638a573686170"
        "65920203a464617461c43000000000000008409a9999999999b93f00000000000008400000000000"
        "0008409a9999999999b93f0000000000000840a46265746183a56474797065a33c6638a573686170"
        "659102a464617461c4109a9999999999c93f9a9999999999e93fa6737461747573a866616c6c6261"
        "636bad736f6c7665725f737461747573af536f6c76655f537563636565646564aa69746572617469"
        "6f6e7307ad736f6c76655f74696d655f6d73cb3fe70a3d70a3d70aa66d6574686f64a663696d7063"
        "63a3735f6dcb4024000000000000a7655f636f6e5f6dcbbfa999999999999aae736f757263655f73"
        "74616d705f73cb41d954fc400ccccdb4636f6e73656375746976655f6661696c7572657301"
    ),
    "plan_10": (990, "b859c4fdc47fe6f64db78c6ea91bd0b3dbf270cf455a054089cd71690e3c89a6"),
    "lap_event": (
        "8aa474797065a96c61705f6576656e74a17601a77374616d705f73cb403e000000000000a3736571"
        "03a46b696e64a36c6170a36c617001aa6c61705f74696d655f73cb4023bd70a3d70a3dae6d65616e"
        "5f73706565645f6d7073cb400b333333333333b06f66665f747261636b5f6576656e747300af6d61"
        "785f6162735f655f636f6e5f6dcb3fbeb851eb851eb8"
    ),
    "lap_event_start": (
        "8aa474797065a96c61705f6576656e74a17601a77374616d705f73cb0000000000000000a3736571"
        "00a46b696e64a57374617274a36c617000aa6c61705f74696d655f73c0ae6d65616e5f7370656564"
        "5f6d7073c0b06f66665f747261636b5f6576656e747300af6d61785f6162735f655f636f6e5f6dc0"
    ),
    "vesc_state": (
        "de001ca474797065aa766573635f7374617465a17601a77374616d705f73cb4008000000000000a3"
        "73657105a6737461747573a26f6baa74656d705f6665745f63cb4041800000000000ac74656d705f"
        "6d6f746f725f63cb4044000000000000b36176675f6d6f746f725f63757272656e745f61cb400999"
        "999999999ab36176675f696e7075745f63757272656e745f61cb3ff199999999999aa86176675f69"
        "645f61c0a86176675f69715f61c0a464757479cb3fc999999999999aa46572706dcb40c770000000"
        "0000a6765f696e5f76cb402799999999999aa9616d705f686f757273cb3fa999999999999ab1616d"
        "705f686f7572735f63686172676564c0aa776174745f686f757273c0b2776174745f686f7572735f"
        "63686172676564c0aa746163686f6d65746572d1fb2eae746163686f6d657465725f616273ceffff"
        "ffffaa6661756c745f636f646500ab7069645f706f735f646567c0ad636f6e74726f6c6c65725f69"
        "64ccffab74656d705f6d6f73315f63c0ab74656d705f6d6f73325f63c0ab74656d705f6d6f73335f"
        "63cbc059000000000000a86176675f76645f76c0a86176675f76715f76c0"
    ),
    "vesc_state_status_only": (
        "de001ca474797065aa766573635f7374617465a17601a77374616d705f73cb4008000000000000a3"
        "73657100a6737461747573ac646973636f6e6e6563746564aa74656d705f6665745f63c0ac74656d"
        "705f6d6f746f725f63c0b36176675f6d6f746f725f63757272656e745f61c0b36176675f696e7075"
        "745f63757272656e745f61c0a86176675f69645f61c0a86176675f69715f61c0a464757479c0a465"
        "72706dc0a6765f696e5f76c0a9616d705f686f757273c0b1616d705f686f7572735f636861726765"
        "64c0aa776174745f686f757273c0b2776174745f686f7572735f63686172676564c0aa746163686f"
        "6d65746572c0ae746163686f6d657465725f616273c0aa6661756c745f636f6465c0ab7069645f70"
        "6f735f646567c0ad636f6e74726f6c6c65725f6964c0ab74656d705f6d6f73315f63c0ab74656d70"
        "5f6d6f73325f63c0ab74656d705f6d6f73335f63c0a86176675f76645f76c0a86176675f76715f76"
        "c0"
    ),
    "sim_truth": (
        "8fa474797065a973696d5f7472757468a17601a77374616d705f73cb4010000000000000a3736571"
        "cd012ca3785f6dcb3ff0000000000000a3795f6dcb3ff0000000000000a77961775f726164cb0000"
        "000000000000a973706565645f6d7073cb4008000000000000ae7961775f726174655f7261647073"
        "cb3fc999999999999aa8736c69705f726164cbc00921fb54442d18ac7374656572696e675f726164"
        "cb3fb999999999999aa3735f6dcb4045000000000000a7655f636f6e5f6dcb3fb999999999999aa9"
        "6f66665f747261636bc3a36c617002"
    ),
    "log_event": (
        "87a474797065a96c6f675f6576656e74a17601a77374616d705f73cb4014000000000000a3736571"
        "06a56c6576656ca77761726e696e67a6736f75726365a7706c616e6e6572a474657874aa736c6f77"
        "20736f6c7665"
    ),
    "log_event_unicode": (
        "87a474797065a96c6f675f6576656e74a17601a77374616d705f73cb4014000000000000a3736571"
        "00a56c6576656ca56572726f72a6736f75726365d980c3bcc3bcc3bcc3bcc3bcc3bcc3bcc3bcc3bc"
        "c3bcc3bcc3bcc3bcc3bcc3bcc3bcc3bcc3bcc3bcc3bcc3bcc3bcc3bcc3bcc3bcc3bcc3bcc3bcc3bc"
        "c3bcc3bcc3bcc3bcc3bcc3bcc3bcc3bcc3bcc3bcc3bcc3bcc3bcc3bcc3bcc3bcc3bcc3bcc3bcc3bc"
        "c3bcc3bcc3bcc3bcc3bcc3bcc3bcc3bcc3bcc3bcc3bcc3bcc3bcc3bcc3bca474657874da013dce94"
        "74203e20313030206d7320e29c930a78787878787878787878787878787878787878787878787878"
        "78787878787878787878787878787878787878787878787878787878787878787878787878787878"
        "78787878787878787878787878787878787878787878787878787878787878787878787878787878"
        "78787878787878787878787878787878787878787878787878787878787878787878787878787878"
        "78787878787878787878787878787878787878787878787878787878787878787878787878787878"
        "78787878787878787878787878787878787878787878787878787878787878787878787878787878"
        "78787878787878787878787878787878787878787878787878787878787878787878787878787878"
        "7878787878787878787878787878787878787878787878787878787878787878787878"
    ),
    "sim_control": (
        "85a474797065ab73696d5f636f6e74726f6ca17601a77374616d705f73cb4018000000000000a373"
        "657100a6616374696f6ea57265736574"
    ),
    "teleport": (
        "88a474797065a874656c65706f7274a17601a77374616d705f73cb401c000000000000a373657109"
        "a3785f6dcbbfd3333333333333a3795f6dcb3ff3333333333333a77961775f726164cb3fb9999999"
        "99999aa973706565645f6d7073cb0000000000000000"
    ),
    "opponents": (301, "3a12436352a874f723c12a9a11de74e4d5167c82d67fae2cede881a0be6f1b70"),
    "opponents_empty": (
        "87a474797065a96f70706f6e656e7473a17601a77374616d705f73cb4020000000000000a3736571"
        "03ae736f757263655f7374616d705f73cb401e000000000000a56672616d65a36d6170a674726163"
        "6b7390"
    ),
}


def _digest(data: bytes) -> tuple[int, str]:
    return len(data), hashlib.sha256(data).hexdigest()


def _matches(data: bytes, golden: str | tuple[int, str]) -> bool:
    if isinstance(golden, str):
        return data.hex() == golden
    return _digest(data) == golden


def test_every_case_has_a_golden_payload() -> None:
    assert set(GOLDEN) == set(CASES)
    kinds = {type(CASES[name]()) for name in CASES}
    assert kinds == set(MESSAGE_TYPES)  # every message type


@pytest.mark.parametrize("name", sorted(CASES))
def test_encoder_reproduces_the_golden_bytes(name: str) -> None:
    msg = CASES[name]()
    data = msg.encode()
    assert _matches(data, GOLDEN[name]), (name, data.hex())
    assert encode(msg) == data
    # encode(seq) is the bytes of the copy with that sequence number
    assert msg.encode(seq=msg.seq) == data
    assert msg.with_seq(msg.seq).encode() == data


@pytest.mark.parametrize("name", sorted(CASES))
def test_golden_bytes_decode_back_identically(name: str) -> None:
    msg = CASES[name]()
    golden = GOLDEN[name]
    data = bytes.fromhex(golden) if isinstance(golden, str) else msg.encode()
    assert _matches(data, golden)
    back = decode(data, type(msg))
    assert type(back) is type(msg) and back == msg
    assert decode_any(data) == msg
    assert back.encode() == data  # and re-encodes to the same bytes
    for name_, value in _values(back).items():  # normalised Python types, read-only arrays
        expect = _values(msg)[name_]
        assert type(value) is type(expect), name_
        if isinstance(value, np.ndarray):
            assert not value.flags.writeable and value.dtype == expect.dtype


def test_payloads_are_plain_msgpack_maps() -> None:
    """Any msgpack library reads them: a string-keyed map, type and v first."""
    for name, make in CASES.items():
        wire = msgpack.unpackb(make().encode(), raw=False)
        assert list(wire)[:4] == ["type", "v", "stamp_s", "seq"], name
        assert wire["v"] == 1


def _values(msg: Message) -> dict[str, object]:
    return {f.name: getattr(msg, f.name) for f in type(msg).fields_info()}
