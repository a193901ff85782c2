"""The ROS 2 message definitions of the gateway: a rosbags typestore plus ackermann_msgs.

``rosbags`` carries the common ROS 2 interfaces of each distribution (std_msgs,
geometry_msgs, nav_msgs, sensor_msgs, ...) and (de)serializes CDR without a ROS
installation. ``ackermann_msgs`` is not among them: it is registered here from its message
definitions, written out from the package's documented fields (ros-drivers/ackermann_msgs,
the messages the F1TENTH ROS 2 VESC stack consumes on ``/drive``)::

    ackermann_msgs/msg/AckermannDrive:        float32 steering_angle [rad],
        float32 steering_angle_velocity [rad/s], float32 speed [m/s],
        float32 acceleration [m/s^2], float32 jerk [m/s^3]
    ackermann_msgs/msg/AckermannDriveStamped: std_msgs/Header header, AckermannDrive drive

Pure: building a typestore reads no file and opens nothing. ``rosbags`` is the ``[ros2]``
extra: it is imported when a typestore is built, so this module imports without it.
"""

from __future__ import annotations

from functools import cache
from typing import Any, Literal

from shared.extras import require

#: ``ackermann_msgs/msg/AckermannDrive`` (the documented fields, in order).
ACKERMANN_DRIVE_MSG = """\
float32 steering_angle
float32 steering_angle_velocity
float32 speed
float32 acceleration
float32 jerk
"""
#: ``ackermann_msgs/msg/AckermannDriveStamped``.
ACKERMANN_DRIVE_STAMPED_MSG = """\
std_msgs/Header header
ackermann_msgs/AckermannDrive drive
"""

Distro = Literal["humble", "jazzy"]


@cache
def make_typestore(distro: Distro) -> Any:
    """The typestore of ``distro`` ("humble" | "jazzy") with ackermann_msgs registered
    (cached: one per distribution and process). Raises ``shared.extras.MissingExtraError``
    without rosbags."""
    require("rosbags")
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore

    stores = {"humble": Stores.ROS2_HUMBLE, "jazzy": Stores.ROS2_JAZZY}
    ts = get_typestore(stores[distro])
    types: dict[str, Any] = {}
    types.update(get_types_from_msg(ACKERMANN_DRIVE_MSG, "ackermann_msgs/msg/AckermannDrive"))
    types.update(
        get_types_from_msg(ACKERMANN_DRIVE_STAMPED_MSG, "ackermann_msgs/msg/AckermannDriveStamped")
    )
    ts.register(types)
    return ts
