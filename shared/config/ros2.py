"""Settings of the ros2_gateway: which ROS 2 topics cross between the stack and ROS 2 tools.

ROS 2 messages travel over Zenoh as CDR in two ways, and the gateway speaks both
(``scheme``, per topic or for the section):

* ``bridge_ros2dds`` (zenoh-bridge-ros2dds next to DDS nodes): the Zenoh key is the ROS
  topic name without its leading ``/`` (``/odom`` -> ``odom``); no type in the key, no
  attachment. A bridge ``namespace`` lives on the DDS side only.
* ``rmw_zenoh`` (nodes running ``RMW_IMPLEMENTATION=rmw_zenoh_cpp``): the key is
  ``<domain_id>/<topic without leading />/<DDS type name>/<type hash>``, e.g.
  ``0/odom/nav_msgs::msg::dds_::Odometry_/RIHS01_3cc9...``; the hash is the REP-2016
  ``RIHS01_`` hash of the type on ``jazzy`` (computed with rosbags) and
  ``TypeHashNotSupported`` on ``humble``. Inbound keys match any hash (``*``). Outbound
  samples carry rmw_zenoh's attachment (sequence number, source time, publisher GID).

``key`` on a topic replaces the computed key (any other bridge, a prefix of your own).

Each ``[[ros2.topics]]`` entry crosses one way (``direction``) between one ROS topic and one
native key of the contract (``native``)::

    in:  geometry_msgs/msg/PoseStamped             -> vehicle/pose
         geometry_msgs/msg/PoseWithCovarianceStamped -> vehicle/pose
         nav_msgs/msg/Odometry                      -> vehicle/odom or vehicle/pose
         sensor_msgs/msg/Imu                        -> vehicle/imu
         sensor_msgs/msg/LaserScan                  -> vehicle/scan
    out: state        -> nav_msgs/msg/Odometry
         planner/plan -> nav_msgs/msg/Path
         cmd/drive    -> ackermann_msgs/msg/AckermannDriveStamped

The three default outbound topics (``default_topics``: ``/odom``, ``/plan``, ``/drive``) stay
beside the configured ones: an entry with a default's ROS name (without the leading ``/``)
or Zenoh key replaces it, and ``defaults`` lists the ones kept (``[]``: none). After loading,
``topics`` holds every topic, the kept defaults after the configured ones. An outbound entry
without ``frame_id`` takes its native's (``DEFAULT_FRAME``: ``state`` and ``planner/plan`` in
``map``, ``cmd/drive`` in ``base_link``).

Stamps: ``header.stamp`` (sec, nanosec since the Unix epoch) is the stack's ``stamp_s`` (wall
clock) and back; ``stamp = "receive"`` on an inbound topic uses the gateway's clock at
arrival instead (for sources whose stamps are zero or on another clock). With ``header``,
a stamp older than ``max_stamp_age_s`` or further ahead than ``max_stamp_ahead_s`` at arrival
is dropped. Under ``rmw_zenoh`` the gateway announces itself as the ROS node ``node_name`` in
``namespace`` (rmw_zenoh's liveliness tokens).
"""

from __future__ import annotations

from collections.abc import Mapping
from types import MappingProxyType
from typing import Any, Literal

from pydantic import Field, model_validator

from shared.config.base import Section

__all__ = [
    "DEFAULT_FRAME",
    "DEFAULT_TOPIC_NAMES",
    "INBOUND",
    "OUTBOUND",
    "Ros2Settings",
    "Ros2Topic",
    "default_topics",
]

Scheme = Literal["bridge_ros2dds", "rmw_zenoh"]
RosType = Literal[
    "geometry_msgs/msg/PoseStamped",
    "geometry_msgs/msg/PoseWithCovarianceStamped",
    "nav_msgs/msg/Odometry",
    "sensor_msgs/msg/Imu",
    "sensor_msgs/msg/LaserScan",
    "nav_msgs/msg/Path",
    "ackermann_msgs/msg/AckermannDriveStamped",
]
Native = Literal[
    "vehicle/pose", "vehicle/odom", "vehicle/imu", "vehicle/scan", "state", "planner/plan",
    "cmd/drive",
]  # fmt: skip

