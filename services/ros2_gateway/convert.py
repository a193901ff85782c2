"""ROS 2 messages (rosbags objects, CDR bytes) <-> the stack's records: the pure conversions.

No I/O and no clock: the caller passes the typestore (``typestore.make_typestore``), the
bytes and, for ``stamp = "receive"``, the arrival time.

Stamps: ``header.stamp`` is (``sec``, ``nanosec``) since the Unix epoch and the stack's
``stamp_s`` is wall-clock seconds, so ``stamp_s = sec + 1e-9 nanosec`` and back
(``stamp_from_s``: ``sec = floor(t)``, ``nanosec = round(1e9 (t - sec))``).

Frames: poses are those of ``base_link`` (the rear-axle centre, F1TENTH's convention and the
stack's) in the map frame; headings are the yaw of the quaternion,
``yaw = atan2(2 (w z + x y), 1 - 2 (y^2 + z^2))``, and back ``q = (0, 0, sin(yaw/2),
cos(yaw/2))``. Twists are in the child (body) frame, as ROS's Odometry defines them.

Inbound (ROS -> record; every record validates itself, so a value beyond the contract raises
``MessageError``). With the arrival time given, a header stamp more than ``max_age_s`` before
or ``max_ahead_s`` after it raises ``CdrError`` (``stale_stamp``, ``future_stamp``:
``check_stamp``); a pose's quaternion is normalised before its yaw is read, and one with no
heading (norm below ``MIN_QUATERNION_NORM``, not finite) raises ``bad_quaternion``
(``checked_yaw``):

* ``PoseStamped`` -> ``Pose`` (cov None); ``PoseWithCovarianceStamped`` and ``Odometry``
  (``native = "vehicle/pose"``) -> ``Pose`` with ``cov`` = rows/columns (x, y, yaw) = (0, 1, 5)
  of the 6x6 covariance, or None when that block is not a covariance (all zeros, negative
  or asymmetric: unknown);
* ``Odometry`` -> ``Odom``: ``speed = twist.linear.x``, ``yaw_rate = twist.angular.z``, and
  the steering the kinematic bicycle implies, ``delta = atan(L r / v)`` for ``|v| >=
  MIN_SPEED_FOR_STEERING_MPS`` (else 0), clipped to the contract's +-1 rad;
* ``Imu`` -> ``Imu``: ``angular_velocity.z``, ``linear_acceleration.x / .y`` (the IMU frame
  is taken as aligned with base_link);
* ``LaserScan`` -> ``Scan``: ``angle_min``, ``angle_increment``, ranges as float32 with NaN,
  +-inf and values outside [range_min, range_max] as +inf (no return).

Outbound (record -> ROS object; ``encode_cdr`` serializes little endian):

* ``State`` -> ``nav_msgs/Odometry`` (pose x, y, yaw; twist linear.x = speed, angular.z =
  yaw rate; covariances 0 = unknown; the service sends none while ``state.valid`` is false);
* ``Plan`` -> ``nav_msgs/Path`` (one ``PoseStamped`` per horizon row X, Y, phi, all stamped
  with the plan's stamp);
* ``DriveCmd`` -> ``ackermann_msgs/AckermannDriveStamped`` (``drive.speed``,
  ``drive.steering_angle``; the rest 0).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from shared.config.ros2 import Ros2Topic
from shared.messages import (
    DriveCmd,
    HorizonCol,
    Imu,
    Message,
    MessageError,
    Odom,
    Plan,
    Pose,
    Scan,
    State,
)

#: Below this speed [m/s] an inbound Odometry's steering is reported as 0 (atan(L r / v) is
#: ill-conditioned near standstill).
MIN_SPEED_FOR_STEERING_MPS = 0.1
#: Largest |steering| [rad] the contract accepts (``Odom.steering_rad``).
MAX_STEERING_RAD = 1.0
#: Rows / columns (x, y, yaw) of a ROS 6x6 pose covariance [x, y, z, roll, pitch, yaw].
COV_XY_YAW = (0, 1, 5)
#: Smallest norm of an inbound quaternion that is normalised and read (below: dropped).
MIN_QUATERNION_NORM = 1e-3
_NS = 1_000_000_000


class CdrError(ValueError):
    """A payload that is not a message of the expected type.

    Attributes:
        reason: ``not_cdr`` (no CDR encapsulation header), ``size_mismatch`` (decodes with
            bytes left over: another type, or garbage after a message), ``bad_cdr``
            (truncated or garbage inside), ``bad_stamp`` (sec < 0 or nanosec >= 1e9),
            ``stale_stamp`` / ``future_stamp`` (far from the arrival time),
            ``bad_quaternion`` (an orientation without a heading).
    """

    def __init__(self, reason: str, detail: str) -> None:
        super().__init__(f"{reason}: {detail}")
        self.reason = reason
        self.detail = detail


# --------------------------------------------------------------------------- CDR
def decode_cdr(typestore: Any, payload: bytes, ros_type: str) -> Any:
    """Deserialize a CDR payload (4-byte encapsulation header first) of ``ros_type``.

    Raises:
        CdrError: with ``reason`` (see ``CdrError``); never anything else.
    """
    if len(payload) < 4 or payload[:2] not in (b"\x00\x00", b"\x00\x01"):
        raise CdrError("not_cdr", f"{len(payload)} bytes without a CDR encapsulation header")
    try:
        return typestore.deserialize_cdr(payload, ros_type)
    except Exception as exc:  # rosbags raises SerdeError, numpy/struct errors leak through
        text = str(exc)
        reason = "size_mismatch" if "size mismatch" in text else "bad_cdr"
        return _raise(reason, f"{type(exc).__name__}: {text[:200]}")


def _raise(reason: str, detail: str) -> Any:
    raise CdrError(reason, detail)


def encode_cdr(typestore: Any, msg: Any, ros_type: str) -> bytes:
    """Serialize a rosbags message object as CDR little endian (with its header)."""
    return bytes(typestore.serialize_cdr(msg, ros_type))


# --------------------------------------------------------------------------- stamps, angles
def stamp_to_s(stamp: Any) -> float:
    """``builtin_interfaces/Time`` -> seconds since the Unix epoch.

    Raises:
        CdrError: ``bad_stamp`` for sec < 0 or nanosec outside [0, 1e9).
    """
    sec, nsec = int(stamp.sec), int(stamp.nanosec)
    if sec < 0 or not 0 <= nsec < _NS:
        raise CdrError("bad_stamp", f"sec={sec} nanosec={nsec}")
    return sec + nsec * 1e-9


def stamp_from_s(typestore: Any, t_s: float) -> Any:
    """Seconds since the Unix epoch (>= 0) -> ``builtin_interfaces/Time``."""
    sec = math.floor(t_s)
    nsec = round((t_s - sec) * 1e9)
    if nsec >= _NS:
        sec, nsec = sec + 1, nsec - _NS
    return typestore.types["builtin_interfaces/msg/Time"](sec=int(sec), nanosec=int(nsec))


def yaw_of(q: Any) -> float:
    """Heading [rad] (about z) of a unit ``geometry_msgs/Quaternion``."""
    return math.atan2(2.0 * (q.w * q.z + q.x * q.y), 1.0 - 2.0 * (q.y * q.y + q.z * q.z))


def checked_yaw(q: Any) -> float:
    """Heading [rad] of an inbound orientation, normalised first (``yaw_of`` assumes a unit
    quaternion; a ROS source may send one slightly off).

    Raises:
        CdrError: ``bad_quaternion`` for a norm below ``MIN_QUATERNION_NORM`` (the all-zero
            "no orientation" quaternion) or not finite: no heading can be read from it.
    """
    x, y, z, w = float(q.x), float(q.y), float(q.z), float(q.w)
    norm = math.sqrt(x * x + y * y + z * z + w * w)
    if not math.isfinite(norm) or norm < MIN_QUATERNION_NORM:
        raise CdrError("bad_quaternion", f"(x, y, z, w) = ({x}, {y}, {z}, {w}), norm {norm:.3g}")
    x, y, z, w = x / norm, y / norm, z / norm, w / norm
    return math.atan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))


def check_stamp(stamp_s: float, now_s: float, max_age_s: float, max_ahead_s: float) -> None:
    """Refuse a header stamp far from the gateway's clock (1970, another clock, +1 h).

    Args:
        stamp_s: the header stamp [s since the Unix epoch].
        now_s: the gateway's wall clock at arrival [s].
        max_age_s: the oldest accepted, ``now_s - stamp_s`` [s].
        max_ahead_s: the furthest ahead accepted, ``stamp_s - now_s`` [s].

    Raises:
        CdrError: ``stale_stamp`` or ``future_stamp``.
    """
    if now_s - stamp_s > max_age_s:
        raise CdrError("stale_stamp", f"stamp {stamp_s:.3f} is {now_s - stamp_s:.3f} s old")
    if stamp_s - now_s > max_ahead_s:
        raise CdrError("future_stamp", f"stamp {stamp_s:.3f} is {stamp_s - now_s:.3f} s ahead")


def quaternion_of(typestore: Any, yaw_rad: float) -> Any:
    """The ``geometry_msgs/Quaternion`` of a rotation by ``yaw_rad`` about z."""
    return typestore.types["geometry_msgs/msg/Quaternion"](
        x=0.0, y=0.0, z=math.sin(0.5 * yaw_rad), w=math.cos(0.5 * yaw_rad)
    )


def pose_cov(covariance: Any) -> np.ndarray | None:
    """The (3, 3) [x, y, yaw] block of a ROS 6x6 pose covariance (36 values, row major), or
    None when it is not a usable covariance (all zeros, not finite, a negative variance,
    asymmetric)."""
    c = np.asarray(covariance, dtype=float)
    if c.size != 36:
        return None
    block = c.reshape(6, 6)[np.ix_(COV_XY_YAW, COV_XY_YAW)]
    if (
        not np.all(np.isfinite(block))
        or not np.any(block)
        or np.any(np.diag(block) < 0.0)
        or not np.allclose(block, block.T, rtol=1e-6, atol=1e-9)
    ):
        return None
    return np.ascontiguousarray(block)


# --------------------------------------------------------------------------- inbound
def to_native(
    msg: Any,
    topic: Ros2Topic,
    *,
    wheelbase_m: float,
    receive_s: float | None = None,
    max_age_s: float = math.inf,
    max_ahead_s: float = math.inf,
) -> Message:
    """The record an inbound ROS message becomes on ``topic.native``.

    Args:
        msg: the deserialized rosbags object of ``topic.type``.
        topic: the topic entry (type, native key, stamp source).
        wheelbase_m: the car's wheelbase [m] (Odometry -> steering).
        receive_s: the arrival time [s] (wall clock): the stamp with ``stamp = "receive"``;
            with ``stamp = "header"`` the clock the header stamp is checked against.
        max_age_s, max_ahead_s: how far [s] a header stamp may lie before / after
            ``receive_s`` (``check_stamp``).

    Raises:
        CdrError: a bad header stamp (``bad_stamp``, ``stale_stamp``, ``future_stamp``), a
            pose's orientation without a heading (``bad_quaternion``). MessageError: a value
            the contract rejects.
    """
    stamp_s = stamp_to_s(msg.header.stamp)
    if receive_s is not None:
        if topic.stamp == "receive":
            stamp_s = receive_s
        else:
            check_stamp(stamp_s, receive_s, max_age_s, max_ahead_s)
    t, native = topic.type, topic.native
    if t == "geometry_msgs/msg/PoseStamped":
        p = msg.pose
        return Pose(
            stamp_s=stamp_s,
            x_m=p.position.x,
            y_m=p.position.y,
            yaw_rad=checked_yaw(p.orientation),
        )
    if t == "geometry_msgs/msg/PoseWithCovarianceStamped" or (
        t == "nav_msgs/msg/Odometry" and native == "vehicle/pose"
    ):
        pc = msg.pose
        p = pc.pose
        return Pose(
            stamp_s=stamp_s,
            x_m=p.position.x,
            y_m=p.position.y,
            yaw_rad=checked_yaw(p.orientation),
            cov=pose_cov(pc.covariance),
        )
    if t == "nav_msgs/msg/Odometry":
        tw = msg.twist.twist
        v, r = float(tw.linear.x), float(tw.angular.z)
        steer = 0.0
        if abs(v) >= MIN_SPEED_FOR_STEERING_MPS and math.isfinite(r):
            steer = math.atan(wheelbase_m * r / v)
            steer = max(-MAX_STEERING_RAD, min(MAX_STEERING_RAD, steer))
        return Odom(stamp_s=stamp_s, speed_mps=v, steering_rad=steer, yaw_rate_radps=r)
    if t == "sensor_msgs/msg/Imu":
        return Imu(
            stamp_s=stamp_s,
            yaw_rate_radps=msg.angular_velocity.z,
            ax_mps2=msg.linear_acceleration.x,
            ay_mps2=msg.linear_acceleration.y,
        )
    if t == "sensor_msgs/msg/LaserScan":
        ranges = np.asarray(msg.ranges, dtype=np.float32)
        lo, hi = float(msg.range_min), float(msg.range_max)
        no_return = ~np.isfinite(ranges) | (ranges > hi) | (ranges < lo)
        ranges = np.where(no_return, np.float32(np.inf), ranges).astype(np.float32)
        return Scan(
            stamp_s=stamp_s,
            angle_min_rad=float(msg.angle_min),
            angle_increment_rad=float(msg.angle_increment),
            ranges_m=ranges,
        )
    raise MessageError("bad_value", f"no inbound conversion {t} -> {native}")


# --------------------------------------------------------------------------- outbound
def _header(ts: Any, stamp_s: float, frame_id: str) -> Any:
    return ts.types["std_msgs/msg/Header"](stamp=stamp_from_s(ts, stamp_s), frame_id=frame_id)


def _pose(ts: Any, x: float, y: float, yaw: float) -> Any:
    point = ts.types["geometry_msgs/msg/Point"](x=float(x), y=float(y), z=0.0)
    return ts.types["geometry_msgs/msg/Pose"](position=point, orientation=quaternion_of(ts, yaw))


def _vector3(ts: Any, x: float = 0.0, y: float = 0.0, z: float = 0.0) -> Any:
    return ts.types["geometry_msgs/msg/Vector3"](x=float(x), y=float(y), z=float(z))


def state_to_odometry(ts: Any, state: State, frame_id: str, child_frame_id: str) -> Any:
    """``State`` -> ``nav_msgs/msg/Odometry`` (see the module docstring)."""
    t = ts.types
    zeros = np.zeros(36, dtype=np.float64)
    twist = t["geometry_msgs/msg/Twist"](
        linear=_vector3(ts, state.speed_mps), angular=_vector3(ts, z=state.yaw_rate_radps)
    )
    return t["nav_msgs/msg/Odometry"](
        header=_header(ts, state.stamp_s, frame_id),
        child_frame_id=child_frame_id,
        pose=t["geometry_msgs/msg/PoseWithCovariance"](
            pose=_pose(ts, state.x_m, state.y_m, state.yaw_rad), covariance=zeros
        ),
        twist=t["geometry_msgs/msg/TwistWithCovariance"](twist=twist, covariance=zeros.copy()),
    )


def plan_to_path(ts: Any, plan: Plan, frame_id: str) -> Any:
    """``Plan`` -> ``nav_msgs/msg/Path``: its horizon rows (X, Y, phi) as poses."""
    t = ts.types
    h = plan.horizon
    poses = [
        t["geometry_msgs/msg/PoseStamped"](
            header=_header(ts, plan.stamp_s, frame_id),
            pose=_pose(ts, row[HorizonCol.X], row[HorizonCol.Y], row[HorizonCol.PHI]),
        )
        for row in h
    ]
    return t["nav_msgs/msg/Path"](header=_header(ts, plan.stamp_s, frame_id), poses=poses)


def drive_to_ackermann(ts: Any, cmd: DriveCmd, frame_id: str) -> Any:
    """``DriveCmd`` -> ``ackermann_msgs/msg/AckermannDriveStamped``."""
    t = ts.types
    drive = t["ackermann_msgs/msg/AckermannDrive"](
        steering_angle=float(cmd.steering_rad),
        steering_angle_velocity=0.0,
        speed=float(cmd.speed_mps),
        acceleration=0.0,
        jerk=0.0,
    )
    return t["ackermann_msgs/msg/AckermannDriveStamped"](
        header=_header(ts, cmd.stamp_s, frame_id), drive=drive
    )


def to_ros(ts: Any, record: Message, topic: Ros2Topic) -> Any:
    """The ROS object an outbound record becomes on ``topic`` (type per ``topic.native``).

    Raises:
        MessageError: no such outbound conversion (the configuration rules it out).
    """
    if isinstance(record, State):
        return state_to_odometry(ts, record, topic.frame_id, topic.child_frame_id)
    if isinstance(record, Plan):
        return plan_to_path(ts, record, topic.frame_id)
    if isinstance(record, DriveCmd):
        return drive_to_ackermann(ts, record, topic.frame_id)
    raise MessageError("bad_value", f"no outbound conversion of {type(record).__name__}")
