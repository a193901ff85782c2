"""The gateway's pure parts: key naming, the rmw_zenoh attachment, CDR in and out, the
conversions and the ``[ros2]`` settings (no Zenoh, no processes)."""

from __future__ import annotations

import math
import os
import re
import struct
import tomllib
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
from pydantic import ValidationError

from services.ros2_gateway.convert import (
    CdrError,
    decode_cdr,
    encode_cdr,
    stamp_from_s,
    stamp_to_s,
    to_native,
    to_ros,
    yaw_of,
)
from services.ros2_gateway.naming import (
    HUMBLE_TYPE_HASH,
    Attachment,
    dds_type_name,
    parse_attachment,
    zenoh_key,
)
from services.ros2_gateway.typestore import make_typestore
from shared.config import config_from_dict
from shared.config.ros2 import Ros2Settings, Ros2Topic
from shared.messages import DriveCmd, Imu, Odom, Plan, Pose, Scan, State

TS = make_typestore("humble")
#: The stamp of the payloads (``conftest.STAMP_S``) [s].
STAMP_S = 1_767_225_600.123456789


def topic(**kw: object) -> Ros2Topic:
    return Ros2Topic.model_validate(kw)


# --------------------------------------------------------------------------- naming
def test_bridge_ros2dds_keys_are_the_topic_without_its_slash() -> None:
    s = Ros2Settings()
    t = topic(
        topic="/pf/pose",
        type="geometry_msgs/msg/PoseStamped",
        direction="in",
        native="vehicle/pose",
    )
    assert zenoh_key(t, s, TS) == "pf/pose"
    assert zenoh_key(s.topics[0], s, TS) == "odom"  # the default /odom out


def test_rmw_zenoh_keys_carry_domain_type_and_hash() -> None:
    assert dds_type_name("nav_msgs/msg/Odometry") == "nav_msgs::msg::dds_::Odometry_"
    out = topic(
        topic="/odom",
        type="nav_msgs/msg/Odometry",
        direction="out",
        native="state",
        scheme="rmw_zenoh",
    )
    humble = Ros2Settings(domain_id=7)
    assert zenoh_key(out, humble, TS) == (
        f"7/odom/nav_msgs::msg::dds_::Odometry_/{HUMBLE_TYPE_HASH}"
    )
    jazzy = Ros2Settings(distro="jazzy")
    key = zenoh_key(out, jazzy, make_typestore("jazzy"))
    assert key.startswith("0/odom/nav_msgs::msg::dds_::Odometry_/RIHS01_") and len(key) > 80
    inbound = topic(
        topic="/car/imu",
        type="sensor_msgs/msg/Imu",
        direction="in",
        native="vehicle/imu",
        scheme="rmw_zenoh",
    )
    assert zenoh_key(inbound, jazzy, TS) == "0/car/imu/sensor_msgs::msg::dds_::Imu_/*"
    explicit = topic(
        topic="/x",
        type="sensor_msgs/msg/Imu",
        direction="in",
        native="vehicle/imu",
        key="robot/**/imu",
    )
    assert zenoh_key(explicit, jazzy, TS) == "robot/**/imu"


def test_rihs01_of_a_known_type() -> None:
    # the REP-2016 hash rmw_zenoh puts in std_msgs/String keys on jazzy
    assert make_typestore("jazzy").hash_rihs01("std_msgs/msg/String") == (
        "RIHS01_df668c740482bbd48fb39d76a70dfd4bd59db1288021743503259e948f6b1a18"
    )


def test_attachment_layout() -> None:
    gid = bytes(range(16))
    a = Attachment(sequence=3, source_time_ns=1_700_000_000_123_456_789, gid=gid)
    raw = a.encode()
    assert len(raw) == 33
    assert raw[:8] == struct.pack("<q", 3) and raw[8:16] == struct.pack("<q", a.source_time_ns)
    assert raw[16] == 16 and raw[17:] == gid
    assert parse_attachment(raw) == a
    assert parse_attachment(raw[:-1]) is None
    with pytest.raises(ValueError):
        Attachment(1, 0, b"short").encode()


