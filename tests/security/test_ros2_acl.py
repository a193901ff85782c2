"""The hub's rules for the ROS 2 topics (pure): who puts which ROS key, who listens."""

from __future__ import annotations

from typing import Any

import pytest

from services.ros2_gateway.typestore import make_typestore
from services.router.service import hub_settings
from shared.config import ConfigError, config_from_dict
from shared.config.ros2 import Ros2Settings
from shared.ros2_keys import HUMBLE_TYPE_HASH, zenoh_key
from shared.security import IDENTITIES, access_control
from shared.security.acl import ros2_keys
from shared.security.identities import ROS2_IDENTITY

POSE_IN = {
    "topic": "/pf/pose",
    "type": "geometry_msgs/msg/PoseStamped",
    "direction": "in",
    "native": "vehicle/pose",
}
IMU_IN = {
    "topic": "/sensors/imu",
    "type": "sensor_msgs/msg/Imu",
    "direction": "in",
    "native": "vehicle/imu",
    "scheme": "rmw_zenoh",
}
PLAN_OUT = {
    "topic": "/plan",
    "type": "nav_msgs/msg/Path",
    "direction": "out",
    "native": "planner/plan",
    "scheme": "rmw_zenoh",
}


def rules_and_policies(acl: dict[str, Any]) -> tuple[dict[str, Any], dict[str, list[str]]]:
    rules = {r["id"]: r for r in acl["rules"]}
    return rules, {p["subjects"][0]: p["rules"] for p in acl["policies"]}


def put_rights(acl: dict[str, Any], key: str) -> list[str]:
    """The identities with an ingress put rule naming exactly `key`."""
    rules, pol = rules_and_policies(acl)
    return sorted(
        name
        for name, ids in pol.items()
        if any(
            key in rules[i]["key_exprs"] and "put" in rules[i]["messages"]
            and rules[i]["flows"] == ["ingress"]
            for i in ids
        )
    )


def test_the_ros_side_has_its_own_certificate() -> None:
    assert ROS2_IDENTITY == "ros2" and ROS2_IDENTITY in IDENTITIES


def test_default_topics_only_the_gateway_puts_odom_plan_drive() -> None:
    ros2 = Ros2Settings()
    assert ros2_keys(ros2) == {"in": (), "out": ("odom", "plan", "drive")}
    acl = access_control("car0", ros2=ros2)
    assert acl["default_permission"] == "deny"
    rules, pol = rules_and_policies(acl)
    assert "ros2_put_in" not in rules  # nothing inbound: nobody may put a ROS key in
    for key in ("odom", "plan", "drive"):
        assert put_rights(acl, key) == ["ros2_gateway"]
    assert rules["ros2_listen"] == {
        "id": "ros2_listen", "messages": ["declare_subscriber"], "flows": ["ingress"],
        "permission": "allow", "key_exprs": ["odom", "plan", "drive"],
    }
    assert rules["ros2_forward"]["flows"] == ["egress"]
    assert set(rules["ros2_forward"]["messages"]) == {"put", "declare_subscriber"}
    for name in IDENTITIES:  # everyone may subscribe; the hub forwards to everyone
        assert {"ros2_listen", "ros2_forward"} <= set(pol[name])
        assert set(pol[name]) <= set(rules)
    # the stack's own keys are untouched: the ROS side may not drive the car
    assert put_rights(acl, "racestack/car0/cmd/drive") == ["planner"]
    assert put_rights(acl, "racestack/car0/vehicle/pose") == [
        "lidar_driver", "ros2_gateway", "simulator", "vesc_driver",
    ]


def test_without_ros2_settings_no_ros_key_is_allowed() -> None:
    rules, _ = rules_and_policies(access_control("car0"))
    assert not [r for r in rules if r.startswith("ros2_")]


