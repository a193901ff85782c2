"""The gateway's shell on ``shared.bus.fake.FakeBus`` and a fake raw session (no Zenoh)."""

from __future__ import annotations

import math
import os
from collections.abc import Callable
from types import SimpleNamespace
from typing import Any

import numpy as np
import pytest

from services.ros2_gateway import Ros2GatewayService
from services.ros2_gateway.liveliness import parse_token
from services.ros2_gateway.naming import parse_attachment
from services.ros2_gateway.typestore import make_typestore
from shared.bus.fake import FakeBus
from shared.config.ros2 import Ros2Settings
from shared.messages import DriveCmd, Imu, LogEvent, Pose, Scan, State

TS = make_typestore("humble")
#: The gateway's wall clock in these tests: 10 ms after the payloads' stamp [s].
NOW_S = 1_767_225_600.133456789


class FakeSession:
    """The raw part of a Zenoh session the gateway uses: subscribers and publishers."""

    def __init__(self) -> None:
        self.subs: dict[str, Callable[[Any], None]] = {}
        self.sent: dict[str, list[tuple[bytes, bytes | None]]] = {}
        self.tokens: list[str] = []

    def liveliness(self) -> Any:
        def declare_token(key: str) -> Any:
            self.tokens.append(key)
            return SimpleNamespace(undeclare=lambda: self.tokens.remove(key))

        return SimpleNamespace(declare_token=declare_token)

    def declare_subscriber(self, key: str, callback: Callable[[Any], None]) -> Any:
        self.subs[key] = callback
        return SimpleNamespace(undeclare=lambda: None)

    def declare_publisher(self, key: str) -> Any:
        def put(payload: bytes, attachment: bytes | None = None) -> None:
            self.sent.setdefault(key, []).append((bytes(payload), attachment))

        return SimpleNamespace(put=put, undeclare=lambda: None)

    def deliver(self, key: str, payload: bytes) -> None:
        sample = SimpleNamespace(key_expr=key, payload=SimpleNamespace(to_bytes=lambda: payload))
        self.subs[key](sample)


def make(
    topics: list[dict[str, Any]], **kw: Any
) -> tuple[Ros2GatewayService, FakeBus, FakeSession]:
    bus, session = FakeBus("gw"), FakeSession()
    settings = Ros2Settings.model_validate({"topics": topics, **kw})
    svc = Ros2GatewayService(settings, bus, session=session, wall_clock=lambda: NOW_S)  # type: ignore[arg-type]
    return svc, bus, session


def drain(svc: Ros2GatewayService) -> None:
    item = svc.inbox.get()
    while item is not None:
        svc.handle_inbound(*item)
        item = svc.inbox.get()


IN_TOPICS = [
    {
        "topic": "/pf/pose",
        "type": "geometry_msgs/msg/PoseStamped",
        "direction": "in",
        "native": "vehicle/pose",
    },
    {
        "topic": "/imu",
        "type": "sensor_msgs/msg/Imu",
        "direction": "in",
        "native": "vehicle/imu",
        "scheme": "rmw_zenoh",
    },
    {
        "topic": "/scan",
        "type": "sensor_msgs/msg/LaserScan",
        "direction": "in",
        "native": "vehicle/scan",
        "stamp": "receive",
    },
]


def test_inbound_payloads_become_native_records(cdr: SimpleNamespace) -> None:
    svc, bus, session = make(IN_TOPICS)
    imu_key = "0/imu/sensor_msgs::msg::dds_::Imu_/*"
    assert set(session.subs) == {"pf/pose", imu_key, "scan"}
    session.deliver("pf/pose", cdr.pose_stamped(TS, 1.0, 2.0, 0.3))
    session.deliver(imu_key, cdr.imu(TS, 0.5, 1.0, 2.0))
    session.deliver("scan", cdr.scan(TS, [1.0, 2.0, 3.0]))
    drain(svc)
    (pose,) = bus.sent(bus.keys.pose, Pose)
    assert (pose.x_m, pose.y_m) == (1.0, 2.0) and pose.stamp_s == pytest.approx(cdr.STAMP_S)
    (imu,) = bus.sent(bus.keys.imu, Imu)
    assert imu.yaw_rate_radps == 0.5
    (scan,) = bus.sent(bus.keys.scan, Scan)
    assert scan.stamp_s == NOW_S  # stamp = "receive"
    assert scan.ranges_m.tolist() == [1.0, 2.0, 3.0]
    assert bus.drops.total == 0
    assert any("pf/pose" in line for line in svc.ros_keys())


