"""The ros2_gateway as a REAL process beside two localization bridges, over loopback Zenoh.

Car ``rosa``'s bridge gets native msgpack records; car ``rosb``'s bridge gets what the
gateway makes of the same readings sent as ROS 2 CDR (built with rosbags) on the configured
keys: PoseStamped, Odometry, Imu (rmw_zenoh keys), PoseWithCovarianceStamped and LaserScan
(checked on the gateway's own output). Both bridges must publish the same state. The
gateway's outbound topics (the bridge's ``state`` as nav_msgs/Odometry, a Plan as
nav_msgs/Path, a DriveCmd as ackermann_msgs/AckermannDriveStamped with rmw_zenoh's
attachment) must decode with rosbags to the records' values. Malformed CDR (random bytes,
truncated, wrong type) is dropped, counted and reported on ``events/log``; the gateway lives
on. Every process is stopped by PID with a timeout in a ``finally``.
"""

from __future__ import annotations

import math
import os
import threading
import time
from collections.abc import Callable, Iterator
from types import SimpleNamespace
from typing import Any

import numpy as np
import pytest

from services.ros2_gateway.convert import stamp_to_s, yaw_of
from services.ros2_gateway.naming import HUMBLE_TYPE_HASH, parse_attachment
from services.ros2_gateway.typestore import make_typestore
from services.tools.launcher.supervisor import Supervisor, service_argv
from shared.bus import Bus
from shared.config import load_config
from shared.keys import Keys
from shared.messages import DriveCmd, Imu, LogEvent, Odom, Plan, Pose, Scan, State
from shared.net import free_loopback_port

pytestmark = pytest.mark.slow
TS = make_typestore("humble")
START_TIMEOUT_S = 120.0
WAIT_S = 10.0
RATE_HZ = 40.0
#: The car's reading both bridges get (a car standing still at a pose off the origin).
X, Y, YAW = 2.5, -1.25, 0.8

KEY_POSE = "pf/pose"
KEY_ODOM_IN = "vesc/odom"
KEY_IMU = "0/sensors/imu/sensor_msgs::msg::dds_::Imu_/TypeHashNotSupported"
KEY_POSE_COV = "amcl_pose"
KEY_SCAN = "scan"
KEY_ODOM_OUT = "odom"
KEY_PATH = f"0/plan/nav_msgs::msg::dds_::Path_/{HUMBLE_TYPE_HASH}"
KEY_DRIVE = f"0/drive/ackermann_msgs::msg::dds_::AckermannDriveStamped_/{HUMBLE_TYPE_HASH}"

GATEWAY_TOML = """
[ros2]
scheme = "bridge_ros2dds"

[[ros2.topics]]
topic = "/pf/pose"
type = "geometry_msgs/msg/PoseStamped"
direction = "in"
native = "vehicle/pose"

[[ros2.topics]]
topic = "/vesc/odom"
type = "nav_msgs/msg/Odometry"
direction = "in"
native = "vehicle/odom"

[[ros2.topics]]
topic = "/sensors/imu"
type = "sensor_msgs/msg/Imu"
direction = "in"
native = "vehicle/imu"
scheme = "rmw_zenoh"

[[ros2.topics]]
topic = "/scan"
type = "sensor_msgs/msg/LaserScan"
direction = "in"
native = "vehicle/scan"

[[ros2.topics]]
topic = "/odom"
type = "nav_msgs/msg/Odometry"
direction = "out"
native = "state"

[[ros2.topics]]
topic = "/plan"
type = "nav_msgs/msg/Path"
direction = "out"
native = "planner/plan"
scheme = "rmw_zenoh"

[[ros2.topics]]
topic = "/drive"
type = "ackermann_msgs/msg/AckermannDriveStamped"
direction = "out"
native = "cmd/drive"
scheme = "rmw_zenoh"
frame_id = "base_link"
"""

#: A second gateway for the pose with covariance (one pose source per bridge).
COV_TOML = """
[ros2]
[[ros2.topics]]
topic = "/amcl_pose"
type = "geometry_msgs/msg/PoseWithCovarianceStamped"
direction = "in"
native = "vehicle/pose"
"""


class Collector:
    """Raw samples per key and typed records, gathered by callbacks (which only append)."""

    def __init__(self) -> None:
        self.lock = threading.Lock()
        self.items: dict[str, list[Any]] = {}

    def add(self, name: str, item: Any) -> None:
        with self.lock:
            lst = self.items.setdefault(name, [])
            lst.append(item)
            del lst[:-4000]

    def get(self, name: str) -> list[Any]:
        with self.lock:
            return list(self.items.get(name, []))

    def clear(self, name: str) -> None:
        with self.lock:
            self.items.pop(name, None)


