"""The car, once (issue #21): ``[vehicle]`` is the car every planner, the minimum-time lap and
the simulator assume; ``[simulator.vehicle]`` an optional override (a model mismatch); a file
that still gives the car only as ``[simulator.vehicle]`` is one clear line."""

from __future__ import annotations

import argparse
import threading
from pathlib import Path

import pytest

from shared.config import ConfigError, RacestackConfig, config_from_dict, load_config
from shared.config.root import VEHICLE_MOVED
from shared.config.simulator import SimulatorSettings
from shared.config.vehicle import F1TENTH_GYM, REAL_CAR_IDENTIFIED, vehicle_preset

CONFIG_DIR = Path(__file__).resolve().parents[2] / "config"
MISMATCH = {"vehicle": {}, "simulator": {"vehicle": {"preset": "real_car_identified"}}}


class StoppedError(Exception):
    """Raised by a stand-in once it has seen what it was given."""


# ----------------------------------------------------------------------- the migration
def test_an_old_file_with_only_simulator_vehicle_is_one_line_saying_what_moved(
    tmp_path: Path,
) -> None:
    old = tmp_path / "old.toml"
    old.write_text('[planner]\nmethod = "mpcc"\n[simulator.vehicle]\npreset = '
                   '"real_car_identified"\n[simulator]\nseed = 3\n')
    with pytest.raises(ConfigError) as info:
        load_config(old)
    text = str(info.value)
    assert text == f"{old}: {VEHICLE_MOVED}"
    assert "\n" not in text
    assert text.endswith(
        "[simulator.vehicle] moved to [vehicle] (the car the planner, the minimum-time lap and "
        "the simulator assume); keep [simulator.vehicle] next to a [vehicle] section only to "
        "simulate a different car than the planner believes"
    )
    # the same car given as [vehicle] loads (the old meaning: one car for everything)
    new = tmp_path / "new.toml"
    new.write_text('[planner]\nmethod = "mpcc"\n[vehicle]\npreset = "real_car_identified"\n')
    cfg = load_config(new)
    assert cfg.vehicle == cfg.simulator.vehicle == REAL_CAR_IDENTIFIED
    assert not cfg.simulates_another_car


def test_the_moved_line_for_tables_given_in_code() -> None:
    with pytest.raises(ConfigError) as info:
        config_from_dict({"simulator": {"vehicle": {"mu": 0.9}}}, "a.toml")
    assert str(info.value) == f"a.toml: {VEHICLE_MOVED}"


@pytest.mark.parametrize("path", sorted(CONFIG_DIR.glob("*.toml")), ids=lambda p: p.name)
def test_every_shipped_config_loads_with_one_car(path: Path) -> None:
    cfg = load_config(path)
    assert cfg.simulator.vehicle == cfg.vehicle and not cfg.simulates_another_car


# ----------------------------------------------------------------------- the default
@pytest.mark.parametrize(
    "data",
    [{}, {"vehicle": {"preset": "real_car_identified", "mass_kg": 3.9}},
     {"vehicle": {"mu": 0.8}, "simulator": {"seed": 4, "lidar": {"beams": 100}}}],
)
def test_without_an_override_the_simulator_races_the_planner_s_car(data: dict) -> None:
    cfg = config_from_dict(data)
    assert cfg.simulator.vehicle == cfg.vehicle
    assert not cfg.simulates_another_car
    assert "vehicle" not in cfg.simulator.model_fields_set  # resolved, not given
    # a copy of the simulator's settings (the tuner's seeds) keeps the car
    assert cfg.simulator.model_copy(update={"seed": 9}).vehicle == cfg.vehicle
    # and a dump reads back as the same configuration
    assert config_from_dict(cfg.model_dump()) == cfg


def test_the_default_configuration_is_the_gym_car_for_everyone() -> None:
    cfg = RacestackConfig()
    assert cfg.vehicle == cfg.simulator.vehicle == F1TENTH_GYM
    assert load_config(None) == cfg == config_from_dict({"vehicle": {}})
    built = RacestackConfig(vehicle=REAL_CAR_IDENTIFIED)  # in code, too
    assert built.simulator.vehicle == REAL_CAR_IDENTIFIED


# ----------------------------------------------------------------------- the override
def test_an_override_with_a_preset_is_that_car_in_the_simulator_only() -> None:
    cfg = config_from_dict(MISMATCH)
    assert cfg.vehicle == F1TENTH_GYM
    assert cfg.simulator.vehicle == REAL_CAR_IDENTIFIED
    assert cfg.simulates_another_car
    assert config_from_dict(cfg.model_dump()) == cfg