def test_malformed_payloads_are_dropped_and_counted_per_reason(cdr: SimpleNamespace) -> None:
    svc, bus, session = make(IN_TOPICS)
    for payload in (
        os.urandom(50),
        b"\x00\x01\x00\x00" + os.urandom(7),
        cdr.pose_stamped(TS, 1, 2, 3)[:30],
        cdr.imu(TS, 0, 0, 0),
        cdr.pose_stamped(TS, float("nan"), 0, 0),
        cdr.pose_stamped(TS, 1e9, 0, 0),
        b"",
    ):
        session.deliver("pf/pose", payload)
    drain(svc)
    assert bus.sent(bus.keys.pose, Pose) == []
    counts = bus.drops.snapshot()
    reasons = {r for (k, r) in counts if k == "pf/pose"}
    assert {"not_cdr", "bad_cdr", "size_mismatch", "not_finite", "out_of_range"} <= reasons
    assert sum(counts.values()) == 7
    session.deliver("pf/pose", cdr.pose_stamped(TS, 1, 2, 3))  # and it goes on
    drain(svc)
    assert len(bus.sent(bus.keys.pose, Pose)) == 1


def test_a_full_inbox_drops_the_oldest(cdr: SimpleNamespace) -> None:
    svc, bus, session = make(IN_TOPICS[:1], queue_size=2)
    for i in range(5):
        session.deliver("pf/pose", cdr.pose_stamped(TS, float(i), 0, 0))
    drain(svc)
    assert [p.x_m for p in bus.sent(bus.keys.pose, Pose)] == [3.0, 4.0]
    assert svc.diagnostics()["inbox_dropped"] == 3


def test_outbound_records_become_cdr_with_the_attachment_under_rmw_zenoh() -> None:
    svc, bus, session = make(
        [
            {
                "topic": "/odom",
                "type": "nav_msgs/msg/Odometry",
                "direction": "out",
                "native": "state",
            },
            {
                "topic": "/drive",
                "type": "ackermann_msgs/msg/AckermannDriveStamped",
                "direction": "out",
                "native": "cmd/drive",
                "scheme": "rmw_zenoh",
                "frame_id": "base_link",
            },
        ]
    )
    state = State(
        stamp_s=1.7e9,
        x_m=1.0,
        y_m=2.0,
        yaw_rad=0.5,
        speed_mps=2.0,
        yaw_rate_radps=0.1,
        steering_rad=0.0,
        source_stamp_s=1.7e9,
        valid=True,
    )
    bus.deliver(bus.keys.state, state)
    for k in range(2):
        bus.deliver(
            bus.keys.drive_cmd, DriveCmd(stamp_s=1.7e9 + k, speed_mps=1.5, steering_rad=0.2)
        )
    assert svc.pump_outbound() == 3
    ((payload, att),) = session.sent["odom"]
    assert att is None
    odo = TS.deserialize_cdr(payload, "nav_msgs/msg/Odometry")
    assert odo.pose.pose.position.x == 1.0 and odo.twist.twist.linear.x == 2.0
    key = "0/drive/ackermann_msgs::msg::dds_::AckermannDriveStamped_/TypeHashNotSupported"
    sent = session.sent[key]
    atts = [parse_attachment(a) for _, a in sent if a is not None]
    assert [a.sequence for a in atts if a] == [1, 2]
    assert all(a is not None and a.source_time_ns == int(NOW_S * 1e9) for a in atts)
    ack = TS.deserialize_cdr(sent[0][0], "ackermann_msgs/msg/AckermannDriveStamped")
    assert ack.drive.speed == 1.5 and np.isclose(ack.drive.steering_angle, 0.2)
    assert svc.pump_outbound() == 0  # each record once


def _state(valid: bool, x: float = 1.0) -> State:
    return State(
        stamp_s=NOW_S,
        x_m=x,
        y_m=2.0,
        yaw_rad=0.5,
        speed_mps=2.0,
        yaw_rate_radps=0.1,
        steering_rad=0.0,
        source_stamp_s=NOW_S,
        valid=valid,
    )


def test_an_invalid_state_is_not_published_on_odom() -> None:
    """While the bridge's ``state.valid`` is false (the car is lost) /odom is silent: no
    frozen last pose at 100 Hz; the skips are counted."""
    svc, bus, session = make([], defaults=["/odom"])
    for valid, x in ((True, 1.0), (False, 9.0), (False, 9.0), (True, 3.0)):
        bus.deliver(bus.keys.state, _state(valid, x))
    assert svc.pump_outbound() == 2
    xs = [TS.deserialize_cdr(p, "nav_msgs/msg/Odometry").pose.pose.position.x
          for p, _ in session.sent["odom"]]
    assert xs == [1.0, 3.0]
    assert svc.diagnostics()["out.odom.skipped_invalid"] == 2


