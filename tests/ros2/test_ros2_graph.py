"""The gateway's rmw_zenoh graph over real Zenoh (loopback, in process): what ``ros2 topic
list`` and rmw_zenoh's graph cache see.

A hub (router) and the gateway (a peer session connected to it) run in this process; a
third session asks ``liveliness().get("@ros2_lv/**")`` as rmw_zenoh's graph cache does at
start. It must see the gateway's node and one publisher per outbound topic (and one
subscription per inbound one) with the ROS names and DDS types, the type hash of the data
key; the tokens go when the gateway's session closes.
"""

from __future__ import annotations

import time
from collections.abc import Iterator
from typing import Any

import pytest

from services.ros2_gateway import Ros2GatewayService
from services.ros2_gateway.liveliness import Token, parse_token
from shared.bus import Bus
from shared.config import config_from_dict
from shared.net import free_loopback_port

WAIT_S = 10.0


def graph(session: Any) -> list[Token]:
    """Every rmw_zenoh token the network answers for (a liveliness query)."""
    out = []
    for reply in session.liveliness().get("@ros2_lv/**", timeout=2.0):
        if reply.ok is not None:
            tok = parse_token(str(reply.ok.key_expr))
            assert tok is not None, str(reply.ok.key_expr)
            out.append(tok)
    return out


def wait_graph(session: Any, n: int) -> list[Token]:
    deadline = time.monotonic() + WAIT_S
    tokens = graph(session)
    while len(tokens) != n and time.monotonic() < deadline:
        time.sleep(0.1)
        tokens = graph(session)
    return tokens


@pytest.fixture
def buses() -> Iterator[tuple[Bus, Any]]:
    port = free_loopback_port()
    cfg = config_from_dict(
        {
            "bus": {"listen": [f"tcp/127.0.0.1:{port}"]},
            "ros2": {
                "scheme": "rmw_zenoh",
                "distro": "jazzy",
                "topics": [
                    {
                        "topic": "/pf/pose",
                        "type": "geometry_msgs/msg/PoseStamped",
                        "direction": "in",
                        "native": "vehicle/pose",
                    }
                ],
            },
        }
    )
    with Bus(cfg.bus, "test", listen_default=True, mode="router") as hub:
        gw_bus = Bus(cfg.bus, "ros2_gateway")
        try:
            yield gw_bus, (hub, cfg)
        finally:
            gw_bus.close()


def test_a_liveliness_query_sees_the_node_and_its_topics(buses: tuple[Bus, Any]) -> None:
    gw_bus, (hub, cfg) = buses
    svc = Ros2GatewayService(cfg.ros2, gw_bus)
    tokens = wait_graph(hub.session, 5)
    kinds = sorted((t.kind, t.topic, t.dds_type) for t in tokens)
    assert kinds == [
        ("MP", "/drive", "ackermann_msgs::msg::dds_::AckermannDriveStamped_"),
        ("MP", "/odom", "nav_msgs::msg::dds_::Odometry_"),
        ("MP", "/plan", "nav_msgs::msg::dds_::Path_"),
        ("MS", "/pf/pose", "geometry_msgs::msg::dds_::PoseStamped_"),
        ("NN", None, None),
    ], kinds
    (node,) = [t for t in tokens if t.kind == "NN"]
    assert node.node == "racestack_gateway" and node.namespace == "/"
    assert {t.zid for t in tokens} == {str(gw_bus.session.info.zid())}
    assert len({t.eid for t in tokens}) == 5
    keys = {o.topic.topic: o.key for o in svc.outbound}
    for t in tokens:
        if t.kind == "MP":  # the token names the data key the gateway publishes on
            assert keys[t.topic] == f"0/{t.topic[1:]}/{t.dds_type}/{t.type_hash}"
            assert t.type_hash.startswith("RIHS01_")
    gw_bus.close()
    assert wait_graph(hub.session, 0) == []
