"""The secure profile without processes: config pairs, access rules, denial parsing."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from services.localization_bridge.service import BridgeService
from services.planner.service import PlannerShell
from services.router.denials import (
    CONNECT_DENIED,
    UNKNOWN_CN,
    Denial,
    DenialParser,
    growth_text,
)
from services.router.service import Router
from services.simulator.service import SimulatorService
from services.telemetry.service import TelemetryService
from services.tools.launcher.up import Launcher
from services.vesc_driver.service import VescService
from shared.config import ConfigError, config_from_dict
from shared.keys import DRIVE_CMD, SIM_CONTROL, STATE, TOPIC_TYPES, Keys
from shared.security import IDENTITIES, PUT_RIGHTS, access_control, may_put
from shared.service import Direction

TRACE = Path(__file__).parent / "data" / "acl_trace_1.10.2.txt"
SERVICES = (SimulatorService, BridgeService, PlannerShell, VescService, TelemetryService,
            Router, Launcher)


def bus(**kw):
    return config_from_dict({"bus": {"security": "mtls", "certs_dir": "/c", **kw}}).bus


def test_default_profile_is_plain_and_unchanged() -> None:
    b = config_from_dict({}).bus
    assert b.security == "none" and b.certs_dir == "certs"
    e = b.session_plan(listen_default=False, service="planner").zenoh_entries()
    assert not any(k.startswith(("transport/", "access_control")) for k in e)
    assert json.loads(e["connect/endpoints"]) == ["tcp/127.0.0.1:7447"]


def test_client_pairs_in_mtls() -> None:
    e = bus().session_plan(listen_default=False, service="planner").zenoh_entries()
    assert json.loads(e["mode"]) == "client"
    assert json.loads(e["listen/endpoints"]) == []
    assert json.loads(e["connect/endpoints"]) == ["tls/127.0.0.1:7447"]
    assert json.loads(e["scouting/gossip/enabled"]) is False
    assert json.loads(e["scouting/multicast/enabled"]) is False
    tls = "transport/link/tls/"
    assert json.loads(e[tls + "root_ca_certificate"]) == "/c/ca.crt"
    assert json.loads(e[tls + "connect_certificate"]) == "/c/planner.crt"
    assert json.loads(e[tls + "connect_private_key"]) == "/c/planner.key"
    assert json.loads(e[tls + "enable_mtls"]) is True
    assert json.loads(e[tls + "verify_name_on_connect"]) is True
    assert tls + "listen_certificate" not in e and "access_control" not in e


def test_the_launcher_is_a_client_and_the_router_the_hub() -> None:
    b = bus(listen=["tcp/0.0.0.0:9000"])
    la = b.session_plan(listen_default=True, service="launcher", mode="router")
    assert la.mode == "client" and la.listen == () and la.connect == ("tls/127.0.0.1:9000",)
    hub = b.session_plan(listen_default=True, service="router", mode="router")
    assert hub.mode == "router" and hub.listen == ("tls/0.0.0.0:9000",) and hub.connect == ()
    e = hub.zenoh_entries()
    assert json.loads(e["transport/link/tls/listen_certificate"]) == "/c/router.crt"
    assert json.loads(e["transport/link/tls/listen_private_key"]) == "/c/router.key"
    assert json.loads(e["access_control"])["default_permission"] == "deny"


def test_certs_dir_override_and_bad_settings() -> None:
    p = bus().session_plan(listen_default=False, service="planner", certs_dir="/other")
    assert p.tls is not None and p.tls.cert == "/other/planner.crt"
    with pytest.raises(ConfigError, match="udp"):
        bus(listen=["udp/127.0.0.1:7447"])
    with pytest.raises(ConfigError, match="mtls"):
        config_from_dict({"bus": {"listen": ["tls/127.0.0.1:7447"]}})
    with pytest.raises(ConfigError, match=r"security"):
        config_from_dict({"bus": {"security": "tls"}})
    with pytest.raises(ValueError, match="service name"):
        bus().session_plan(listen_default=False)


def test_every_declared_publisher_may_put_and_nobody_else_drives() -> None:
    assert set(PUT_RIGHTS) == set(TOPIC_TYPES)
    for svc in SERVICES:
        assert svc.NAME in IDENTITIES
        for port in svc.PORTS:
            if port.direction is Direction.PUBLISH:
                assert may_put(svc.NAME, port.suffix), (svc.NAME, port.suffix)
    assert [i for i in IDENTITIES if may_put(i, DRIVE_CMD)] == ["planner"]
    assert [i for i in IDENTITIES if may_put(i, STATE)] == ["localization_bridge"]
    assert sorted(i for i in IDENTITIES if may_put(i, SIM_CONTROL)) == ["launcher", "operator"]


def test_access_control_document() -> None:
    acl = access_control("car7")
    rules = {r["id"]: r for r in acl["rules"]}
    assert rules["put_cmd_drive"]["key_exprs"] == [Keys("car7").key(DRIVE_CMD)]
    assert rules["put_cmd_drive"]["messages"] == ["put"]
    assert rules["put_cmd_drive"]["flows"] == ["ingress"]
    assert rules["alive_planner"]["key_exprs"] == ["racestack/car7/alive/planner"]
    assert "put" not in rules["listen"]["messages"]
    # one subject per identity: one decision is one line of Zenoh's trace
    assert [s["cert_common_names"] for s in acl["subjects"]] == [[i] for i in IDENTITIES]
    pol = {p["subjects"][0]: p["rules"] for p in acl["policies"]}
    assert "put_cmd_drive" in pol["planner"] and "put_cmd_drive" not in pol["telemetry"]
    assert all(set(p) <= set(rules) for p in pol.values())


def test_denials_parsed_from_a_real_trace() -> None:
    """A trace of zenoh 1.10.2's hub: telemetry put cmd/drive 10 times and declared a
    token alive/planner2; planner's 10 allowed commands and every cache fill not counted."""
    parser = DenialParser()
    found: dict[Denial, int] = {}
    for line in TRACE.read_text(errors="replace").splitlines():
        d = parser.feed(line)
        if d is not None:
            found[d] = found.get(d, 0) + 1
    drive = Denial("telemetry", "Put", "ingress", "racestack/car0/cmd/drive")
    token = Denial("telemetry", "Liveliness Token", "ingress", "racestack/car0/alive/planner2")
    assert found == {drive: 10, token: 1}
    n, text = growth_text(found, {drive: 4})
    assert n == 7 and text.startswith("telemetry Put (ingress) racestack/car0/cmd/drive x6")
    assert parser.feed("some other line") is None
    assert parser.feed("zenoh::net::routing::interceptor::access_control: garbage") is None


