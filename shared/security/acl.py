"""The hub's access rules in the secure profile, as Zenoh 1.x ``access_control`` data (pure).

Who may put what (ingress ``put`` on the hub, matched by the certificate's common name; every
other put is denied, ``default_permission = "deny"``):

| key (below ``racestack/<car>/``) | may put |
|---|---|
| ``vehicle/*`` (pose, imu, odom, scan) | simulator, vesc_driver, lidar_driver, ros2_gateway |
| ``state``, ``opponents`` | localization_bridge |
| ``cmd/drive``, ``planner/plan`` | planner |
| ``lap``, ``sim/truth`` | simulator |
| ``vesc/state`` | vesc_driver |
| ``sim/control`` | launcher, operator |
| ``events/log`` | every identity |

The keys of the ROS 2 topics (``[ros2]``, ``[[ros2.topics]]``; outside ``racestack/<car>/``,
named by ``shared.ros2_keys.zenoh_key`` exactly as the gateway names them, with ``*`` for
jazzy's type hash of an outbound rmw_zenoh key):

| ROS key | may put |
|---|---|
| each outbound topic's key (stack -> ROS; default ``odom``, ``plan``, ``drive``) | ros2_gateway |
| every inbound topic's key (ROS -> stack, e.g. ``pf/pose``) | ros2 (the ROS side) |

Every identity may declare subscribers on them, and the hub forwards puts and subscriber
declarations on them (egress). When a topic uses the ``rmw_zenoh`` scheme, rmw_zenoh's graph
``@ros2_lv/<domain>/**`` gets rules too: everyone may watch it and ask for it (liveliness
subscribers, queries on all of ``@ros2_lv/**``; forwarded with the tokens and replies), only
ros2_gateway and ros2 may declare tokens in the domain (the gateway's node and endpoints,
the ROS side's nodes). A ROS key that would reach into ``racestack/`` is refused
(``ValueError``): the ROS side must never get put rights on the stack's own keys.

Besides: every identity may declare subscribers and liveliness subscribers and make liveliness
queries on ``racestack/<car>/**`` (everyone may listen), and may declare only its own
liveliness token ``alive/<identity>`` (nobody can pretend another service is alive). What the
hub forwards to a session (egress: puts, subscriber and token declarations, liveliness
queries and replies) is allowed on ``racestack/<car>/**``. Queries, replies, queryables and
deletes from sessions are denied (the stack uses none). Each identity is exactly one subject,
so one decision is one line of Zenoh's access-control trace (``services.router`` counts the
denied ones).
"""

from __future__ import annotations

from collections.abc import Mapping
from types import MappingProxyType
from typing import TYPE_CHECKING, Any

from shared.keys import (
    DRIVE_CMD,
    EVENTS_LOG,
    IMU,
    LAP,
    ODOM,
    OPPONENTS,
    PLAN,
    POSE,
    SCAN,
    SIM_CONTROL,
    SIM_TRUTH,
    STATE,
    TELEPORT,
    TOPIC_TYPES,
    VESC_STATE,
    Keys,
)
from shared.security.identities import (
    IDENTITIES,
    PER_CAR_SERVICES,
    ROS2_IDENTITY,
    car_identity,
)

if TYPE_CHECKING:
    from shared.config.ros2 import Ros2Settings

#: The identities that may publish what a car's sensors measure.
VEHICLE_WRITERS: tuple[str, ...] = ("simulator", "vesc_driver", "lidar_driver", "ros2_gateway")

#: Key suffix -> identities allowed to put it (every key of ``shared.keys.TOPIC_TYPES``).
PUT_RIGHTS: Mapping[str, tuple[str, ...]] = MappingProxyType(
    {
        POSE: VEHICLE_WRITERS,
        IMU: VEHICLE_WRITERS,
        ODOM: VEHICLE_WRITERS,
        SCAN: VEHICLE_WRITERS,
        STATE: ("localization_bridge",),
        DRIVE_CMD: ("planner",),
        PLAN: ("planner",),
        LAP: ("simulator",),
        VESC_STATE: ("vesc_driver",),
        SIM_TRUTH: ("simulator",),
        SIM_CONTROL: ("launcher", "operator"),
        TELEPORT: ("simulator", "operator"),
        OPPONENTS: ("localization_bridge",),
        EVENTS_LOG: IDENTITIES,
    }
)

