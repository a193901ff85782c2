"""Zenoh keys of ROS 2 topics (pure, no I/O): what the ros2_gateway uses and the hub allows.

``shared.config.ros2`` has the settings and the sources of the naming:

* ``bridge_ros2dds`` (zenoh-bridge-ros2dds): ``/scan`` -> ``scan``, ``/car/odom`` ->
  ``car/odom`` (the ROS name without its leading ``/``).
* ``rmw_zenoh`` (rmw_zenoh_cpp): ``<domain_id>/<name without leading />/<DDS type>/<hash>``,
  the DDS type name of ``pkg/msg/Name`` being ``pkg::msg::dds_::Name_``, the hash the
  REP-2016 ``RIHS01_<sha256>`` of the type (jazzy; rosbags computes it) or
  ``TypeHashNotSupported`` (humble). Inbound keys put ``*`` in the hash chunk.

A topic's explicit ``key`` replaces the computed one. These keys live outside
``racestack/<car>/``; the gateway (``services.ros2_gateway``) uses them on its raw session
and the hub's access rules (``shared.security.acl``) name them.
"""

from __future__ import annotations

from shared.config.ros2 import Ros2Settings, Ros2Topic

__all__ = ["ANY_TYPE_HASH", "HUMBLE_TYPE_HASH", "dds_type_name", "type_hash", "zenoh_key"]

#: The hash chunk of rmw_zenoh keys on humble (no REP-2016 type hashes there).
HUMBLE_TYPE_HASH = "TypeHashNotSupported"
#: The hash chunk that matches every type hash (inbound keys; rules made without a typestore).
ANY_TYPE_HASH = "*"


def dds_type_name(ros_type: str) -> str:
    """``pkg/msg/Name`` -> ``pkg::msg::dds_::Name_`` (the DDS type name of a ROS 2 type)."""
    pkg, kind, name = ros_type.split("/")
    return f"{pkg}::{kind}::dds_::{name}_"


def type_hash(ros_type: str, distro: str, typestore: object | None) -> str:
    """The hash chunk of an rmw_zenoh key: humble's marker on humble; else the ``RIHS01_...``
    hash from `typestore` (a rosbags typestore), or ``*`` (every hash) when it is None."""
    if distro == "humble":
        return HUMBLE_TYPE_HASH
    if typestore is None:
        return ANY_TYPE_HASH
    return str(typestore.hash_rihs01(ros_type))  # type: ignore[attr-defined]


def zenoh_key(topic: Ros2Topic, settings: Ros2Settings, typestore: object | None = None) -> str:
    """The Zenoh key (inbound: key expression) a topic entry uses (see the module doc).

    Args:
        topic: one ``[[ros2.topics]]`` entry.
        settings: the ``[ros2]`` section (default scheme, distro, domain id).
        typestore: a rosbags typestore for jazzy's type hashes of outbound rmw_zenoh keys
            (None: ``*`` in that chunk, a key expression covering the gateway's key; what
            the hub's access rules use, so the hub needs no typestore).
    """
    if topic.key is not None:
        return topic.key
    name = topic.topic.lstrip("/")
    scheme = topic.scheme or settings.scheme
    if scheme == "bridge_ros2dds":
        return name
    hash_chunk = (
        ANY_TYPE_HASH
        if topic.direction == "in"
        else type_hash(topic.type, settings.distro, typestore)
    )
    return f"{settings.domain_id}/{name}/{dds_type_name(topic.type)}/{hash_chunk}"
