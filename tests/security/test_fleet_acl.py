"""The hub's rules for a race of several cars (pure, issue #24): each car's bridge, planner
and telemetry have their own identity and may put only their own car's keys; the shared
services (simulator, launcher) every car's; everyone may listen to every car; one car's
rules are as they were."""

from __future__ import annotations

from typing import Any

import pytest

from shared.config import config_from_dict
from shared.security import IDENTITIES, access_control
from shared.security.identities import car_identity, fleet_identities

FLEET = ("car0", "car1")


def put_rights(acl: dict[str, Any], key: str) -> list[str]:
    rules = {r["id"]: r for r in acl["rules"]}
    return sorted(
        p["subjects"][0] for p in acl["policies"]
        if any(key in rules[i]["key_exprs"] and "put" in rules[i]["messages"]
               and rules[i]["permission"] == "allow" for i in p["rules"])
    )


def tokens(acl: dict[str, Any], identity: str) -> list[str]:
    rules = {r["id"]: r for r in acl["rules"]}
    pol = next(p for p in acl["policies"] if p["subjects"] == [identity])
    return [k for i in pol["rules"] if "liveliness_token" in rules[i]["messages"]
            and rules[i]["flows"] == ["ingress"]
            and rules[i]["permission"] == "allow" for k in rules[i]["key_exprs"]]


@pytest.fixture(scope="module")
def acl() -> dict[str, Any]:
    return access_control("car0", fleet_identities(FLEET), fleet=FLEET)


def test_each_planner_drives_only_its_own_car(acl) -> None:
    assert put_rights(acl, "racestack/car0/cmd/drive") == ["planner-car0"]
    assert put_rights(acl, "racestack/car1/cmd/drive") == ["planner-car1"]
    assert put_rights(acl, "racestack/car1/state") == ["localization_bridge-car1"]
    assert put_rights(acl, "racestack/car1/opponents") == ["localization_bridge-car1"]


def test_the_simulator_and_launcher_serve_every_car(acl) -> None:
    for car in FLEET:
        assert "simulator" in put_rights(acl, f"racestack/{car}/vehicle/scan")
        assert put_rights(acl, f"racestack/{car}/sim/control") == ["launcher", "operator"]


def test_everyone_listens_to_every_car_and_tokens_are_per_car(acl) -> None:
    listen = next(r for r in acl["rules"] if r["id"] == "listen")
    assert listen["key_exprs"] == ["racestack/car0/**", "racestack/car1/**"]
    assert tokens(acl, "planner-car1") == ["racestack/car1/alive/planner"]
    assert tokens(acl, "planner") == []  # in a race no car's planner goes by the plain name
    assert tokens(acl, "simulator") == ["racestack/car0/alive/simulator",
                                        "racestack/car1/alive/simulator"]


def test_one_car_is_as_before() -> None:
    acl = access_control("car0")
    assert put_rights(acl, "racestack/car0/cmd/drive") == ["planner"]
    assert tokens(acl, "planner") == ["racestack/car0/alive/planner"]
    assert {p["subjects"][0] for p in acl["policies"]} == set(IDENTITIES)


def test_a_car_outside_the_fleet_is_refused() -> None:
    with pytest.raises(ValueError, match="not in the fleet"):
        access_control("car9", fleet=FLEET)


def test_per_car_identity_picks_the_car_s_certificate(tmp_path) -> None:
    cfg = config_from_dict({"bus": {"car": "car1", "security": "mtls", "per_car_identity": True,
                                    "certs_dir": str(tmp_path)}})
    plan = cfg.bus.session_plan(listen_default=False, service="planner")
    assert plan.tls.cert.endswith("planner-car1.crt")
    plan = cfg.bus.session_plan(listen_default=False, service="simulator")
    assert plan.tls.cert.endswith("simulator.crt")
    assert car_identity("planner", "car1") == "planner-car1"