#: What every identity may do on ``racestack/<car>/**`` (ingress): listen.
LISTEN_MESSAGES: tuple[str, ...] = (
    "declare_subscriber",
    "declare_liveliness_subscriber",
    "liveliness_query",
)
#: What the hub may forward to any identity (egress) on ``racestack/<car>/**``.
FORWARD_MESSAGES: tuple[str, ...] = (
    "put",
    "declare_subscriber",
    "declare_liveliness_subscriber",
    "liveliness_token",
    "liveliness_query",
    "reply",
)


#: Who may put the ROS keys, by topic direction ("out": stack -> ROS, "in": ROS -> stack).
ROS2_WRITERS: Mapping[str, tuple[str, ...]] = MappingProxyType(
    {"out": ("ros2_gateway",), "in": (ROS2_IDENTITY,)}
)
#: What every identity may do on the ROS keys (ingress): subscribe.
ROS2_LISTEN_MESSAGES: tuple[str, ...] = ("declare_subscriber",)
#: What the hub may forward to any identity (egress) on the ROS keys.
ROS2_FORWARD_MESSAGES: tuple[str, ...] = ("put", "declare_subscriber")
#: Who may declare rmw_zenoh graph tokens (``@ros2_lv/<domain>/**``: the gateway's node
#: and endpoints, the ROS side's nodes).
ROS2_GRAPH_WRITERS: tuple[str, ...] = ("ros2_gateway", ROS2_IDENTITY)
#: What every identity may do on rmw_zenoh's graph (ingress): watch and ask for it.
ROS2_GRAPH_LISTEN_MESSAGES: tuple[str, ...] = ("declare_liveliness_subscriber", "liveliness_query")
#: What the hub may forward on it (egress): the tokens, the watchers, the queries, replies.
ROS2_GRAPH_FORWARD_MESSAGES: tuple[str, ...] = (
    "liveliness_token",
    "declare_liveliness_subscriber",
    "liveliness_query",
    "reply",
)


#: Every domain's graph: watching and asking (read only) is allowed on all of it, so that a
#: query of ``@ros2_lv/**`` (not only rmw_zenoh's own ``@ros2_lv/<domain>/**``) is not
#: denied; declaring tokens only in the configured domain.
ROS2_GRAPH_ALL = "@ros2_lv/**"


def ros2_graph_key(ros2: Ros2Settings) -> str | None:
    """The key expression of rmw_zenoh's liveliness tokens for `ros2`'s domain, or None when
    no topic uses the ``rmw_zenoh`` scheme (no graph to allow)."""
    if not any((t.scheme or ros2.scheme) == "rmw_zenoh" for t in ros2.topics):
        return None
    return f"@ros2_lv/{ros2.domain_id}/**"


#: The first chunk of every key of the stack (a ROS key must stay clear of it).
STACK_ROOT = "racestack"


def _key_problem(key: str) -> str | None:
    """Why `key` cannot be a ROS key of the rules (None: it can).

    A Zenoh key expression is ``/``-separated non-empty chunks, ``*`` (one chunk) and ``**``
    (any number of chunks) only as whole chunks here (``[[ros2.topics]] key`` has no ``$``).
    It intersects ``racestack/**`` iff its first chunk can be ``racestack``: that chunk is
    ``racestack``, ``*`` or ``**``.
    """
    chunks = key.split("/")
    if any(not c for c in chunks):
        return "has an empty chunk"
    if any("*" in c and c not in ("*", "**") for c in chunks):
        return "has a wildcard inside a chunk"
    if chunks[0] in (STACK_ROOT, "*", "**"):
        return f"reaches into {STACK_ROOT}/ (the stack's keys have their own rules)"
    return None


