"""CDR payloads made with rosbags, as a ROS 2 node would send them (fixture ``cdr``)."""

from __future__ import annotations

import math
from types import SimpleNamespace
from typing import Any

import numpy as np
import pytest

from services.ros2_gateway.convert import quaternion_of, stamp_from_s

#: The stamp every payload carries unless told otherwise [s since the Unix epoch].
STAMP_S = 1_767_225_600.123456789


def _header(ts: Any, stamp_s: float, frame: str = "map") -> Any:
    return ts.types["std_msgs/msg/Header"](stamp=stamp_from_s(ts, stamp_s), frame_id=frame)


def _pose(ts: Any, x: float, y: float, yaw: float) -> Any:
    t = ts.types
    return t["geometry_msgs/msg/Pose"](
        position=t["geometry_msgs/msg/Point"](x=float(x), y=float(y), z=0.0),
        orientation=quaternion_of(ts, yaw),
    )


def _cov36(var: tuple[float, float, float]) -> np.ndarray:
    c = np.zeros((6, 6))
    c[0, 0], c[1, 1], c[5, 5] = var
    return c.reshape(36)


def _v3(ts: Any, x: float = 0.0, y: float = 0.0, z: float = 0.0) -> Any:
    return ts.types["geometry_msgs/msg/Vector3"](x=float(x), y=float(y), z=float(z))


def pose_stamped_cdr(ts: Any, x: float, y: float, yaw: float, stamp_s: float = STAMP_S) -> bytes:
    msg = ts.types["geometry_msgs/msg/PoseStamped"](
        header=_header(ts, stamp_s), pose=_pose(ts, x, y, yaw)
    )
    return bytes(ts.serialize_cdr(msg, "geometry_msgs/msg/PoseStamped"))


def pose_cov_cdr(
    ts: Any,
    x: float,
    y: float,
    yaw: float,
    var: tuple[float, float, float] = (0.01, 0.01, 0.001),
    stamp_s: float = STAMP_S,
) -> bytes:
    t = ts.types
    msg = t["geometry_msgs/msg/PoseWithCovarianceStamped"](
        header=_header(ts, stamp_s),
        pose=t["geometry_msgs/msg/PoseWithCovariance"](
            pose=_pose(ts, x, y, yaw), covariance=_cov36(var)
        ),
    )
    return bytes(ts.serialize_cdr(msg, "geometry_msgs/msg/PoseWithCovarianceStamped"))


def odometry_cdr(
    ts: Any, x: float, y: float, yaw: float, v: float, r: float, stamp_s: float = STAMP_S
) -> bytes:
    t = ts.types
    msg = t["nav_msgs/msg/Odometry"](
        header=_header(ts, stamp_s, "odom"),
        child_frame_id="base_link",
        pose=t["geometry_msgs/msg/PoseWithCovariance"](
            pose=_pose(ts, x, y, yaw), covariance=np.zeros(36)
        ),
        twist=t["geometry_msgs/msg/TwistWithCovariance"](
            twist=t["geometry_msgs/msg/Twist"](linear=_v3(ts, v), angular=_v3(ts, z=r)),
            covariance=np.zeros(36),
        ),
    )
    return bytes(ts.serialize_cdr(msg, "nav_msgs/msg/Odometry"))


def imu_cdr(ts: Any, r: float, ax: float, ay: float, stamp_s: float = STAMP_S) -> bytes:
    t = ts.types
    msg = t["sensor_msgs/msg/Imu"](
        header=_header(ts, stamp_s, "imu"),
        orientation=quaternion_of(ts, 0.0),
        orientation_covariance=np.full(9, -1.0),  # orientation unknown (REP-145)
        angular_velocity=_v3(ts, z=r),
        angular_velocity_covariance=np.zeros(9),
        linear_acceleration=_v3(ts, ax, ay, 9.81),
        linear_acceleration_covariance=np.zeros(9),
    )
    return bytes(ts.serialize_cdr(msg, "sensor_msgs/msg/Imu"))


def scan_cdr(ts: Any, ranges: list[float], stamp_s: float = STAMP_S) -> bytes:
    n = len(ranges)
    msg = ts.types["sensor_msgs/msg/LaserScan"](
        header=_header(ts, stamp_s, "laser"),
        angle_min=-2.35,
        angle_max=2.35,
        angle_increment=4.7 / max(n - 1, 1),
        time_increment=0.0,
        scan_time=0.025,
        range_min=0.06,
        range_max=30.0,
        ranges=np.asarray(ranges, dtype=np.float32),
        intensities=np.zeros(0, dtype=np.float32),
    )
    return bytes(ts.serialize_cdr(msg, "sensor_msgs/msg/LaserScan"))


@pytest.fixture(scope="session")
def cdr() -> SimpleNamespace:
    """The payload builders (``cdr.pose_stamped(ts, x, y, yaw)`` ...) and ``cdr.STAMP_S``."""
    return SimpleNamespace(
        STAMP_S=STAMP_S,
        pose_stamped=pose_stamped_cdr,
        pose_cov=pose_cov_cdr,
        odometry=odometry_cdr,
        imu=imu_cdr,
        scan=scan_cdr,
        wrap=lambda a: math.atan2(math.sin(a), math.cos(a)),
    )
