"""The ROS 2 gateway: ROS 2 topics as CDR over Zenoh <-> the stack's msgpack keys.

``python -m services.ros2_gateway --config FILE`` (or ``racestack run ros2_gateway``). Beside
zenoh-bridge-ros2dds or rmw_zenoh (``[ros2] scheme``), on the same Zenoh router as the stack,
it carries every ``[[ros2.topics]]`` entry one way:

* inbound (``direction = "in"``): the CDR samples on the topic's key (``naming.zenoh_key``)
  are decoded with rosbags, converted (``convert.to_native``) and published on the native key
  (``vehicle/pose``, ``vehicle/odom``, ``vehicle/imu``, ``vehicle/scan``), stamped with
  ``header.stamp``. A payload that is not CDR, is truncated, is of another type (bytes left
  over), has a bad stamp (negative, older than ``[ros2] max_stamp_age_s`` or further ahead
  than ``max_stamp_ahead_s`` of the gateway's clock), a pose without a heading (a zero
  quaternion) or values the contract rejects is dropped and counted per (ROS key, reason)
  in ``bus.drops``; the service's ``DropReporter`` says so on ``events/log``.
* outbound (``direction = "out"``): ``state``, ``planner/plan`` and ``cmd/drive`` records
  become ``nav_msgs/Odometry``, ``nav_msgs/Path`` and
  ``ackermann_msgs/AckermannDriveStamped`` in CDR on the topic's key (with rmw_zenoh's
  attachment under that scheme), so RViz, Foxglove and rosbag see the race. A ``state``
  with ``valid = false`` is not sent (counted: ``skipped_invalid``).
* under ``rmw_zenoh`` the gateway is a ROS node: it declares rmw_zenoh's liveliness tokens
  (``liveliness``: the node, one publisher per outbound and one subscription per inbound
  topic), so ``ros2 topic list`` and rviz2 find the topics (``graph_tokens``).

Threads: Zenoh's callback threads only enqueue (inbound payloads into a bounded queue that
drops the oldest, native records into their subscriptions' queues); the main thread
(``serve``) converts and publishes, and every ``period_s`` reports drops and faults.

The ROS keys are configuration, not contract: ``PORTS`` declares the native keys the
gateway may publish or subscribe to (it uses those of its configured topics); the ROS keys
it uses are listed by ``ros_keys()`` and logged at start.
"""

from __future__ import annotations

import argparse
import os
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

from services.ros2_gateway.convert import (
    CdrError,
    decode_cdr,
    encode_cdr,
    to_native,
    to_ros,
)
from services.ros2_gateway.liveliness import (
    PUBLISHER,
    SUBSCRIPTION,
    NodeId,
    endpoint_token,
    full_topic_name,
    node_token,
)
from services.ros2_gateway.naming import (
    GID_LEN,
    Attachment,
    dds_type_name,
    type_hash,
    uses_attachment,
    zenoh_key,
)
from services.ros2_gateway.raw import RawPublisher, RawSubscriber, RawToken, session_zid
from services.ros2_gateway.typestore import make_typestore
from shared.bus import Bus, DropOldestQueue, Subscription, TypedPublisher
from shared.car import CAR
from shared.config import RacestackConfig
from shared.config.ros2 import Ros2Settings, Ros2Topic
from shared.extras import require
from shared.keys import DRIVE_CMD, EVENTS_LOG, IMU, ODOM, PLAN, POSE, SCAN, STATE
from shared.messages import (
    DriveCmd,
    Imu,
    LogEvent,
    LogLevelName,
    MessageError,
    Odom,
    Plan,
    Pose,
    Scan,
    State,
)
from shared.service import Service, publishes, subscribes

#: Longest the main loop waits for an inbound payload before it looks at the outbound
#: queues [s] (the outbound latency bound).
LOOP_WAIT_S = 0.01
#: Records of one native key waiting to go out (the oldest dropped).
OUTBOUND_QUEUE = 64


@dataclass(slots=True)
class _Inbound:
    topic: Ros2Topic
    key: str
    pub: TypedPublisher[Any]
    sub: RawSubscriber | None = None
    received: int = 0
    published: int = 0