#: The conversions the gateway has: (ROS type, native key) per direction.
INBOUND: frozenset[tuple[str, str]] = frozenset(
    {
        ("geometry_msgs/msg/PoseStamped", "vehicle/pose"),
        ("geometry_msgs/msg/PoseWithCovarianceStamped", "vehicle/pose"),
        ("nav_msgs/msg/Odometry", "vehicle/odom"),
        ("nav_msgs/msg/Odometry", "vehicle/pose"),
        ("sensor_msgs/msg/Imu", "vehicle/imu"),
        ("sensor_msgs/msg/LaserScan", "vehicle/scan"),
    }
)
OUTBOUND: frozenset[tuple[str, str]] = frozenset(
    {
        ("nav_msgs/msg/Odometry", "state"),
        ("nav_msgs/msg/Path", "planner/plan"),
        ("ackermann_msgs/msg/AckermannDriveStamped", "cmd/drive"),
    }
)

#: ``header.frame_id`` of an outbound topic without one, by native key: the pose and the
#: plan are in the map frame (Odometry's child frame is ``child_frame_id``, base_link); a
#: drive command is the car's own (base_link, as the F1TENTH VESC stack expects).
DEFAULT_FRAME: Mapping[str, str] = MappingProxyType(
    {"state": "map", "planner/plan": "map", "cmd/drive": "base_link"}
)
#: The default outbound topics (``[ros2] defaults`` names which of them are kept).
DEFAULT_TOPIC_NAMES: tuple[str, ...] = ("/odom", "/plan", "/drive")

_ROS_NAME = r"^/?[A-Za-z][A-Za-z0-9_]*(/[A-Za-z][A-Za-z0-9_]*)*$"
_FRAME = r"^[A-Za-z0-9_/.-]{0,128}$"


class Ros2Topic(Section):
    """One ROS 2 topic crossing the gateway (``[[ros2.topics]]``)."""

    topic: str = Field(pattern=_ROS_NAME, max_length=200, description="ROS topic, e.g. /odom")
    type: RosType = Field(description="ROS 2 message type (package/msg/Name)")
    direction: Literal["in", "out"] = Field(description="in: ROS -> stack; out: stack -> ROS")
    native: Native = Field(description="the native key below racestack/<car>/")
    scheme: Scheme | None = Field(None, description="key naming (None: [ros2] scheme)")
    key: str | None = Field(
        None,
        min_length=1,
        max_length=400,
        pattern=r"^[^\s#?$]+$",
        description="explicit Zenoh key (replaces the scheme's; inbound may use * and **)",
    )
    frame_id: str = Field(
        "map",
        pattern=_FRAME,
        description=(
            "outbound header.frame_id (default per native: state and planner/plan map, "
            "cmd/drive base_link)"
        ),
    )
    child_frame_id: str = Field(
        "base_link", pattern=_FRAME, description="outbound Odometry child_frame_id"
    )
    stamp: Literal["header", "receive"] = Field(
        "header", description="inbound stamp: header.stamp or the gateway's clock at arrival"
    )

    @model_validator(mode="before")
    @classmethod
    def _default_frame(cls, data: Any) -> Any:
        """An outbound entry without ``frame_id`` gets its native's (``DEFAULT_FRAME``)."""
        if isinstance(data, dict) and "frame_id" not in data:
            frame = DEFAULT_FRAME.get(str(data.get("native")))
            if frame is not None:
                data = {**data, "frame_id": frame}
        return data

    @model_validator(mode="after")
    def _check_pair(self) -> Ros2Topic:
        table = INBOUND if self.direction == "in" else OUTBOUND
        if (self.type, self.native) not in table:
            have = sorted(f"{t} <-> {n}" for t, n in table)
            raise ValueError(
                f"no {self.direction}bound conversion {self.type} <-> {self.native}; "
                f"the gateway has: {', '.join(have)}"
            )
        if self.key is not None and self.direction == "out" and any(c in self.key for c in "*"):
            raise ValueError("an outbound key cannot contain wildcards")
        return self