def until(cond: Callable[[], bool], timeout_s: float = WAIT_S) -> bool:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if cond():
            return True
        time.sleep(0.02)
    return cond()


@pytest.fixture(scope="module")
def rig(tmp_path_factory: pytest.TempPathFactory) -> Iterator[SimpleNamespace]:
    tmp = tmp_path_factory.mktemp("ros2-gateway")
    port = free_loopback_port()
    bus_block = f'listen = ["tcp/127.0.0.1:{port}"]\n'
    tomls = {
        "a": tmp / "a.toml",
        "b": tmp / "b.toml",
        "c": tmp / "c.toml",
    }
    tomls["a"].write_text(f'[bus]\ncar = "rosa"\n{bus_block}', encoding="utf-8")
    tomls["b"].write_text(f'[bus]\ncar = "rosb"\n{bus_block}{GATEWAY_TOML}', encoding="utf-8")
    tomls["c"].write_text(f'[bus]\ncar = "rosc"\n{bus_block}{COV_TOML}', encoding="utf-8")
    cfg = load_config(tomls["a"])
    sup = Supervisor(log_dir=tmp / "logs")
    got = Collector()
    with Bus(cfg.bus, "test", listen_default=True, mode="router") as hub:
        ka, kb, kc = Keys("rosa"), Keys("rosb"), Keys("rosc")
        session = hub.session

        def raw(name: str) -> Callable[[Any], None]:
            def cb(sample: Any) -> None:
                att = sample.attachment
                got.add(name, (sample.payload.to_bytes(), None if att is None else att.to_bytes()))

            return cb

        subs = [session.declare_subscriber(k, raw(k)) for k in (KEY_ODOM_OUT, KEY_PATH, KEY_DRIVE)]
        for car, keys in (("a", ka), ("b", kb), ("c", kc)):
            hub.subscribe(keys.state, State, callback=lambda m, c=car: got.add(f"state.{c}", m))
        hub.subscribe(kb.pose, Pose, callback=lambda m: got.add("pose.b", m))
        hub.subscribe(kb.odom, Odom, callback=lambda m: got.add("odom.b", m))
        hub.subscribe(kb.imu, Imu, callback=lambda m: got.add("imu.b", m))
        hub.subscribe(kb.scan, Scan, callback=lambda m: got.add("scan.b", m))
        hub.subscribe(kc.pose, Pose, callback=lambda m: got.add("pose.c", m))
        hub.subscribe(kb.events_log, LogEvent, callback=lambda m: got.add("log.b", m))
        pubs = SimpleNamespace(
            pose=hub.publisher(ka.pose, Pose),
            odom=hub.publisher(ka.odom, Odom),
            imu=hub.publisher(ka.imu, Imu),
            plan=hub.publisher(kb.plan, Plan),
            drive=hub.publisher(kb.drive_cmd, DriveCmd),
        )
        try:
            sup.start("bridge_a", service_argv("localization_bridge", str(tomls["a"])))
            sup.start("bridge_b", service_argv("localization_bridge", str(tomls["b"])))
            sup.start("gateway_b", service_argv("ros2_gateway", str(tomls["b"])))
            sup.start("gateway_c", service_argv("ros2_gateway", str(tomls["c"])))

            ok = sup.wait_until(_alive_all(session), START_TIMEOUT_S)
            yield SimpleNamespace(hub=hub, sup=sup, got=got, pubs=pubs, logs=_logs(sup), ok=ok)
        finally:
            for s in subs:
                s.undeclare()
            codes = sup.stop_all(grace_s=5.0)
            assert all(c is not None for c in codes.values()), f"left running: {codes}"


def _alive_all(session: Any) -> Callable[[], bool]:
    wanted = {
        "racestack/rosa/alive/localization_bridge",
        "racestack/rosb/alive/localization_bridge",
        "racestack/rosb/alive/ros2_gateway",
        "racestack/rosc/alive/ros2_gateway",
    }

    def check() -> bool:
        replies = session.liveliness().get("racestack/*/alive/*", timeout=1.0)
        seen = set()
        for r in replies:
            if r.ok is not None:
                seen.add(str(r.ok.key_expr))
        return wanted <= seen

    return check


def _logs(sup: Supervisor) -> Callable[[], str]:
    def text() -> str:
        return "\n".join(
            f"--- {c.name} (exit {c.exit_code()})\n{c.log_path.read_text()[-2500:]}"
            for c in sup.children
            if c.log_path and c.log_path.exists()
        )

    return text