@dataclass(slots=True)
class _Outbound:
    topic: Ros2Topic
    key: str
    pub: RawPublisher
    sub: Subscription[Any]
    attach: bool
    gid: bytes = field(default_factory=lambda: os.urandom(GID_LEN))
    seq: int = 0
    published: int = 0
    skipped_invalid: int = 0


class Ros2GatewayService(Service):
    """The gateway (see the module docstring)."""

    NAME = "ros2_gateway"
    PORTS = (
        subscribes(STATE, State),
        subscribes(PLAN, Plan),
        subscribes(DRIVE_CMD, DriveCmd),
        publishes(POSE, Pose),
        publishes(ODOM, Odom),
        publishes(IMU, Imu),
        publishes(SCAN, Scan),
        publishes(EVENTS_LOG, LogEvent),
    )
    PERIOD_S = 0.2

    def __init__(
        self,
        settings: Ros2Settings,
        bus: Bus,
        *,
        wheelbase_m: float = CAR.wheelbase_m,
        session: Any = None,
        clock: Callable[[], float] = time.monotonic,
        wall_clock: Callable[[], float] = time.time,
    ) -> None:
        """Declare every configured topic's raw and native ends.

        Args:
            settings: the ``[ros2]`` section.
            bus: the service's open bus.
            wheelbase_m: the car's wheelbase [m] (inbound Odometry -> steering).
            session: the Zenoh session of the raw ROS keys (default: ``bus.session``).
            clock, wall_clock: monotonic [s] and wall clock [s] (arrival stamps).
        """
        super().__init__(
            bus,
            clock=clock,
            wall_clock=wall_clock,
            report_period_s=settings.event_interval_s,
            event_interval_s=settings.event_interval_s,
        )
        self.settings = settings
        self.wheelbase_m = wheelbase_m
        self.ts = make_typestore(settings.distro)
        self.session = bus.session if session is None else session
        self.inbox: DropOldestQueue[tuple[int, bytes, float]] = DropOldestQueue(settings.queue_size)
        self.inbound: list[_Inbound] = []
        self.outbound: list[_Outbound] = []
        for topic in settings.topics:
            key = zenoh_key(topic, settings, self.ts)
            if topic.direction == "in":
                route = _Inbound(topic, key, self.publisher(topic.native))
                index = len(self.inbound)
                self.inbound.append(route)
                route.sub = RawSubscriber(
                    self.session, key, lambda _k, p, i=index: self._enqueue(i, p)
                )
            else:
                self.outbound.append(
                    _Outbound(
                        topic,
                        key,
                        RawPublisher(self.session, key),
                        self.subscribe(topic.native, queue_size=OUTBOUND_QUEUE),
                        uses_attachment(topic, settings),
                    )
                )
        self.tokens: list[RawToken] = [RawToken(self.session, k) for k in self.graph_tokens()]

    def graph_tokens(self) -> list[str]:
        """rmw_zenoh's liveliness tokens of the gateway (``liveliness``): its node, then one
        publisher (outbound) or subscription (inbound) per topic of the ``rmw_zenoh`` scheme
        without an explicit ``key``; none when there is no such topic."""
        s = self.settings
        ros = [
            (i, t)
            for i, t in enumerate(s.topics)
            if (t.scheme or s.scheme) == "rmw_zenoh" and t.key is None
        ]
        if not ros:
            return []
        node = NodeId(s.domain_id, session_zid(self.session), s.node_name, s.namespace)
        tokens = [node_token(node)]
        for i, t in ros:
            kind = PUBLISHER if t.direction == "out" else SUBSCRIPTION
            tokens.append(
                endpoint_token(
                    node,
                    node.nid + 1 + i,
                    kind,
                    full_topic_name(t.topic),
                    dds_type_name(t.type),
                    type_hash(t.type, s.distro, self.ts),
                )
            )
        return tokens

    @classmethod
    def body(cls, cfg: RacestackConfig, args: argparse.Namespace, stop: threading.Event) -> int:
        """``Service.body`` once rosbags (the ``[ros2]`` extra) is there: without it, one line
        and exit code 2 (``shared.extras.MissingExtraError``) before the bus is opened."""
        require("rosbags")
        return super().body(cfg, args, stop)

    @classmethod
    def create(cls, cfg: RacestackConfig, args: argparse.Namespace, bus: Bus) -> Ros2GatewayService:
        """The gateway with ``[ros2]`` (the wheelbase of ``[vesc]``, the car's geometry)."""
        return cls(cfg.ros2, bus, wheelbase_m=cfg.vesc.wheelbase_m)

    def ros_keys(self) -> list[str]:
        """One line per topic: ``in <key> -> <native>`` / ``out <native> -> <key>``."""
        lines = [f"in  {r.key} ({r.topic.type}) -> {r.topic.native}" for r in self.inbound]
        lines += [f"out {r.topic.native} -> {r.key} ({r.topic.type})" for r in self.outbound]
        return lines

    # -- Zenoh thread --------------------------------------------------------------------
    def _enqueue(self, index: int, payload: bytes) -> None:
        self.inbox.put((index, payload, self.wall_clock()))

    # -- main thread ---------------------------------------------------------------------
    def handle_inbound(self, index: int, payload: bytes, receive_s: float) -> bool:
        """Decode, convert and publish one inbound payload; False when it was dropped."""
        route = self.inbound[index]
        route.received += 1
        try:
            ros = decode_cdr(self.ts, payload, route.topic.type)
            record = to_native(
                ros,
                route.topic,
                wheelbase_m=self.wheelbase_m,
                receive_s=receive_s,
                max_age_s=self.settings.max_stamp_age_s,
                max_ahead_s=self.settings.max_stamp_ahead_s,
            )
        except CdrError as exc:
            self.bus.drops.record(route.key, exc.reason, exc.detail)
            return False
        except MessageError as exc:
            self.bus.drops.record(route.key, exc.reason, str(exc)[:200])
            return False
        except Exception as exc:  # an attribute missing from an odd payload: still a drop
            self.bus.drops.record(route.key, "bad_cdr", f"{type(exc).__name__}: {exc}"[:200])
            return False
        route.pub.put(record)
        route.published += 1
        return True

    def pump_outbound(self) -> int:
        """Convert and publish every native record waiting; the number published."""
        n = 0
        for route in self.outbound:
            for record in route.sub.drain():
                if isinstance(record, State) and not record.valid:
                    route.skipped_invalid += 1  # the bridge has lost the car: no pose to show
                    continue
                with self.bus.faults.guard(route.key):
                    payload = encode_cdr(
                        self.ts, to_ros(self.ts, record, route.topic), route.topic.type
                    )
                    attachment = None
                    if route.attach:
                        route.seq += 1
                        attachment = Attachment(
                            route.seq, int(self.wall_clock() * 1e9), route.gid
                        ).encode()
                    try:
                        route.pub.put(payload, attachment)
                    except Exception as exc:  # the session closing under us while stopping
                        self.bus.faults.record(route.key, "put_failed", str(exc)[:200])
                        continue
                    route.published += 1
                    n += 1
        return n

    def serve(self, stop: threading.Event) -> int:
        """Carry the topics until ``stop`` is set (see the module docstring); 0."""
        self.log.info("ROS 2 gateway (%s, %s):", self.settings.scheme, self.settings.distro)
        for line in self.ros_keys():
            self.log.info("  %s", line)
        if not self.inbound and not self.outbound:
            self.say(LogLevelName.WARNING, "no [[ros2.topics]] configured: nothing to carry")
        next_poll = self.clock() + self.period_s
        while not stop.is_set():
            item = self.inbox.get(timeout_s=LOOP_WAIT_S)
            while item is not None:
                self.handle_inbound(*item)
                item = self.inbox.get()
            self.pump_outbound()
            now = self.clock()
            if now >= next_poll:
                next_poll = now + self.period_s
                self.poll()
        self.log.info("counters: %s", self.diagnostics())
        return 0

    def diagnostics(self) -> dict[str, int]:
        """Per-topic counts (``in.<key>.received/published``, ``out.<key>.published``)."""
        out: dict[str, int] = {}
        for r in self.inbound:
            out[f"in.{r.key}.received"] = r.received
            out[f"in.{r.key}.published"] = r.published
        for o in self.outbound:
            out[f"out.{o.key}.published"] = o.published
            if o.topic.native == "state":
                out[f"out.{o.key}.skipped_invalid"] = o.skipped_invalid
        out["inbox_dropped"] = self.inbox.dropped
        out["bus_drops"] = self.bus.drops.total
        out["own_faults"] = self.bus.faults.total
        return out


main = Ros2GatewayService.main