# --------------------------------------------------------------------------- stamps
def test_stamps_round_trip() -> None:
    st = stamp_from_s(TS, STAMP_S)
    assert st.sec == int(STAMP_S) and 0 <= st.nanosec < 10**9
    assert stamp_to_s(st) == pytest.approx(STAMP_S, abs=1e-9)
    carry = stamp_from_s(TS, 12.9999999999)
    assert (carry.sec, carry.nanosec) == (13, 0)
    bad = TS.types["builtin_interfaces/msg/Time"](sec=1, nanosec=10**9)
    with pytest.raises(CdrError) as err:
        stamp_to_s(bad)
    assert err.value.reason == "bad_stamp"


# --------------------------------------------------------------------------- inbound
def _in(ros_type: str, native: str, **kw: object) -> Ros2Topic:
    return topic(topic="/x", type=ros_type, direction="in", native=native, **kw)


def test_pose_stamped_to_pose(cdr: SimpleNamespace) -> None:
    payload = cdr.pose_stamped(TS, 1.5, -2.0, 0.75)
    rec = to_native(
        decode_cdr(TS, payload, "geometry_msgs/msg/PoseStamped"),
        _in("geometry_msgs/msg/PoseStamped", "vehicle/pose"),
        wheelbase_m=0.33,
    )
    assert isinstance(rec, Pose)
    assert (rec.x_m, rec.y_m) == (1.5, -2.0) and rec.yaw_rad == pytest.approx(0.75)
    assert rec.stamp_s == pytest.approx(STAMP_S, abs=1e-9) and rec.cov is None


def test_pose_with_covariance_takes_the_x_y_yaw_block(cdr: SimpleNamespace) -> None:
    payload = cdr.pose_cov(TS, 1.0, 2.0, -3.0, var=(0.01, 0.02, 0.03))
    t = _in("geometry_msgs/msg/PoseWithCovarianceStamped", "vehicle/pose")
    rec = to_native(decode_cdr(TS, payload, t.type), t, wheelbase_m=0.33)
    assert isinstance(rec, Pose) and rec.yaw_rad == pytest.approx(-3.0)
    assert rec.cov is not None and np.diag(rec.cov) == pytest.approx([0.01, 0.02, 0.03])
    zero = to_native(
        decode_cdr(TS, cdr.pose_cov(TS, 1, 2, 0, var=(0, 0, 0)), t.type), t, wheelbase_m=0.33
    )
    assert isinstance(zero, Pose) and zero.cov is None  # all zeros: unknown
    neg = to_native(
        decode_cdr(TS, cdr.pose_cov(TS, 1, 2, 0, var=(-1, 0, 0)), t.type), t, wheelbase_m=0.33
    )
    assert isinstance(neg, Pose) and neg.cov is None


def test_odometry_to_odom_and_to_pose(cdr: SimpleNamespace) -> None:
    payload = cdr.odometry(TS, 3.0, 4.0, 0.5, v=2.0, r=1.0)
    t = _in("nav_msgs/msg/Odometry", "vehicle/odom")
    odom = to_native(decode_cdr(TS, payload, t.type), t, wheelbase_m=0.33)
    assert isinstance(odom, Odom)
    assert odom.speed_mps == 2.0 and odom.yaw_rate_radps == 1.0
    assert odom.steering_rad == pytest.approx(math.atan(0.33 * 1.0 / 2.0))
    still = cdr.odometry(TS, 0, 0, 0, v=0.0, r=0.3)
    assert to_native(decode_cdr(TS, still, t.type), t, wheelbase_m=0.33).steering_rad == 0.0
    tp = _in("nav_msgs/msg/Odometry", "vehicle/pose")
    pose = to_native(decode_cdr(TS, payload, tp.type), tp, wheelbase_m=0.33)
    assert isinstance(pose, Pose) and (pose.x_m, pose.y_m) == (3.0, 4.0)