def ros2_keys(ros2: Ros2Settings) -> dict[str, tuple[str, ...]]:
    """The ROS keys of `ros2`'s topics by direction: ``{"in": (...), "out": (...)}``
    (key expressions in topic order, each once; ``shared.ros2_keys.zenoh_key`` without a
    typestore).

    Raises:
        ValueError: a key is not a key expression the rules take, or it intersects
            ``racestack/**`` (``_key_problem``).
    """
    from shared.ros2_keys import zenoh_key

    out: dict[str, list[str]] = {"in": [], "out": []}
    for topic in ros2.topics:
        key = zenoh_key(topic, ros2)
        problem = _key_problem(key)
        if problem is not None:
            raise ValueError(f"[[ros2.topics]] {topic.topic}: key {key!r} {problem}")
        if key not in out[topic.direction]:
            out[topic.direction].append(key)
    return {d: tuple(keys) for d, keys in out.items()}


def _rule_id(suffix: str) -> str:
    return "put_" + suffix.replace("/", "_")


def may_put(identity: str, suffix: str) -> bool:
    """True when `identity` may put on key `suffix` (the table above)."""
    return identity in PUT_RIGHTS.get(suffix, ())


def fleet_put_rights(identity: str, car: str, fleet: tuple[str, ...]) -> tuple[str, ...]:
    """The key suffixes `identity` may put below ``racestack/<car>/`` in a race of `fleet`:
    a per-car identity (``car_identity``: ``planner-car1``) its service's keys of its own
    car only; the plain name of a per-car service (``planner``) nothing there (every car's
    services have their car's identity); every other identity (simulator, launcher, ...)
    its keys of every car."""
    for service in PER_CAR_SERVICES:
        if identity == service:
            return ()
        for c in fleet:
            if identity == car_identity(service, c):
                return tuple(s for s in TOPIC_TYPES if may_put(service, s)) if c == car else ()
    return tuple(s for s in TOPIC_TYPES if may_put(identity, s))


def _alive_name(identity: str, car: str, fleet: tuple[str, ...]) -> str | None:
    """The service name whose token `identity` may declare below `car` (None: none)."""
    if not fleet:
        return identity
    for service in PER_CAR_SERVICES:
        if identity == service:
            return None
        if any(identity == car_identity(service, c) for c in fleet):
            return service if identity == car_identity(service, car) else None
    return identity


