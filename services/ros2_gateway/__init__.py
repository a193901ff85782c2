"""The ROS 2 gateway: ROS 2 topics as CDR over Zenoh (zenoh-bridge-ros2dds or rmw_zenoh) in
and out of the stack, so a ROS 2 localiser can feed it and RViz, Foxglove and rosbag see it.

Modules: ``typestore`` (rosbags typestores with ackermann_msgs registered), ``naming`` (the
Zenoh key of a ROS topic under each scheme, rmw_zenoh's attachment), ``convert`` (CDR and the
pure conversions between ROS messages and the stack's records), ``raw`` (raw bytes on ROS
keys through the bus session) and ``service`` (the shell). Settings: ``[ros2]``
(``shared.config.ros2``).
"""

from services.ros2_gateway.service import Ros2GatewayService

__all__ = ["Ros2GatewayService"]
