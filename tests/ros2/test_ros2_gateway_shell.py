"""The gateway's shell on ``shared.bus.fake.FakeBus`` and a fake raw session (no Zenoh)."""

from __future__ import annotations

import os
from collections.abc import Callable
from types import SimpleNamespace
from typing import Any

import numpy as np
import pytest

from services.ros2_gateway import Ros2GatewayService
from services.ros2_gateway.naming import parse_attachment
from services.ros2_gateway.typestore import make_typestore
from shared.bus.fake import FakeBus
from shared.config.ros2 import Ros2Settings
from shared.messages import DriveCmd, Imu, Pose, Scan, State

TS = make_typestore("humble")


class FakeSession:
    """The raw part of a Zenoh session the gateway uses: subscribers and publishers."""

    def __init__(self) -> None:
        self.subs: dict[str, Callable[[Any], None]] = {}
        self.sent: dict[str, list[tuple[bytes, bytes | None]]] = {}

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
    svc = Ros2GatewayService(settings, bus, session=session, wall_clock=lambda: 1.7e9)  # type: ignore[arg-type]
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
    assert scan.stamp_s == 1.7e9  # stamp = "receive"
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
    assert all(a is not None and a.source_time_ns == 1_700_000_000_000_000_000 for a in atts)
    ack = TS.deserialize_cdr(sent[0][0], "ackermann_msgs/msg/AckermannDriveStamped")
    assert ack.drive.speed == 1.5 and np.isclose(ack.drive.steering_angle, 0.2)
    assert svc.pump_outbound() == 0  # each record once