def default_topics() -> tuple[Ros2Topic, ...]:
    """The three default outbound topics: ``state`` on ``/odom`` (nav_msgs/Odometry, frame
    map, child base_link), ``planner/plan`` on ``/plan`` (nav_msgs/Path, map),
    ``cmd/drive`` on ``/drive`` (ackermann_msgs/AckermannDriveStamped, base_link)."""
    return (
        Ros2Topic(topic="/odom", type="nav_msgs/msg/Odometry", direction="out", native="state"),
        Ros2Topic(topic="/plan", type="nav_msgs/msg/Path", direction="out", native="planner/plan"),
        Ros2Topic(
            topic="/drive",
            type="ackermann_msgs/msg/AckermannDriveStamped",
            direction="out",
            native="cmd/drive",
        ),
    )


class Ros2Settings(Section):
    """The ros2_gateway's settings (``[ros2]``, topics as ``[[ros2.topics]]``)."""

    scheme: Scheme = Field("bridge_ros2dds", description="default key naming of the topics")
    distro: Literal["humble", "jazzy"] = Field(
        "humble", description="ROS 2 distribution of the message definitions and type hashes"
    )
    domain_id: int = Field(0, ge=0, le=232, description="ROS_DOMAIN_ID (rmw_zenoh keys)")
    topics: tuple[Ros2Topic, ...] = Field(
        (),
        max_length=64,
        description=(
            "the topics crossing besides the kept defaults (an entry with a default's ROS "
            "name or key replaces it); after loading: every topic, defaults included"
        ),
    )
    defaults: tuple[Literal["/odom", "/plan", "/drive"], ...] = Field(
        DEFAULT_TOPIC_NAMES,
        description="the default outbound topics kept (/odom, /plan, /drive; [] for none)",
    )
    queue_size: int = Field(
        256, ge=1, le=100_000, description="inbound samples waiting for the gateway's loop"
    )
    max_stamp_age_s: float = Field(
        5.0,
        gt=0.0,
        le=86_400.0,
        allow_inf_nan=False,
        description="inbound header stamps older than this at arrival are dropped [s]",
    )
    max_stamp_ahead_s: float = Field(
        0.5,
        gt=0.0,
        le=86_400.0,
        allow_inf_nan=False,
        description="inbound header stamps further ahead of the gateway's clock are dropped [s]",
    )
    node_name: str = Field(
        "racestack_gateway",
        pattern=r"^[A-Za-z][A-Za-z0-9_]{0,63}$",
        description="the ROS node name the gateway announces under rmw_zenoh",
    )
    namespace: str = Field(
        "/",
        pattern=r"^/([A-Za-z][A-Za-z0-9_]*(/[A-Za-z][A-Za-z0-9_]*)*)?$",
        max_length=200,
        description="the ROS namespace of that node (rmw_zenoh liveliness tokens)",
    )
    event_interval_s: float = Field(
        2.0,
        gt=0.0,
        le=3600.0,
        allow_inf_nan=False,
        description="shortest interval between two events/log records of one kind [s]",
    )

    @model_validator(mode="after")
    def _merge_defaults(self) -> Ros2Settings:
        """``topics`` = the configured entries, then each kept default that no entry replaces
        (same ROS name without its leading ``/``, or the same Zenoh key)."""
        from shared.ros2_keys import zenoh_key

        user = self.topics
        names = {t.topic.lstrip("/") for t in user}
        keys = {zenoh_key(t, self) for t in user}
        kept = tuple(
            d
            for d in default_topics()
            if d.topic in self.defaults
            and d.topic.lstrip("/") not in names
            and zenoh_key(d, self) not in keys
        )
        if kept:  # frozen: set once, here, before anything reads it
            object.__setattr__(self, "topics", user + kept)
        return self

    @model_validator(mode="after")
    def _check_unique(self) -> Ros2Settings:
        seen: set[tuple[str, str]] = set()
        for t in self.topics:
            ident = (t.direction, t.key or f"{t.scheme or self.scheme}:{t.topic.lstrip('/')}")
            if ident in seen:
                raise ValueError(f"topic {t.topic!r} ({t.direction}) is configured twice")
            seen.add(ident)
        both = {i for d, i in seen if d == "in"} & {i for d, i in seen if d == "out"}
        if both:
            raise ValueError(
                f"{sorted(both)} both in and out: the gateway would read back what it sends"
            )
        return self
