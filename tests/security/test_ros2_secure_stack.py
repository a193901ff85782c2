"""The ROS 2 gateway in the secure profile, with real processes on loopback.

A router (the hub, its rules from the whole configuration) and a ros2_gateway run with
``[bus] security = "mtls"`` and certificates from ``shared.security.certs``; this test plays
the ROS side and an intruder:

* a client with the ``ros2`` certificate puts PoseStamped CDR (made with rosbags) on the
  inbound ROS key ``pf/pose``: the gateway republishes it on ``vehicle/pose``;
* a client with the ``telemetry`` certificate puts other poses on the same ROS key: none
  reaches ``vehicle/pose`` and the router reports exactly that many denied puts;
* a ``state`` record goes out as nav_msgs/Odometry CDR on ``odom`` (the gateway's outbound
  put is allowed) and the ``ros2`` client receives it.

Every process is stopped by PID with a timeout in a ``finally``.
"""

from __future__ import annotations

import re
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest

from services.ros2_gateway.convert import decode_cdr, quaternion_of, stamp_from_s
from services.ros2_gateway.typestore import make_typestore
from services.tools.launcher.supervisor import Supervisor, service_argv
from shared.bus import Bus
from shared.config import load_config
from shared.messages import LogEvent, Pose, State
from shared.net import free_loopback_port
from shared.security.certs import make_certs

pytestmark = pytest.mark.slow
TS = make_typestore("humble")
START_TIMEOUT_S = 120.0
RATE_HZ = 20.0
SENT = 30  # puts of each sender
X_ROS, X_INTRUDER = 2.5, 9.0  # the x of the ROS side's poses and of the intruder's [m]

TOPICS_TOML = """
[ros2]
[[ros2.topics]]
topic = "/pf/pose"
type = "geometry_msgs/msg/PoseStamped"
direction = "in"
native = "vehicle/pose"

[[ros2.topics]]
topic = "/odom"
type = "nav_msgs/msg/Odometry"
direction = "out"
native = "state"
"""


def pose_stamped_cdr(x: float, y: float, yaw: float, stamp_s: float) -> bytes:
    """A geometry_msgs/msg/PoseStamped in CDR, as a ROS 2 node sends it (rosbags)."""
    t = TS.types
    msg = t["geometry_msgs/msg/PoseStamped"](
        header=t["std_msgs/msg/Header"](stamp=stamp_from_s(TS, stamp_s), frame_id="map"),
        pose=t["geometry_msgs/msg/Pose"](
            position=t["geometry_msgs/msg/Point"](x=x, y=y, z=0.0),
            orientation=quaternion_of(TS, yaw),
        ),
    )
    return bytes(TS.serialize_cdr(msg, "geometry_msgs/msg/PoseStamped"))


def until(cond: Callable[[], bool], timeout_s: float) -> bool:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if cond():
            return True
        time.sleep(0.05)
    return cond()


def logs(sup: Supervisor) -> str:
    return "\n".join(
        f"--- {c.name} (exit {c.exit_code()})\n{c.log_path.read_text()[-3000:]}"
        for c in sup.children
        if c.log_path and c.log_path.exists()
    )