def test_an_override_without_a_preset_changes_the_keys_of_vehicle() -> None:
    cfg = config_from_dict({"vehicle": {"preset": "real_car_identified", "mass_kg": 3.9},
                            "simulator": {"vehicle": {"mu": 0.9}}})
    assert cfg.vehicle == vehicle_preset("real_car_identified", mass_kg=3.9)
    assert cfg.simulator.vehicle == vehicle_preset("real_car_identified", mass_kg=3.9, mu=0.9)
    # a preset in the override starts from that preset, not from [vehicle]
    fresh = config_from_dict({"vehicle": {"preset": "real_car_identified"},
                              "simulator": {"vehicle": {"preset": "f1tenth_gym", "mu": 0.9}}})
    assert fresh.simulator.vehicle == vehicle_preset("f1tenth_gym", mu=0.9)
    # an override equal to [vehicle] is no mismatch
    same = config_from_dict({"vehicle": {"mu": 0.9}, "simulator": {"vehicle": {"mu": 0.9}}})
    assert not same.simulates_another_car


def test_a_bad_vehicle_is_reported_once_not_again_at_the_override() -> None:
    with pytest.raises(ConfigError) as info:
        config_from_dict({"vehicle": {"mu": 9.0}, "simulator": {"vehicle": {"mass_kg": 3.0}}},
                         "x.toml")
    assert str(info.value).splitlines() == [
        "x.toml: vehicle.mu: Input should be less than or equal to 3"
    ]
    with pytest.raises(ConfigError, match=r"simulator\.vehicle\.mu"):
        config_from_dict({"vehicle": {}, "simulator": {"vehicle": {"mu": 9.0}}})


def test_a_simulator_car_given_in_code_is_taken_as_the_override() -> None:
    cfg = RacestackConfig(simulator=SimulatorSettings(vehicle=REAL_CAR_IDENTIFIED))
    assert cfg.vehicle == F1TENTH_GYM and cfg.simulator.vehicle == REAL_CAR_IDENTIFIED


# ----------------------------------------------------------------------- who reads which
def test_the_planner_service_builds_from_vehicle(monkeypatch) -> None:
    import services.planner.service as service

    seen = []

    def fake_make_planner(track, settings, curvature, vehicle=None, **_kwargs):
        seen.append(vehicle)
        raise StoppedError

    monkeypatch.setattr(service, "make_planner", fake_make_planner)
    cfg = config_from_dict(MISMATCH)
    with pytest.raises(StoppedError):
        service.run(cfg, argparse.Namespace(config=None), threading.Event())
    assert seen == [F1TENTH_GYM]


def test_racestack_laps_builds_from_vehicle(tmp_path: Path, monkeypatch) -> None:
    import services.planner as planner_pkg
    from services.tools.cli import main

    seen = []

    def fake_ensure(method, track, settings, vehicle=None, **_kwargs):
        seen.append(("ensure", vehicle))
        return []

    def fake_make_planner(track, settings, curvature, vehicle=None, **_kwargs):
        seen.append(("planner", vehicle))
        raise StoppedError

    monkeypatch.setattr(planner_pkg, "ensure_artefacts", fake_ensure)
    monkeypatch.setattr(planner_pkg, "make_planner", fake_make_planner)
    config = tmp_path / "m.toml"
    config.write_text('[vehicle]\npreset = "real_car_identified"\n'
                      '[simulator.vehicle]\npreset = "f1tenth_gym"\n')
    with pytest.raises(StoppedError):
        main(["laps", "--config", str(config), "--laps", "1"])
    assert seen == [("ensure", REAL_CAR_IDENTIFIED), ("planner", REAL_CAR_IDENTIFIED)]


def test_the_tuner_plans_for_vehicle_and_races_the_simulated_car(monkeypatch) -> None:
    import services.tools.tune.evaluate as evaluate
    from services.tools.tune.search import space_for
    from shared.track import load_track

    seen = []

    def fake_ensure(method, track, settings, vehicle=None, **_kwargs):
        seen.append(("ensure", vehicle))
        return []

    def fake_run(method, planner, track, sim, opts, progress=None):
        seen.append(("race", sim.vehicle))
        raise StoppedError

    monkeypatch.setattr(evaluate, "ensure_artefacts", fake_ensure)
    monkeypatch.setattr(evaluate, "run_method", fake_run)
    space = space_for("cimpcc", 4.18)
    ev = evaluate.Evaluator(space, load_track("paperlike"), MISMATCH,
                            evaluate.ObjectiveSettings())
    assert ev._pool.vehicle == F1TENTH_GYM
    _overlay, cfg = ev.config_for(space.baseline(ev.base_cfg))
    assert cfg.vehicle == F1TENTH_GYM and cfg.simulator.vehicle == REAL_CAR_IDENTIFIED
    monkeypatch.setattr(ev._pool, "planner", lambda *_args, **_kwargs: object())
    planner = ev.planner_for(cfg)
    with pytest.raises(StoppedError):
        ev.run_seed(planner, cfg, 0)
    assert seen == [("ensure", F1TENTH_GYM), ("race", REAL_CAR_IDENTIFIED)]
