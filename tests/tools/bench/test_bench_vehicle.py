"""The bench's two cars (issue #21): the planners and the lines they race on are built for
``[vehicle]``; the simulator races ``[simulator.vehicle]`` when it is given, and the reference
(the ratio's denominator) is the limit of that simulated car, whose laps it judges."""

from __future__ import annotations

import json
from pathlib import Path
from types import SimpleNamespace

import pytest

import services.tools.bench.run as bench
from services.planner import MinTimeError, limit_request, make_min_time_lap
from services.tools.bench.closed_loop import LoopOptions
from shared.config import config_from_dict, load_config
from shared.config.vehicle import F1TENTH_GYM, REAL_CAR_IDENTIFIED
from shared.track import load_track

MISMATCH_TOML = ('[vehicle]\npreset = "f1tenth_gym"\n'
                 '[simulator.vehicle]\npreset = "real_car_identified"\n')


class StoppedError(Exception):
    """Raised by a stand-in once it has seen what it was given."""


def test_the_planners_get_vehicle_the_simulator_and_the_reference_the_simulated_car(
    tmp_path: Path, monkeypatch
) -> None:
    seen: list = []

    class Pool:
        def __init__(self, track, vehicle=None) -> None:
            seen.append(("pool", vehicle))

        def planner(self, settings, method, curvature):
            return SimpleNamespace(reference=SimpleNamespace(speed=SimpleNamespace(
                lap_time_s=1.0)))

    def fake_ensure(method, track, settings, vehicle=None, **_kwargs):
        seen.append(("ensure", vehicle))
        return []

    def fake_limit(track, car, settings, *args, **kwargs):
        seen.append(("reference", car))
        raise MinTimeError(track.name, "test: not solved")

    def fake_run(name, planner, track, sim, opts, progress=None):
        seen.append(("race", sim.vehicle))
        raise StoppedError

    monkeypatch.setattr(bench, "PlannerPool", Pool)
    monkeypatch.setattr(bench, "ensure_artefacts", fake_ensure)
    monkeypatch.setattr(bench, "make_min_time_lap", fake_limit)
    monkeypatch.setattr(bench, "run_method", fake_run)
    cfg = config_from_dict({"vehicle": {"preset": "f1tenth_gym"},
                            "simulator": {"vehicle": {"preset": "real_car_identified"}}})
    with pytest.raises(StoppedError):
        bench.run_bench(cfg, "paperlike", ["cimpcc-line"], 1, tmp_path, LoopOptions(laps=1),
                        [], 1, figures=False)
    assert seen == [
        ("reference", REAL_CAR_IDENTIFIED),  # the limit of the car whose laps are judged
        ("ensure", F1TENTH_GYM),  # the line cimpcc-line races on: the planners' car
        ("pool", F1TENTH_GYM),
        ("race", REAL_CAR_IDENTIFIED),
    ]
    note = bench.mismatch_note(cfg)
    assert "\n" not in note and "preset f1tenth_gym" in note and "real_car_identified" in note


@pytest.mark.slow
def test_a_mismatch_run_records_both_cars_and_judges_against_the_simulated_car(
    tmp_path: Path, capsys
) -> None:
    config = tmp_path / "mismatch.toml"
    config.write_text(MISMATCH_TOML)
    out = tmp_path / "out"
    code = bench.main(["--config", str(config), "--track", "paperlike", "--laps", "1",
                       "--methods", "cimpcc", "--no-figures", "--out", str(out)])
    err = capsys.readouterr().err
    assert code == 0, err
    assert "model mismatch" in err
    doc = json.loads((out / "results.json").read_text(encoding="utf-8"))
    meta = doc["meta"]
    as_json = json.loads(json.dumps({"p": F1TENTH_GYM.model_dump(),
                                     "s": REAL_CAR_IDENTIFIED.model_dump()}))
    assert meta["vehicle"] == as_json["p"]
    assert meta["simulator_vehicle"] == as_json["s"]
    # the reference is the simulated (identified) car's limit: the bench made exactly that lap
    cfg = load_config(config)
    lap = make_min_time_lap(load_track("paperlike"),
                            *limit_request(cfg.planner, REAL_CAR_IDENTIFIED), progress=None)
    assert lap.cache_hit
    assert doc["reference"]["min_time_lap_s"] == lap.lap_time_s
    assert doc["reference"]["tyre_model"] == "pacejka"