def test_ros_side_certificate_puts_inbound_keys_intruder_denied_outbound_allowed(
    tmp_path: Path,
) -> None:
    certs = tmp_path / "certs"
    make_certs(certs)
    port = free_loopback_port()
    cfg_path = tmp_path / "secure.toml"
    cfg_path.write_text(
        f'[bus]\nlisten = ["tcp/127.0.0.1:{port}"]\nsecurity = "mtls"\n'
        f'certs_dir = "{certs}"\n{TOPICS_TOML}',
        encoding="utf-8",
    )
    cfg = load_config(cfg_path)
    sup = Supervisor(log_dir=tmp_path / "logs", env={"RACESTACK_CERTS_DIR": str(certs)})
    lock = threading.Lock()
    poses: list[float] = []
    router_logs: list[str] = []
    odoms: list[Any] = []
    try:
        sup.start("router", service_argv("router", str(cfg_path)))
        time.sleep(1.0)  # the hub listens before anyone connects
        sup.start("ros2_gateway", service_argv("ros2_gateway", str(cfg_path)))
        with Bus(cfg.bus, "operator", announce=False) as watch, \
                Bus(cfg.bus, "ros2", announce=False) as ros, \
                Bus(cfg.bus, "telemetry", announce=False) as intruder, \
                Bus(cfg.bus, "localization_bridge", announce=False) as loc:
            assert watch.wait_alive(["ros2_gateway"], START_TIMEOUT_S), logs(sup)

            def on_pose(m: Pose) -> None:
                with lock:
                    poses.append(m.x_m)

            def on_log(m: LogEvent) -> None:
                if m.source == "router":
                    with lock:
                        router_logs.append(m.text)

            def on_odom(sample: Any) -> None:
                with lock:
                    odoms.append(sample.payload.to_bytes())

            watch.subscribe(watch.keys.pose, Pose, on_pose)
            watch.subscribe(watch.keys.events_log, LogEvent, on_log)
            odom_sub = ros.session.declare_subscriber("odom", on_odom)
            ros_pub = ros.session.declare_publisher("pf/pose")
            bad_pub = intruder.session.declare_publisher("pf/pose")
            # the gateway's subscriber on pf/pose is forwarded to both clients
            assert until(lambda: ros_pub.matching_status.matching, 10.0), logs(sup)
            assert until(lambda: bad_pub.matching_status.matching, 10.0), logs(sup)

            # 1. the ROS side's poses arrive on vehicle/pose
            for _ in range(SENT):
                ros_pub.put(pose_stamped_cdr(X_ROS, -1.25, 0.8, time.time()))
                time.sleep(1.0 / RATE_HZ)
            assert until(lambda: len(poses) >= SENT // 2, 10.0), (poses, logs(sup))

            # 2. the intruder's are denied, counted and reported
            for _ in range(SENT):
                bad_pub.put(pose_stamped_cdr(X_INTRUDER, 0.0, 0.0, time.time()))
                time.sleep(1.0 / RATE_HZ)
            pattern = re.compile(r"telemetry Put \(ingress\) pf/pose x(\d+)")

            def counted() -> int:
                with lock:
                    return sum(int(n) for t in router_logs for n in pattern.findall(t))

            until(lambda: counted() >= SENT, 10.0)
            time.sleep(1.5)  # one more report period: nothing beyond SENT

            # 3. the gateway's outbound put on odom is allowed
            state = loc.publisher(loc.keys.state, State)
            assert state.wait_matching(10.0), logs(sup)
            for _ in range(10):
                now = time.time()
                state.put(State(stamp_s=now, x_m=1.5, y_m=0.5, yaw_rad=0.25, speed_mps=2.0,
                                yaw_rate_radps=0.0, steering_rad=0.0, source_stamp_s=now,
                                valid=True))
                time.sleep(1.0 / RATE_HZ)
            assert until(lambda: len(odoms) >= 5, 10.0), logs(sup)
            odom_sub.undeclare()
            for pub in (ros_pub, bad_pub):
                pub.undeclare()
        with lock:
            got_poses, reports, odom_payloads = list(poses), list(router_logs), list(odoms)
        assert counted() == SENT, (reports, logs(sup))
        assert X_INTRUDER not in got_poses and got_poses.count(X_ROS) == len(got_poses)
        assert len(got_poses) >= SENT // 2, got_poses
        odom = decode_cdr(TS, odom_payloads[-1], "nav_msgs/msg/Odometry")
        assert odom.pose.pose.position.x == pytest.approx(1.5)
        # nothing else was denied (the gateway's outbound puts, the ROS side's)
        parts = [p for t in reports for p in t.split("): ", 1)[1].split(", ")]
        assert parts and all(p.startswith("telemetry Put (ingress) pf/pose x") for p in parts), (
            reports
        )
    finally:
        codes = sup.stop_all(grace_s=5.0)
        assert all(c is not None for c in codes.values()), f"left running: {codes}"
