"""rmw_zenoh's graph: the liveliness tokens that make the gateway a ROS 2 node (pure, no I/O).

rmw_zenoh_cpp (the Zenoh 1.x versions: humble 0.1, jazzy 0.2, kilted 0.4) keeps no
discovery of its own: every node, publisher and subscription declares a Zenoh liveliness
token, and each process's graph cache asks for them (a liveliness query on
``@ros2_lv/<domain>/**`` at start, a liveliness subscriber after). ``ros2 node list``,
``ros2 topic list``, ``ros2 topic echo`` without a type and rviz2's topic lists are built
from these tokens alone; data keys without a token are invisible to them. The format (read
in rmw_zenoh's ``liveliness_utils.cpp``)::

    @ros2_lv/<domain>/<zid>/<nid>/<eid>/NN/<enclave>/<namespace>/<node>
    @ros2_lv/<domain>/<zid>/<nid>/<eid>/MP|MS/<enclave>/<namespace>/<node>/<topic>/<type>/<hash>/<qos>

* ``zid``: the Zenoh session id (hex, as Zenoh prints it); ``nid``: the node's id, ``eid``
  the entity's (one counter per process: the node 0, its endpoints 1, 2, ...).
* ``enclave``, ``namespace``, ``node``, ``topic``, ``type``, ``hash``: the names with every
  ``/`` replaced by ``%`` (``mangle``): the root namespace ``/`` is ``%``, ``/odom`` is
  ``%odom``; ``type`` is the DDS type name (``nav_msgs::msg::dds_::Odometry_``), ``hash``
  the type hash chunk of the data key (``RIHS01_...`` on jazzy, ``TypeHashNotSupported`` on
  humble).
* ``qos``: ``reliability:durability:history,depth:deadline_s,deadline_ns:lifespan_s,
  lifespan_ns:liveliness,lease_s,lease_ns`` with the rmw enum values (an empty field is
  rmw_zenoh's default). The gateway announces RELIABLE (1), VOLATILE (2), KEEP_LAST (1)
  depth 10: ``1:2:1,10:,:,:,,`` (``QOS``).
"""

from __future__ import annotations

from dataclasses import dataclass

#: The liveliness admin space of rmw_zenoh.
ADMIN_SPACE = "@ros2_lv"
#: Entity kinds: node, message publisher, message subscription.
NODE, PUBLISHER, SUBSCRIPTION = "NN", "MP", "MS"
#: The QoS chunk of the gateway's endpoints (see the module docstring).
QOS = "1:2:1,10:,:,:,,"
#: The enclave of a node started without ``--enclave`` (rcl's default).
DEFAULT_ENCLAVE = "/"


def mangle(name: str) -> str:
    """``/`` -> ``%`` (a name as one key chunk; ``/`` alone becomes ``%``)."""
    return name.replace("/", "%")


def demangle(chunk: str) -> str:
    """``%`` -> ``/`` (the inverse of ``mangle``)."""
    return chunk.replace("%", "/")


def full_topic_name(topic: str) -> str:
    """The fully qualified ROS name of a configured topic (``odom`` and ``/odom`` are both
    ``/odom``: the gateway's topic names are absolute, as its data keys are)."""
    return "/" + topic.lstrip("/")


@dataclass(frozen=True, slots=True)
class NodeId:
    """Who announces: the domain, the Zenoh session id and the node's names.

    Attributes:
        domain_id: ROS_DOMAIN_ID.
        zid: the Zenoh session id as a hex string.
        name: the node name.
        namespace: the node namespace ("/" for the root).
        enclave: the security enclave ("/" by default).
        nid: the node's entity id (0: the first entity of the process).
    """

    domain_id: int
    zid: str
    name: str
    namespace: str = "/"
    enclave: str = DEFAULT_ENCLAVE
    nid: int = 0

    def prefix(self, eid: int, kind: str) -> str:
        """The token up to and including the node name."""
        return "/".join(
            (
                ADMIN_SPACE,
                str(self.domain_id),
                self.zid,
                str(self.nid),
                str(eid),
                kind,
                mangle(self.enclave),
                mangle(self.namespace),
                mangle(self.name),
            )
        )


def node_token(node: NodeId) -> str:
    """The node's own token (kind ``NN``, entity id = node id)."""
    return node.prefix(node.nid, NODE)


def endpoint_token(
    node: NodeId, eid: int, kind: str, topic: str, dds_type: str, type_hash: str, qos: str = QOS
) -> str:
    """The token of a publisher (``MP``) or subscription (``MS``) of `node`.

    Args:
        node: the node it belongs to.
        eid: its entity id (distinct from every other entity of the process).
        kind: ``PUBLISHER`` or ``SUBSCRIPTION``.
        topic: the fully qualified topic name (``/odom``).
        dds_type: the DDS type name (``nav_msgs::msg::dds_::Odometry_``).
        type_hash: ``RIHS01_...`` or ``TypeHashNotSupported``.
        qos: the QoS chunk.
    """
    if kind not in (PUBLISHER, SUBSCRIPTION):
        raise ValueError(f"an endpoint is {PUBLISHER} or {SUBSCRIPTION}, not {kind!r}")
    return "/".join(
        (node.prefix(eid, kind), mangle(topic), mangle(dds_type), mangle(type_hash), qos)
    )


@dataclass(frozen=True, slots=True)
class Token:
    """A parsed rmw_zenoh liveliness token (what a graph cache reads from it).

    Attributes:
        domain_id, zid, nid, eid, kind: the chunks after the admin space.
        enclave, namespace, node: demangled names.
        topic, dds_type, type_hash, qos: the endpoint's (None for a node).
    """

    domain_id: int
    zid: str
    nid: str
    eid: str
    kind: str
    enclave: str
    namespace: str
    node: str
    topic: str | None = None
    dds_type: str | None = None
    type_hash: str | None = None
    qos: str | None = None


def parse_token(key: str) -> Token | None:
    """The token `key` names, or None when it is not a well-formed rmw_zenoh token (the
    checks rmw_zenoh's ``Entity::make`` makes: the admin space, 9 non-empty chunks for a node,
    13 for an endpoint, a known kind, a QoS chunk of 6 ``:``-separated parts)."""
    parts = key.split("/")
    if len(parts) < 9 or parts[0] != ADMIN_SPACE or any(not p for p in parts):
        return None
    kind = parts[5]
    if kind not in (NODE, PUBLISHER, SUBSCRIPTION, "SS", "SC") or not parts[1].isdigit():
        return None
    base = dict(
        domain_id=int(parts[1]),
        zid=parts[2],
        nid=parts[3],
        eid=parts[4],
        kind=kind,
        enclave=demangle(parts[6]),
        namespace=demangle(parts[7]),
        node=demangle(parts[8]),
    )
    if kind == NODE:
        return Token(**base) if len(parts) == 9 else None  # type: ignore[arg-type]
    if len(parts) != 13 or len(parts[12].split(":")) < 6:
        return None
    return Token(
        **base,  # type: ignore[arg-type]
        topic=demangle(parts[9]),
        dds_type=demangle(parts[10]),
        type_hash=demangle(parts[11]),
        qos=parts[12],
    )
