"""BusSettings: validation, defaults (loopback only, no multicast) and per-service plans."""

from __future__ import annotations

import json

import pytest
from pydantic import ValidationError

from shared.config.bus import (
    DEFAULT_HUB_ENDPOINT,
    BusSettings,
    SessionPlan,
    connectable,
    parse_endpoint,
)


def test_defaults_are_loopback_without_multicast() -> None:
    b = BusSettings()
    assert b.car == "car0" and b.mode == "peer"
    assert b.listen == [DEFAULT_HUB_ENDPOINT] == ["tcp/127.0.0.1:7447"]
    assert b.connect == [] and b.multicast_scouting is False
    hub = b.session_plan(listen_default=True)
    other = b.session_plan(listen_default=False)
    assert hub == SessionPlan("peer", ("tcp/127.0.0.1:7447",), (), False, True)
    assert other == SessionPlan("peer", ("tcp/127.0.0.1:0",), ("tcp/127.0.0.1:7447",), False, True)
    for plan in (hub, other):
        assert all(parse_endpoint(e).is_loopback for e in plan.listen + plan.connect)


def test_zenoh_entries_are_json() -> None:
    entries = BusSettings().session_plan(listen_default=False).zenoh_entries()
    assert json.loads(entries["scouting/multicast/enabled"]) is False
    assert json.loads(entries["listen/endpoints"]) == ["tcp/127.0.0.1:0"]
    assert json.loads(entries["connect/endpoints"]) == ["tcp/127.0.0.1:7447"]
    assert json.loads(entries["mode"]) == "peer"


@pytest.mark.parametrize("car", ["car0", "Car_1", "my-car", "a" * 64])
def test_car_names_accepted(car: str) -> None:
    assert BusSettings(car=car).car == car


@pytest.mark.parametrize("car", ["", "car/0", "car*", "car 0", "$car", "ü", "a" * 65, "**"])
def test_unsafe_car_names_rejected(car: str) -> None:
    with pytest.raises(ValidationError):
        BusSettings(car=car)


@pytest.mark.parametrize(
    "endpoint",
    [
        "tcp/127.0.0.1:7447",
        "udp/127.0.0.1:7447",
        "tcp/[::1]:7447",
        "tcp/0.0.0.0:7447",
        "tcp/car0.local:7447",
        "tcp/localhost:0",
    ],
)
def test_good_listen_endpoints(endpoint: str) -> None:
    assert BusSettings(listen=[endpoint], connect=["tcp/127.0.0.1:1"]).listen == [endpoint]


@pytest.mark.parametrize(
    "endpoint",
    [
        "127.0.0.1:7447",
        "tcp/127.0.0.1",
        "tcp/127.0.0.1:99999",
        "tcp/256.0.0.1:7447",
        "tcp/[::zz]:7447",
        "quic/127.0.0.1:7447",
        "tcp/127.0.0.1:7447?iface=lo",
        "tcp/127.0.0.1:7447#x",
        "tcp/bad_host:7447",
        "tcp/-x:1",
        " tcp/127.0.0.1:7447",
        "",
    ],
)
def test_bad_endpoints_rejected(endpoint: str) -> None:
    with pytest.raises(ValidationError):
        BusSettings(listen=[endpoint])
    with pytest.raises(ValidationError):
        BusSettings(connect=[endpoint])
    with pytest.raises(ValidationError):
        BusSettings(local_listen=[endpoint])


def test_connect_to_port_zero_rejected() -> None:
    with pytest.raises(ValidationError):
        BusSettings(connect=["tcp/127.0.0.1:0"])
    with pytest.raises(ValidationError, match="nobody could reach the hub"):
        BusSettings(listen=["tcp/127.0.0.1:0"])


def test_unknown_keys_and_mutation_rejected() -> None:
    with pytest.raises(ValidationError):
        BusSettings.model_validate({"car": "car0", "scouting": True})
    with pytest.raises(ValidationError):
        BusSettings(mode="server")  # type: ignore[arg-type]
    with pytest.raises(ValidationError):
        BusSettings().car = "x"  # type: ignore[misc]


def test_wildcard_listen_becomes_loopback_to_connect() -> None:
    assert connectable("tcp/0.0.0.0:7447") == "tcp/127.0.0.1:7447"
    assert connectable("tcp/[::]:7447") == "tcp/[::1]:7447"
    assert connectable("tcp/10.0.0.2:7447") == "tcp/10.0.0.2:7447"
    b = BusSettings(listen=["tcp/0.0.0.0:7447"])
    assert b.session_plan(listen_default=False).connect == ("tcp/127.0.0.1:7447",)


def test_gossip_auto_only_when_listening_on_loopback() -> None:
    b = BusSettings(listen=["tcp/0.0.0.0:7447"])
    assert b.session_plan(listen_default=True).gossip is False
    assert b.session_plan(listen_default=False).gossip is True  # local_listen is loopback
    assert BusSettings(gossip=False).session_plan(listen_default=False).gossip is False


def test_client_listens_nowhere() -> None:
    plan = BusSettings(mode="client").session_plan(listen_default=False)
    assert plan.mode == "client" and plan.listen == () and plan.connect == (DEFAULT_HUB_ENDPOINT,)


def test_hub_never_connects_to_itself() -> None:
    b = BusSettings(connect=["tcp/127.0.0.1:7447", "tcp/10.0.0.9:7447"])
    assert b.session_plan(listen_default=True).connect == ("tcp/10.0.0.9:7447",)
    assert b.session_plan(listen_default=False).connect == tuple(b.connect)


def test_multi_machine_is_configuration() -> None:
    car = BusSettings.model_validate(
        {"listen": ["tcp/0.0.0.0:7447"], "services": {"router": {"mode": "router"}}}
    )
    router = car.session_plan(listen_default=True, service="router")
    assert router.mode == "router" and router.listen == ("tcp/0.0.0.0:7447",)
    assert router.gossip is False  # would advertise non-loopback addresses
    planner = car.session_plan(listen_default=False, service="planner")
    assert planner.connect == ("tcp/127.0.0.1:7447",)
    laptop = BusSettings(mode="client", connect=["tcp/192.168.1.10:7447"])
    tele = laptop.session_plan(listen_default=False, service="telemetry")
    assert tele.mode == "client" and tele.connect == ("tcp/192.168.1.10:7447",)
    assert tele.multicast_scouting is False


def test_per_service_override_wins() -> None:
    b = BusSettings.model_validate(
        {
            "services": {
                "simulator": {"listen_default": False},
                "launcher": {"listen_default": True, "mode": "router"},
                "telemetry": {"connect": ["tcp/127.0.0.1:9000"], "local_listen": []},
            }
        }
    )
    assert b.session_plan(listen_default=True, service="simulator").listen == ("tcp/127.0.0.1:0",)
    launcher = b.session_plan(listen_default=False, service="launcher", mode="peer")
    assert launcher.mode == "router" and launcher.listen == ("tcp/127.0.0.1:7447",)
    tele = b.session_plan(listen_default=False, service="telemetry")
    assert tele.connect == ("tcp/127.0.0.1:9000",) and tele.listen == ()
    # a built-in mode applies when no override says otherwise
    assert b.session_plan(listen_default=True, service="x", mode="router").mode == "router"


def test_bad_override_rejected() -> None:
    with pytest.raises(ValidationError):
        BusSettings.model_validate({"services": {"bad/name": {}}})
    with pytest.raises(ValidationError):
        BusSettings.model_validate({"services": {"planner": {"connect": ["x"]}}})
    with pytest.raises(ValidationError):
        BusSettings.model_validate({"services": {"planner": {"unknown": 1}}})