def test_imu_and_scan(cdr: SimpleNamespace) -> None:
    t = _in("sensor_msgs/msg/Imu", "vehicle/imu")
    imu = to_native(decode_cdr(TS, cdr.imu(TS, 0.4, 1.0, -2.0), t.type), t, wheelbase_m=0.33)
    assert isinstance(imu, Imu) and (imu.yaw_rate_radps, imu.ax_mps2, imu.ay_mps2) == (
        pytest.approx(0.4),
        1.0,
        -2.0,
    )
    ranges = [1.0, float("nan"), 50.0, 0.01, float("inf"), 2.5]
    ts = _in("sensor_msgs/msg/LaserScan", "vehicle/scan")
    scan = to_native(decode_cdr(TS, cdr.scan(TS, ranges), ts.type), ts, wheelbase_m=0.33)
    assert isinstance(scan, Scan) and scan.ranges_m.dtype == np.float32
    assert scan.ranges_m.tolist() == [1.0, math.inf, math.inf, math.inf, math.inf, 2.5]
    assert scan.angle_min_rad == pytest.approx(-2.35) and scan.angle_increment_rad > 0


def test_receive_stamp_replaces_the_header(cdr: SimpleNamespace) -> None:
    t = _in("sensor_msgs/msg/Imu", "vehicle/imu", stamp="receive")
    rec = to_native(
        decode_cdr(TS, cdr.imu(TS, 0, 0, 0), t.type), t, wheelbase_m=0.33, receive_s=1234.5
    )
    assert rec.stamp_s == 1234.5


# --------------------------------------------------------------------------- malformed
def test_malformed_cdr_raises_cdr_error_with_a_reason(cdr: SimpleNamespace) -> None:
    good = cdr.pose_stamped(TS, 1, 2, 3)
    cases = [
        (b"", "not_cdr"),
        (b"\x07\x07garbage!", "not_cdr"),
        (b"\x00\x01\x00\x00" + os.urandom(9), "bad_cdr"),
        (good[:-9], "bad_cdr"),  # truncated
        (cdr.imu(TS, 0, 0, 0), "size_mismatch"),  # an Imu on a PoseStamped key
        (good + bytes(16), "size_mismatch"),  # bytes left over
    ]
    for payload, reason in cases:
        with pytest.raises(CdrError) as err:
            decode_cdr(TS, payload, "geometry_msgs/msg/PoseStamped")
        assert err.value.reason == reason, (payload[:16], err.value)


def test_random_bytes_never_raise_anything_but_cdr_error(cdr: SimpleNamespace) -> None:
    rng = np.random.default_rng(14)
    types = [
        "geometry_msgs/msg/PoseStamped",
        "geometry_msgs/msg/PoseWithCovarianceStamped",
        "nav_msgs/msg/Odometry",
        "sensor_msgs/msg/Imu",
        "sensor_msgs/msg/LaserScan",
    ]
    good = cdr.scan(TS, [1.0] * 50)
    for i in range(400):
        n = int(rng.integers(0, 300))
        body = rng.bytes(n)
        payload = (b"\x00\x01\x00\x00" + body) if i % 2 else body
        if i % 5 == 0:  # a real header with a corrupted body
            cut = int(rng.integers(4, len(good)))
            payload = good[:cut] + rng.bytes(int(rng.integers(0, 40)))
        for t in types:
            try:
                decode_cdr(TS, payload, t)
            except CdrError:
                pass


def test_values_beyond_the_contract_are_message_errors(cdr: SimpleNamespace) -> None:
    from shared.messages import MessageError

    t = _in("sensor_msgs/msg/Imu", "vehicle/imu")
    with pytest.raises(MessageError):
        to_native(decode_cdr(TS, cdr.imu(TS, math.nan, 0, 0), t.type), t, wheelbase_m=0.33)
    tp = _in("geometry_msgs/msg/PoseStamped", "vehicle/pose")
    with pytest.raises(MessageError):
        to_native(decode_cdr(TS, cdr.pose_stamped(TS, 1e9, 0, 0), tp.type), tp, wheelbase_m=0.33)