def _send_round(rig: SimpleNamespace, cdr: SimpleNamespace, stamp: float) -> None:
    """One reading, natively to car rosa and as CDR to the gateway of car rosb."""
    s, p = rig.hub.session, rig.pubs
    p.pose.put(Pose(stamp_s=stamp, x_m=X, y_m=Y, yaw_rad=YAW))
    p.odom.put(Odom(stamp_s=stamp, speed_mps=0.0, steering_rad=0.0, yaw_rate_radps=0.0))
    p.imu.put(Imu(stamp_s=stamp, yaw_rate_radps=0.0, ax_mps2=0.0, ay_mps2=0.0))
    s.put(KEY_POSE, cdr.pose_stamped(TS, X, Y, YAW, stamp_s=stamp))
    s.put(KEY_ODOM_IN, cdr.odometry(TS, X, Y, YAW, v=0.0, r=0.0, stamp_s=stamp))
    s.put(KEY_IMU, cdr.imu(TS, 0.0, 0.0, 0.0, stamp_s=stamp))


def _stream(rig: SimpleNamespace, cdr: SimpleNamespace, seconds: float) -> float:
    end = time.monotonic() + seconds
    stamp = time.time()
    while time.monotonic() < end:
        stamp = time.time()
        _send_round(rig, cdr, stamp)
        time.sleep(1.0 / RATE_HZ)
    return stamp


def test_cdr_inputs_yield_the_same_state_as_native_ones(
    rig: SimpleNamespace, cdr: SimpleNamespace
) -> None:
    assert rig.ok, rig.logs()
    got = rig.got
    last = _stream(rig, cdr, 2.0)
    # the gateway republished each reading as the native record, same values and stamps
    assert until(lambda: any(abs(m.stamp_s - last) < 1e-6 for m in got.get("pose.b"))), rig.logs()
    pose = next(m for m in got.get("pose.b") if abs(m.stamp_s - last) < 1e-6)
    assert (pose.x_m, pose.y_m) == (X, Y) and pose.yaw_rad == pytest.approx(YAW, abs=1e-12)
    odom = got.get("odom.b")[-1]
    assert (odom.speed_mps, odom.steering_rad, odom.yaw_rate_radps) == (0.0, 0.0, 0.0)
    assert got.get("imu.b")[-1].ax_mps2 == 0.0  # via the rmw_zenoh key
    # both bridges: a valid state built from the newest pose, the same numbers
    last = _stream(rig, cdr, 1.0)

    def newest(car: str) -> State | None:
        states = [s for s in got.get(f"state.{car}") if abs(s.source_stamp_s - last) < 1e-6]
        return states[-1] if states else None

    assert until(lambda: newest("a") is not None and newest("b") is not None), rig.logs()
    a, b = newest("a"), newest("b")
    assert a is not None and b is not None
    assert a.valid and b.valid
    for name in ("x_m", "y_m", "yaw_rad", "speed_mps", "yaw_rate_radps", "steering_rad"):
        assert getattr(b, name) == pytest.approx(getattr(a, name), abs=1e-6), name
    assert b.x_m == pytest.approx(X, abs=1e-3) and b.yaw_rad == pytest.approx(YAW, abs=1e-3)


def test_pose_with_covariance_and_laser_scan_arrive_as_native_records(
    rig: SimpleNamespace, cdr: SimpleNamespace
) -> None:
    assert rig.ok, rig.logs()
    s, got = rig.hub.session, rig.got
    stamp = time.time()
    ranges = [1.0 + 0.01 * i for i in range(1081)]
    ranges[5] = float("nan")
    s.put(KEY_POSE_COV, cdr.pose_cov(TS, 1.0, 2.0, -0.5, var=(0.04, 0.09, 0.01), stamp_s=stamp))
    s.put(KEY_SCAN, cdr.scan(TS, ranges, stamp_s=stamp))
    assert until(lambda: bool(got.get("pose.c")) and bool(got.get("scan.b"))), rig.logs()
    pose = got.get("pose.c")[-1]
    assert pose.stamp_s == pytest.approx(stamp, abs=1e-6) and pose.yaw_rad == pytest.approx(-0.5)
    assert pose.cov is not None and np.diag(pose.cov) == pytest.approx([0.04, 0.09, 0.01])
    scan = got.get("scan.b")[-1]
    assert scan.ranges_m.shape == (1081,) and math.isinf(scan.ranges_m[5])
    assert scan.ranges_m[0] == pytest.approx(1.0) and scan.angle_min_rad == pytest.approx(-2.35)