def test_denials_of_an_unknown_common_name_are_counted() -> None:
    """A trace of zenoh 1.10.2's hub (with ``ACL_LOG_DIRECTIVES``): a certificate of the
    project's CA with the common name ``stranger`` (no identity) connected, declared a token
    and put cmd/drive; then telemetry put cmd/drive 5 times. Zenoh gives the stranger no
    cache-fill lines: its connection and both decisions count, named after the CN the TLS
    link logged."""
    parser = DenialParser()
    found: dict[Denial, int] = {}
    for line in (TRACE.parent / "acl_trace_unknown_cn_1.10.2.txt").read_text(
        errors="replace"
    ).splitlines():
        d = parser.feed(line)
        if d is not None:
            found[d] = found.get(d, 0) + 1
    who = "stranger" + UNKNOWN_CN
    assert found == {
        Denial(who, CONNECT_DENIED, "ingress", "*"): 1,
        Denial(who, "Liveliness Token", "ingress", "racestack/car0/alive/stranger"): 1,
        Denial(who, "Put", "ingress", "racestack/car0/cmd/drive"): 1,
        Denial("telemetry", "Put", "ingress", "racestack/car0/cmd/drive"): 5,
    }
    assert parser.strangers == 1
    n, text = growth_text(found, {})
    assert n == 8 and "stranger (unknown CN) Connect" in text