def test_an_inbound_topic_is_put_by_the_ros_side_only() -> None:
    ros2 = Ros2Settings.model_validate({"topics": [POSE_IN, IMU_IN, PLAN_OUT]})
    imu = "0/sensors/imu/sensor_msgs::msg::dds_::Imu_/*"
    plan = f"0/plan/nav_msgs::msg::dds_::Path_/{HUMBLE_TYPE_HASH}"
    # the default /odom and /drive stay beside the configured /plan
    assert ros2_keys(ros2) == {"in": ("pf/pose", imu), "out": (plan, "odom", "drive")}
    acl = access_control("car0", ros2=ros2)
    assert put_rights(acl, "pf/pose") == ["ros2"] == put_rights(acl, imu)
    assert put_rights(acl, plan) == ["ros2_gateway"]
    rules, pol = rules_and_policies(acl)
    assert "ros2_put_in" not in pol["telemetry"] and "ros2_put_in" not in pol["ros2_gateway"]
    assert rules["ros2_listen"]["key_exprs"] == [plan, "odom", "drive", "pf/pose", imu]
    # the gateway subscribes to and publishes on exactly the keys of the rules
    ts = make_typestore("humble")
    assert [zenoh_key(t, ros2, ts) for t in ros2.topics[:3]] == ["pf/pose", imu, plan]


def test_jazzy_outbound_hash_is_a_wildcard_in_the_rules_covering_the_gateway_s_key() -> None:
    ros2 = Ros2Settings.model_validate({"distro": "jazzy", "topics": [PLAN_OUT], "defaults": []})
    (rule_key,) = ros2_keys(ros2)["out"]
    gw_key = zenoh_key(ros2.topics[0], ros2, make_typestore("jazzy"))
    assert rule_key == "0/plan/nav_msgs::msg::dds_::Path_/*"
    head, _, tail = gw_key.rpartition("/")
    assert head == rule_key[:-2] and tail.startswith("RIHS01_")


@pytest.mark.parametrize("key", ["racestack/car0/cmd/drive", "**", "*/car0/state", "a//b",
                                 "ros/x*"])
def test_a_ros_key_into_the_stack_or_malformed_is_refused(key: str) -> None:
    topic = {**POSE_IN, "key": key}
    ros2 = Ros2Settings.model_validate({"topics": [topic]})
    with pytest.raises(ValueError, match=r"\[\[ros2.topics\]\] /pf/pose: key"):
        access_control("car0", ros2=ros2)
    cfg = config_from_dict({"bus": {"security": "mtls", "certs_dir": "/c"},
                            "ros2": {"topics": [topic]}})
    with pytest.raises(ConfigError, match="secure profile"):
        hub_settings(cfg)


def test_the_router_s_session_carries_the_configured_topics() -> None:
    cfg = config_from_dict({"bus": {"security": "mtls", "certs_dir": "/c", "car": "c9"},
                            "ros2": {"topics": [POSE_IN]}})
    hub = hub_settings(cfg)
    plan = hub.session_plan(listen_default=True, service="router")
    assert plan.access_control is not None
    assert put_rights(plan.access_control, "pf/pose") == ["ros2"]
    assert put_rights(plan.access_control, "racestack/c9/state") == ["localization_bridge"]
    # other sessions of the same settings get no rules; the plain profile is untouched
    assert hub.session_plan(listen_default=False, service="planner").access_control is None
    plain = config_from_dict({"ros2": {"topics": [POSE_IN]}})
    assert hub_settings(plain) is plain.bus


def test_rmw_zenoh_graph_tokens_only_from_the_gateway_and_the_ros_side() -> None:
    """With an rmw_zenoh topic, ``@ros2_lv/<domain>/**``: everyone may watch and query it,
    only ros2_gateway and ros2 declare tokens; without one, no graph rule at all."""
    ros2 = Ros2Settings.model_validate({"domain_id": 4, "topics": [IMU_IN]})
    rules, pol = rules_and_policies(access_control("car0", ros2=ros2))
    assert rules["ros2_graph_token"]["key_exprs"] == ["@ros2_lv/4/**"]
    assert rules["ros2_graph_token"]["messages"] == ["liveliness_token"]
    writers = sorted(n for n, ids in pol.items() if "ros2_graph_token" in ids)
    assert writers == ["ros2", "ros2_gateway"]
    assert all("ros2_graph_listen" in ids and "ros2_graph_forward" in ids for ids in pol.values())
    assert "liveliness_token" not in rules["ros2_graph_listen"]["messages"]
    assert rules["ros2_graph_listen"]["key_exprs"] == ["@ros2_lv/**"]  # watching: any domain
    plain, _ = rules_and_policies(access_control("car0", ros2=Ros2Settings()))
    assert not any(r.startswith("ros2_graph") for r in plain)