# --------------------------------------------------------------------------- outbound
def _out(ros_type: str, native: str, **kw: object) -> Ros2Topic:
    return topic(topic="/y", type=ros_type, direction="out", native=native, **kw)


def test_state_to_odometry_decodes_back() -> None:
    state = State(
        stamp_s=STAMP_S,
        x_m=1.0,
        y_m=-2.0,
        yaw_rad=2.5,
        speed_mps=3.0,
        yaw_rate_radps=-0.5,
        steering_rad=0.1,
        source_stamp_s=STAMP_S,
        valid=True,
    )
    t = _out("nav_msgs/msg/Odometry", "state", frame_id="map", child_frame_id="base_link")
    raw = encode_cdr(TS, to_ros(TS, state, t), t.type)
    back = TS.deserialize_cdr(raw, t.type)
    assert back.header.frame_id == "map" and back.child_frame_id == "base_link"
    assert stamp_to_s(back.header.stamp) == pytest.approx(STAMP_S, abs=1e-9)
    p = back.pose.pose
    assert (p.position.x, p.position.y) == (1.0, -2.0) and yaw_of(p.orientation) == pytest.approx(
        2.5
    )
    assert back.twist.twist.linear.x == 3.0 and back.twist.twist.angular.z == -0.5


def test_plan_to_path_and_drive_to_ackermann() -> None:
    n = 10
    horizon = np.column_stack(
        [np.arange(n + 1.0), -np.arange(n + 1.0), np.linspace(0, 1, n + 1), np.arange(n + 1.0)]
    )
    plan = Plan(
        stamp_s=STAMP_S,
        horizon=horizon,
        inputs=np.zeros((n, 3)),
        beta=np.zeros(n),
        status="solved",
        solver_status="ok",
        iterations=3,
        solve_time_ms=0.7,
        method="cimpcc",
        s_m=0.0,
        e_con_m=0.0,
        source_stamp_s=STAMP_S,
        consecutive_failures=0,
    )
    t = _out("nav_msgs/msg/Path", "planner/plan")
    path = TS.deserialize_cdr(encode_cdr(TS, to_ros(TS, plan, t), t.type), t.type)
    assert len(path.poses) == n + 1 and path.header.frame_id == "map"
    last = path.poses[-1].pose
    assert (last.position.x, last.position.y) == (10.0, -10.0)
    assert yaw_of(last.orientation) == pytest.approx(1.0)
    cmd = DriveCmd(stamp_s=STAMP_S, speed_mps=3.25, steering_rad=-0.2)
    ta = _out("ackermann_msgs/msg/AckermannDriveStamped", "cmd/drive", frame_id="base_link")
    ack = TS.deserialize_cdr(encode_cdr(TS, to_ros(TS, cmd, ta), ta.type), ta.type)
    assert ack.drive.speed == 3.25 and ack.drive.steering_angle == pytest.approx(-0.2)
    assert ack.header.frame_id == "base_link"
    # float32 x5 after the header: the layout the F1TENTH VESC stack reads
    assert len(TS.fielddefs["ackermann_msgs/msg/AckermannDrive"][1]) == 5