def access_control(
    car: str,
    identities: tuple[str, ...] = IDENTITIES,
    ros2: Ros2Settings | None = None,
    fleet: tuple[str, ...] = (),
) -> dict[str, Any]:
    """The ``access_control`` section of the hub's Zenoh config for `car` (JSON-able).

    Args:
        car: the car name (the ``<car>`` chunk of every key).
        identities: the certificate common names known to the rules (each one subject).
        ros2: the ``[ros2]`` section whose topics' keys get rules (None: no ROS keys, every
            put on them denied).
        fleet: the cars of a race of several cars (``[[cars]]``, `car` among them; empty:
            `car` alone). Then every car's keys get the rules, everyone may listen on all
            of them, and each car's bridge, planner and telemetry have their own identity
            (``shared.security.identities.car_identity``) that may put only their car's
            keys (``fleet_put_rights``): car1's planner drives only car1.

    Raises:
        ValueError: a key without put rights, or a bad ROS key (``ros2_keys``).
    """
    missing = set(TOPIC_TYPES) - set(PUT_RIGHTS)
    if missing:  # a new key must get its writers here
        raise ValueError(f"keys without put rights: {sorted(missing)}")
    if fleet and car not in fleet:
        raise ValueError(f"car {car!r} is not in the fleet {list(fleet)}")
    cars = tuple(fleet) or (car,)
    keys = Keys(car)
    everything = [f"{Keys(c).prefix}/**" for c in cars]
    rules: list[dict[str, Any]] = [
        {
            "id": "listen",
            "messages": list(LISTEN_MESSAGES),
            "flows": ["ingress"],
            "permission": "allow",
            "key_exprs": everything,
        },
        {
            "id": "forward",
            "messages": list(FORWARD_MESSAGES),
            "flows": ["egress"],
            "permission": "allow",
            "key_exprs": everything,
        },
    ]
    for suffix in TOPIC_TYPES:
        rules.append(
            {
                "id": _rule_id(suffix),
                "messages": ["put"],
                "flows": ["ingress"],
                "permission": "allow",
                "key_exprs": [keys.key(suffix)],
            }
        )
    for other in cars:  # the other cars' keys, each a rule of its own
        if other == car:
            continue
        for suffix in TOPIC_TYPES:
            rules.append(
                {
                    "id": f"{_rule_id(suffix)}_{other}",
                    "messages": ["put"],
                    "flows": ["ingress"],
                    "permission": "allow",
                    "key_exprs": [Keys(other).key(suffix)],
                }
            )
    shared_ros2: list[str] = []  # rule ids every identity gets
    ros2_put: dict[str, list[str]] = {}  # identity -> rule ids of its ROS puts
    if ros2 is not None:
        by_dir = ros2_keys(ros2)
        every_key = [*by_dir["out"], *by_dir["in"]]
        if every_key:
            rules.append(
                {
                    "id": "ros2_listen",
                    "messages": list(ROS2_LISTEN_MESSAGES),
                    "flows": ["ingress"],
                    "permission": "allow",
                    "key_exprs": every_key,
                }
            )
            rules.append(
                {
                    "id": "ros2_forward",
                    "messages": list(ROS2_FORWARD_MESSAGES),
                    "flows": ["egress"],
                    "permission": "allow",
                    "key_exprs": every_key,
                }
            )
            shared_ros2 = ["ros2_listen", "ros2_forward"]
        for direction, ros_keys in by_dir.items():
            if not ros_keys:
                continue
            rule_id = f"ros2_put_{direction}"
            rules.append(
                {
                    "id": rule_id,
                    "messages": ["put"],
                    "flows": ["ingress"],
                    "permission": "allow",
                    "key_exprs": list(ros_keys),
                }
            )
            for name in ROS2_WRITERS[direction]:
                ros2_put.setdefault(name, []).append(rule_id)
        graph = ros2_graph_key(ros2)
        if graph is not None:
            rules += [
                {
                    "id": "ros2_graph_listen",
                    "messages": list(ROS2_GRAPH_LISTEN_MESSAGES),
                    "flows": ["ingress"],
                    "permission": "allow",
                    "key_exprs": [ROS2_GRAPH_ALL],
                },
                {
                    "id": "ros2_graph_forward",
                    "messages": list(ROS2_GRAPH_FORWARD_MESSAGES),
                    "flows": ["egress"],
                    "permission": "allow",
                    "key_exprs": [ROS2_GRAPH_ALL],
                },
                {
                    "id": "ros2_graph_token",
                    "messages": ["liveliness_token"],
                    "flows": ["ingress"],
                    "permission": "allow",
                    "key_exprs": [graph],
                },
            ]
            shared_ros2 += ["ros2_graph_listen", "ros2_graph_forward"]
            for name in ROS2_GRAPH_WRITERS:
                ros2_put.setdefault(name, []).append("ros2_graph_token")
    policies: list[dict[str, Any]] = []
    for name in identities:
        tokens = [Keys(c).alive(a) for c in cars
                  if (a := _alive_name(name, c, tuple(fleet))) is not None]
        rules.append(
            {
                "id": f"alive_{name}",
                "messages": ["liveliness_token"],
                "flows": ["ingress"],
                "permission": "allow",
                "key_exprs": tokens or [keys.alive(name)],
                **({} if tokens else {"permission": "deny"}),
            }
        )
        if fleet:
            own = [_rule_id(s) if c == car else f"{_rule_id(s)}_{c}"
                   for c in cars for s in fleet_put_rights(name, c, tuple(fleet))]
        else:
            own = [_rule_id(s) for s in TOPIC_TYPES if may_put(name, s)]
        policies.append(
            {
                "id": f"policy_{name}",
                "rules": [
                    "listen", "forward", f"alive_{name}", *own, *shared_ros2,
                    *ros2_put.get(name, []),
                ],
                "subjects": [name],
            }
        )
    return {
        "enabled": True,
        "default_permission": "deny",
        "rules": rules,
        "subjects": [{"id": name, "cert_common_names": [name]} for name in identities],
        "policies": policies,
    }
