"""Keys: one place for every key expression; every topic maps to one message type."""

from __future__ import annotations

from pathlib import Path

import pytest

from shared.keys import TOPIC_TYPES, Keys, check_chunk
from shared.messages import MESSAGE_TYPES, REGISTRY

DOC = Path(__file__).resolve().parents[2] / "docs" / "message-contract.md"


def test_keys_of_the_default_car() -> None:
    k = Keys()
    assert k.car == "car0" and k.prefix == "racestack/car0"
    assert k.pose == "racestack/car0/vehicle/pose"
    assert k.imu == "racestack/car0/vehicle/imu"
    assert k.odom == "racestack/car0/vehicle/odom"
    assert k.scan == "racestack/car0/vehicle/scan"
    assert k.state == "racestack/car0/state"
    assert k.drive_cmd == "racestack/car0/cmd/drive"
    assert k.plan == "racestack/car0/planner/plan"
    assert k.lap == "racestack/car0/lap"
    assert k.vesc_state == "racestack/car0/vesc/state"
    assert k.sim_truth == "racestack/car0/sim/truth"
    assert k.sim_control == "racestack/car0/sim/control"
    assert k.events_log == "racestack/car0/events/log"
    assert k.alive("planner") == "racestack/car0/alive/planner"
    assert k.alive_any == "racestack/car0/alive/*"
    assert k.all_data == "racestack/car0/**"


def test_other_car_and_parsing() -> None:
    k = Keys("blue-7")
    assert k.drive_cmd == "racestack/blue-7/cmd/drive"
    assert k.suffix_of("racestack/blue-7/vehicle/pose") == "vehicle/pose"
    assert k.suffix_of("racestack/car0/vehicle/pose") is None
    assert k.suffix_of("racestack/blue-7/nope") is None
    assert k.service_of_alive_key("racestack/blue-7/alive/sim") == "sim"
    assert k.service_of_alive_key("racestack/car0/alive/sim") is None
    assert len(k.topics()) == len(TOPIC_TYPES)


@pytest.mark.parametrize("name", ["", "a/b", "*", "a b", "$x", "x" * 65])
def test_unsafe_names_rejected(name: str) -> None:
    with pytest.raises(ValueError):
        Keys(name)
    with pytest.raises(ValueError):
        Keys().alive(name)
    with pytest.raises(ValueError):
        check_chunk(name)
    with pytest.raises(ValueError):
        Keys().key("vehicle/nope")


def test_every_topic_has_one_message_type_and_back() -> None:
    assert set(TOPIC_TYPES.values()) <= set(REGISTRY)
    assert sorted(TOPIC_TYPES.values()) == sorted(c.TYPE for c in MESSAGE_TYPES)


def test_contract_doc_lists_every_key_and_type() -> None:
    text = DOC.read_text(encoding="utf-8")
    for suffix in TOPIC_TYPES:
        assert f"`{suffix}`" in text, suffix
    for cls in MESSAGE_TYPES:
        assert f"`{cls.__name__}`" in text, cls.__name__
        for f in cls.fields_info():
            assert f"`{f.name}`" in text, f"{cls.__name__}.{f.name}"