def test_badly_stamped_and_headless_poses_are_dropped_counted_and_reported(
    cdr: SimpleNamespace,
) -> None:
    """1970, an hour ahead, a minute old, a zero and a NaN quaternion: each dropped with its
    reason and said on events/log by the drop reporter; a pose 10 ms old and a quaternion
    of norm 2 (normalised) pass."""
    svc, bus, session = make(IN_TOPICS[:1])
    t = TS.types

    def pose_q(x: float, y: float, z: float, w: float) -> bytes:
        msg = t["geometry_msgs/msg/PoseStamped"](
            header=t["std_msgs/msg/Header"](
                stamp=t["builtin_interfaces/msg/Time"](sec=1_767_225_600, nanosec=123456789),
                frame_id="map",
            ),
            pose=t["geometry_msgs/msg/Pose"](
                position=t["geometry_msgs/msg/Point"](x=1.0, y=2.0, z=0.0),
                orientation=t["geometry_msgs/msg/Quaternion"](x=x, y=y, z=z, w=w),
            ),
        )
        return bytes(TS.serialize_cdr(msg, "geometry_msgs/msg/PoseStamped"))

    for payload in (
        cdr.pose_stamped(TS, 1.0, 2.0, 0.3, stamp_s=1.0),  # 1970
        cdr.pose_stamped(TS, 1.0, 2.0, 0.3, stamp_s=NOW_S + 3600.0),
        cdr.pose_stamped(TS, 1.0, 2.0, 0.3, stamp_s=NOW_S - 60.0),
        pose_q(0.0, 0.0, 0.0, 0.0),
        pose_q(0.0, 0.0, float("nan"), 1.0),
    ):
        session.deliver("pf/pose", payload)
    drain(svc)
    assert bus.sent(bus.keys.pose, Pose) == []
    counts = bus.drops.snapshot()
    assert counts == {
        ("pf/pose", "stale_stamp"): 2,
        ("pf/pose", "future_stamp"): 1,
        ("pf/pose", "bad_quaternion"): 2,
    }
    svc.poll()
    logs = [e.text for e in bus.sent(bus.keys.events_log, LogEvent)]
    assert any("pf/pose stale_stamp x2" in x and "bad_quaternion x2" in x for x in logs), logs
    session.deliver("pf/pose", pose_q(0.0, 0.0, 2.0 * math.sin(0.2), 2.0 * math.cos(0.2)))
    session.deliver("pf/pose", cdr.pose_stamped(TS, 1.0, 2.0, 0.3))
    drain(svc)
    poses = bus.sent(bus.keys.pose, Pose)
    assert [round(p.yaw_rad, 9) for p in poses] == [0.4, 0.3]


def test_rmw_zenoh_topics_get_the_graph_tokens_of_one_node() -> None:
    """A node token and one MP / MS token per rmw_zenoh topic, in rmw_zenoh's format, with
    the ROS names, DDS types and the data key's hash; bridge_ros2dds topics get none."""
    svc, _bus, session = make(IN_TOPICS, scheme="bridge_ros2dds", node_name="gw", domain_id=3)
    (node, imu) = [parse_token(k) for k in session.tokens]
    assert node is not None and imu is not None
    assert (node.kind, node.node, node.namespace, node.enclave, node.domain_id) == (
        "NN", "gw", "/", "/", 3,
    )
    assert (imu.kind, imu.topic, imu.dds_type, imu.type_hash) == (
        "MS", "/imu", "sensor_msgs::msg::dds_::Imu_", "TypeHashNotSupported",
    )
    assert imu.zid == node.zid and imu.eid != node.eid
    svc, _bus, session = make([], scheme="rmw_zenoh", distro="jazzy")
    tokens = [parse_token(k) for k in session.tokens]
    assert [(t.kind, t.topic) for t in tokens if t] == [
        ("NN", None), ("MP", "/odom"), ("MP", "/plan"), ("MP", "/drive"),
    ]
    ts = make_typestore("jazzy")
    odom = tokens[1]
    assert odom is not None and odom.type_hash == ts.hash_rihs01("nav_msgs/msg/Odometry")
    assert odom.qos == "1:2:1,10:,:,:,,"
    # the data key's chunks are the token's (a subscriber built from the token finds it)
    assert svc.outbound[0].key == f"0/odom/{odom.dds_type}/{odom.type_hash}"
    svc, _bus, session = make([], scheme="bridge_ros2dds")
    assert session.tokens == []