def test_outbound_odometry_path_and_ackermann_decode_to_the_records(
    rig: SimpleNamespace, cdr: SimpleNamespace
) -> None:
    assert rig.ok, rig.logs()
    got = rig.got
    _stream(rig, cdr, 0.5)  # keeps bridge b publishing
    # /odom: each sample is one of bridge b's states
    assert until(lambda: len(got.get(KEY_ODOM_OUT)) >= 5), rig.logs()
    states = {round(s.stamp_s, 6): s for s in got.get("state.b")}
    matched = 0
    for payload, att in got.get(KEY_ODOM_OUT)[-20:]:
        assert att is None  # bridge_ros2dds: no attachment
        odo = TS.deserialize_cdr(payload, "nav_msgs/msg/Odometry")
        st = states.get(round(stamp_to_s(odo.header.stamp), 6))
        if st is None:
            continue
        matched += 1
        assert odo.header.frame_id == "map" and odo.child_frame_id == "base_link"
        assert odo.pose.pose.position.x == st.x_m and odo.pose.pose.position.y == st.y_m
        assert yaw_of(odo.pose.pose.orientation) == pytest.approx(st.yaw_rad, abs=1e-12)
        assert odo.twist.twist.linear.x == st.speed_mps
        assert odo.twist.twist.angular.z == st.yaw_rate_radps
    assert matched >= 3
    # /plan and /drive (rmw_zenoh keys with the attachment)
    n = 10
    horizon = np.column_stack(
        [
            np.linspace(0, 5, n + 1),
            np.linspace(0, -2, n + 1),
            np.linspace(0, 0.3, n + 1),
            np.linspace(0, 5, n + 1),
        ]
    )
    stamp = time.time()
    rig.pubs.plan.put(
        Plan(
            stamp_s=stamp,
            horizon=horizon,
            inputs=np.zeros((n, 3)),
            beta=np.zeros(n),
            status="solved",
            solver_status="ok",
            iterations=4,
            solve_time_ms=0.8,
            method="cimpcc",
            s_m=1.0,
            e_con_m=0.0,
            source_stamp_s=stamp,
            consecutive_failures=0,
        )
    )
    for k in range(3):
        rig.pubs.drive.put(DriveCmd(stamp_s=stamp + k, speed_mps=3.5, steering_rad=-0.25))
    assert until(lambda: got.get(KEY_PATH) and len(got.get(KEY_DRIVE)) >= 3), rig.logs()
    payload, att = got.get(KEY_PATH)[-1]
    path = TS.deserialize_cdr(payload, "nav_msgs/msg/Path")
    assert len(path.poses) == n + 1 and path.header.frame_id == "map"
    assert stamp_to_s(path.header.stamp) == pytest.approx(stamp, abs=1e-6)
    assert path.poses[-1].pose.position.x == pytest.approx(5.0)
    assert yaw_of(path.poses[-1].pose.orientation) == pytest.approx(0.3)
    assert att is not None and parse_attachment(att) is not None
    drives = got.get(KEY_DRIVE)[-3:]
    seqs = []
    for payload, att in drives:
        ack = TS.deserialize_cdr(payload, "ackermann_msgs/msg/AckermannDriveStamped")
        assert ack.drive.speed == 3.5 and ack.drive.steering_angle == pytest.approx(-0.25)
        assert ack.header.frame_id == "base_link"
        a = parse_attachment(att)
        assert a is not None and abs(a.source_time_ns * 1e-9 - time.time()) < 30.0
        seqs.append(a.sequence)
    assert seqs == sorted(seqs) and len(set(seqs)) == 3
    assert len({parse_attachment(att).gid for _, att in drives}) == 1  # one publisher id


def test_malformed_cdr_is_counted_reported_and_survived(
    rig: SimpleNamespace, cdr: SimpleNamespace
) -> None:
    assert rig.ok, rig.logs()
    s, got = rig.hub.session, rig.got
    good = cdr.pose_stamped(TS, X, Y, YAW, stamp_s=time.time())
    bad = [
        os.urandom(64),  # random bytes
        b"\x00\x01\x00\x00" + os.urandom(40),  # a CDR header, garbage behind
        good[: len(good) // 2],  # truncated
        cdr.imu(TS, 0.0, 0.0, 0.0),  # the wrong type
        b"",
    ]
    for _ in range(3):
        for payload in bad:
            s.put(KEY_POSE, payload)
            s.put(KEY_SCAN, payload)

    def reported() -> bool:
        text = " ".join(e.text for e in got.get("log.b") if e.text.startswith("rejected"))
        return f"{KEY_POSE} " in text and f"{KEY_SCAN} " in text

    assert until(reported), f"{[e.text for e in got.get('log.b')]}\n{rig.logs()}"
    text = " ".join(e.text for e in got.get("log.b"))
    for reason in ("not_cdr", "bad_cdr", "size_mismatch"):  # each kind of bad payload
        assert f"{KEY_POSE} {reason}" in text, text
    # still alive and still converting
    assert not rig.sup.dead(), rig.logs()
    stamp = time.time()
    s.put(KEY_POSE, cdr.pose_stamped(TS, X, Y, YAW, stamp_s=stamp))
    assert until(lambda: any(abs(m.stamp_s - stamp) < 1e-6 for m in got.get("pose.b"))), rig.logs()