# --------------------------------------------------------------------------- settings
def test_settings_defaults_and_validation() -> None:
    s = Ros2Settings()
    assert [(t.topic, t.direction, t.native) for t in s.topics] == [
        ("/odom", "out", "state"),
        ("/plan", "out", "planner/plan"),
        ("/drive", "out", "cmd/drive"),
    ]
    with pytest.raises(ValidationError, match="no inbound conversion"):
        _in("sensor_msgs/msg/LaserScan", "vehicle/pose")
    with pytest.raises(ValidationError, match="no outbound conversion"):
        _out("nav_msgs/msg/Path", "state")
    with pytest.raises(ValidationError):
        topic(topic="not a topic", type="sensor_msgs/msg/Imu", direction="in", native="vehicle/imu")
    with pytest.raises(ValidationError, match="twice"):
        Ros2Settings(topics=(s.topics[0], s.topics[0]))
    odom_in = topic(
        topic="odom", type="nav_msgs/msg/Odometry", direction="in", native="vehicle/odom"
    )
    with pytest.raises(ValidationError, match="read back"):
        Ros2Settings(topics=(s.topics[0], odom_in))
    cfg = config_from_dict(
        {
            "ros2": {
                "scheme": "rmw_zenoh",
                "distro": "jazzy",
                "topics": [
                    {
                        "topic": "/pf/pose",
                        "type": "geometry_msgs/msg/PoseStamped",
                        "direction": "in",
                        "native": "vehicle/pose",
                    }
                ],
            }
        }
    )
    assert cfg.ros2.topics[0].topic == "/pf/pose"
    with pytest.raises(ValueError, match="unknown key"):
        config_from_dict({"ros2": {"topcs": []}})


def _readme_ros2_example() -> str:
    """The README's ``[ros2]`` example (the toml block with the inbound /pf/pose), verbatim."""
    readme = (Path(__file__).resolve().parents[2] / "README.md").read_text(encoding="utf-8")
    blocks = re.findall(r"```toml\n(.*?)```", readme, flags=re.S)
    (block,) = [b for b in blocks if "[[ros2.topics]]" in b and '"/pf/pose"' in b]
    return block


def test_the_readme_inbound_example_keeps_the_outbound_defaults() -> None:
    cfg = config_from_dict(tomllib.loads(_readme_ros2_example()))
    got = [(t.topic, t.direction, t.native, t.frame_id) for t in cfg.ros2.topics]
    assert got == [
        ("/pf/pose", "in", "vehicle/pose", "map"),
        ("/odom", "out", "state", "map"),
        ("/plan", "out", "planner/plan", "map"),
        ("/drive", "out", "cmd/drive", "base_link"),
    ]


def test_an_entry_replaces_the_default_of_its_name_and_defaults_can_be_disabled() -> None:
    drive_ns = {"topic": "/drive", "type": "ackermann_msgs/msg/AckermannDriveStamped",
                "direction": "out", "native": "cmd/drive", "scheme": "rmw_zenoh"}
    s = Ros2Settings.model_validate({"topics": [drive_ns]})
    assert [(t.topic, t.scheme) for t in s.topics] == [
        ("/drive", "rmw_zenoh"), ("/odom", None), ("/plan", None),
    ]
    assert s.topics[0].frame_id == "base_link"  # the per-native default frame
    odom_in = {"topic": "odom", "type": "nav_msgs/msg/Odometry", "direction": "in",
               "native": "vehicle/odom"}  # same ROS name: replaces the outbound /odom
    s = Ros2Settings.model_validate({"topics": [odom_in]})
    assert [(t.topic, t.direction) for t in s.topics] == [
        ("odom", "in"), ("/plan", "out"), ("/drive", "out"),
    ]
    by_key = {"topic": "/car/odom", "key": "plan", "type": "nav_msgs/msg/Odometry",
              "direction": "out", "native": "state"}  # same key as /plan: replaces it
    s = Ros2Settings.model_validate({"topics": [by_key]})
    assert [t.topic for t in s.topics] == ["/car/odom", "/odom", "/drive"]
    assert [t.topic for t in Ros2Settings(defaults=()).topics] == []
    assert [t.topic for t in Ros2Settings(defaults=("/plan",)).topics] == ["/plan"]
    with pytest.raises(ValidationError):
        Ros2Settings.model_validate({"defaults": ["/scan"]})
    # a dumped configuration loads back to the same settings (defaults not doubled)
    s = Ros2Settings.model_validate({"topics": [odom_in]})
    assert Ros2Settings.model_validate(s.model_dump()) == s
    # an explicit frame stays; the plan's frame is configurable too
    s = Ros2Settings.model_validate({"topics": [{**drive_ns, "frame_id": "laser"}]})
    assert s.topics[0].frame_id == "laser"
