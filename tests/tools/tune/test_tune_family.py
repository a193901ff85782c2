"""``racestack tune`` over a family (tracks x cars): the family's score, the car list shared
with the robustness benchmark, and two workers on one PostgreSQL study (a real server,
``postgres_url`` in conftest.py) beside the SQLite default."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
from pathlib import Path

import optuna
import pytest
from optuna.trial import TrialState

from benchmarks import robustness as rb
from services.tools.tune import cli
from services.tools.tune import study as st
from services.tools.tune.evaluate import ObjectiveSettings
from services.tools.tune.family import FamilyCell, FamilyEvaluator, cell_config, limit_lap_s
from services.tools.tune.search import (
    CONSTRAINTS,
    PENALTY_S,
    CellScore,
    SeedResult,
    family_score,
    is_infeasible,
    score,
    space_for,
)
from shared.config import load_config
from shared.evaluation import car_family as cars
from shared.track import load_track

ROOT = Path(__file__).resolve().parents[3]
#: Two short tracks (42.5 m and 28.5 m) and two cars whose limits solve in seconds.
TRACKS = "paperlike,gen:7"
CARS = "default,linear"
TINY = ["--method", "cimpcc", "--tracks", TRACKS, "--cars", CARS, "--laps", "1",
        "--seeds", "0"]
#: Seconds a worker may take for the whole tiny study.
WORKER_TIMEOUT_S = 900.0


def _cell(track: str, car: str, laps: tuple[float, ...], limit: float, **kw) -> CellScore:
    seed = SeedResult(0, laps, kw.get("off", 0), 0, 0.2, "", kw.get("spins", 0),
                      kw.get("below", 0))
    return CellScore(track, car, score([seed], 1, 1, 0.05), limit)


# ------------------------------------------------------------------------- pure parts
def test_the_tuner_and_the_robustness_benchmark_share_one_car_list() -> None:
    assert rb.CARS is cars.CARS and rb.DEFAULT_CARS == cars.DEFAULT_CARS
    assert cars.car_names("linear, default,linear") == ["linear", "default"]
    with pytest.raises(cars.UnknownCarError, match="unknown car tank; choose from default"):
        cars.car_names("default,tank")


def test_the_family_value_is_the_worst_or_mean_ratio() -> None:
    cells = [_cell("a", "default", (10.5,), 10.0), _cell("b", "linear", (6.3,), 6.0)]
    worst = family_score(cells, 2, "worst")
    assert worst.feasible and worst.value == pytest.approx(1.05)
    assert family_score(cells, 2, "mean").value == pytest.approx(0.5 * (1.05 + 1.05))
    cells[1] = _cell("b", "linear", (6.6,), 6.0)
    assert family_score(cells, 2, "worst").value == pytest.approx(1.1)
    assert family_score(cells, 2, "mean").value == pytest.approx(0.5 * (1.05 + 1.1))
    with pytest.raises(ValueError, match="aggregate"):
        family_score(cells, 2, "median")


@pytest.mark.parametrize(
    ("kw", "key", "reason"),
    [
        ({"off": 1}, "off_track_events", "b/linear: 1 off-track event(s)"),
        ({"spins": 2}, "spins", "b/linear: 2 spin(s)"),
        ({"below": 1}, "below_limit_laps", "b/linear: 1 lap(s) below the minimum-time lap"),
    ],
)
def test_an_off_track_spin_or_below_limit_lap_in_any_cell_is_infeasible(kw, key, reason) -> None:
    cells = [_cell("a", "default", (10.5,), 10.0), _cell("b", "linear", (6.3,), 6.0, **kw)]
    sc = family_score(cells, 3, "worst")
    assert not sc.feasible and reason in sc.reasons
    assert sc.constraints[CONSTRAINTS.index(key)] > 0
    assert "1 cell(s) skipped" in sc.reasons and sc.value == PENALTY_S
    seed = SeedResult(0, (6.3,), kw.get("off", 0), 0, 0.2, "", kw.get("spins", 0),
                      kw.get("below", 0))
    assert is_infeasible(seed, 1, 0.05)


def test_family_options_are_checked_before_anything_races(tmp_path: Path, capsys) -> None:
    for argv, message in (
        (["--track", "paperlike", "--tracks", "paperlike"], "--track or --tracks, not both"),
        (["--tracks", "paperlike", "--cars", "default,tank"], "--cars: unknown car tank"),
        (["--tracks", " , "], "--tracks names no track"),
        (["--tracks", "paperlike,nosuchtrack"], "nosuchtrack"),
    ):
        code = cli.main(["--method", "cimpcc", *argv, "--out", str(tmp_path / "o")])
        err = capsys.readouterr().err
        assert code == 2 and err.startswith("racestack tune: error: ") and message in err, err
        assert len(err.strip().splitlines()) == 1


# ----------------------------------------------------------------------- end to end
def _warm() -> None:
    """Solve the four cells' minimum-time laps and compile their planners' problems once
    (into the session's cache, which the workers read), so the two workers race trials
    instead of making the same laps and problems side by side."""
    space = space_for("cimpcc", 4.18)
    cells = [FamilyCell(spec, load_track(spec), car)
             for spec in TRACKS.split(",") for car in CARS.split(",")]
    limits = [limit_lap_s(c.track, cell_config({}, c.car), 4.18)[0] for c in cells]
    family = FamilyEvaluator(space, cells, {}, ObjectiveSettings(laps=1, seeds=(0,)), limits)
    baseline = space.baseline(load_config(None))
    for ev in family.evaluators:
        ev.planner_for(ev.config_for(baseline)[1])


def _check_outputs(out: Path, study_name: str) -> dict:
    doc = json.loads((out / "trials.json").read_text())
    assert doc["study"]["study"] == study_name
    assert doc["study"]["cars"] == ["default", "linear"]
    assert [(c["track"], c["car"]) for c in doc["study"]["cells"]] == [
        ("paperlike", "default"), ("paperlike", "linear"), ("gen-7", "default"),
        ("gen-7", "linear")]
    best = doc["best"]
    assert best is not None and (out / "best.toml").is_file()
    assert len(best["cells"]) == 4 and all(c["feasible"] for c in best["cells"])
    worst = max(c["ratio"] for c in best["cells"])
    assert best["mean_lap_s"] == pytest.approx(worst, abs=1e-5)
    for c in best["cells"]:
        assert c["ratio"] == pytest.approx(c["mean_lap_s"] / c["limit_s"], abs=1e-5)
        assert c["ratio"] >= 1.0 and c["spins"] == 0 and c["below_limit_laps"] == 0
    header = (out / "trials.csv").read_text().splitlines()[0]
    assert "ratio_gen-7/linear" in header and "spins" in header
    return doc


@pytest.mark.slow
def test_a_tiny_family_tune_with_the_default_sqlite_storage(tmp_path: Path, capsys) -> None:
    out = tmp_path / "sqlite"
    code = cli.main([*TINY, "--trials", "1", "--out", str(out)])
    printed, err = capsys.readouterr()
    assert code == 0, err
    assert "4 cells (paperlike/default, paperlike/linear, gen-7/default, gen-7/linear)" in err
    assert "best: trial 0, worst ratio to the minimum-time lap" in printed
    assert (out / "study.db").is_file()
    doc = _check_outputs(out, json.loads((out / "trials.json").read_text())["study"]["study"])
    assert doc["study"]["study"].startswith("cimpcc@family-")
    assert doc["study"]["storage"].startswith("sqlite:///")


@pytest.mark.slow
def test_two_workers_tune_a_family_on_one_postgresql_study(
    tmp_path: Path, postgres_url: str
) -> None:
    _warm()
    budget = 3
    env = {**os.environ, "MPLBACKEND": "Agg"}
    procs = []
    for k in (1, 2):
        cmd = [sys.executable, "-m", "services.tools.tune.cli", *TINY, "--trials", str(budget),
               "--storage", postgres_url, "--seed", str(k), "--out", str(tmp_path / f"w{k}")]
        procs.append(subprocess.Popen(cmd, cwd=ROOT, env=env, stdout=subprocess.PIPE,
                                      stderr=subprocess.PIPE, text=True))
    try:
        results = [p.communicate(timeout=WORKER_TIMEOUT_S) for p in procs]
    finally:
        for p in procs:
            if p.poll() is None:
                os.kill(p.pid, signal.SIGTERM)
                p.communicate(timeout=60)
    for p, (_, err) in zip(procs, results, strict=True):
        assert p.returncode == 0, err
        assert "Traceback" not in err
    summaries = optuna.get_all_study_summaries(postgres_url)
    assert len(summaries) == 1  # one study, both workers in it
    name = summaries[0].study_name
    trials = optuna.load_study(study_name=name, storage=postgres_url).get_trials()
    finished = [t for t in trials if t.state == TrialState.COMPLETE]
    # the budget is the study's, counted once over both workers
    assert len(finished) == budget and len(trials) == budget
    assert sorted(t.number for t in trials) == list(range(budget))
    # the baseline is queued by whichever worker finds the study empty; two that start
    # together may both queue it (enqueue_baseline is not atomic), and each copy is a trial
    # of the budget like any other
    assert 1 <= sum(bool(t.user_attrs.get("baseline")) for t in trials) <= 2
    workers = {t.user_attrs["worker"].split(":")[-1] for t in finished}
    assert workers == {str(p.pid) for p in procs}, "each worker raced a trial"
    for t in finished:
        assert {c["car"] for c in t.user_attrs["cells"]} <= {"default", "linear"}
        assert set(t.constraints) == set(CONSTRAINTS)
    for k in (1, 2):
        doc = _check_outputs(tmp_path / f"w{k}", name)
        assert doc["study"]["storage"] == postgres_url
        assert len(doc["trials"]) == budget
    assert st.best_trial(optuna.load_study(study_name=name, storage=postgres_url)) is not None


def test_family_cells_know_their_car() -> None:
    cell = FamilyCell("paperlike", load_track("paperlike"), "identified-on-default")
    cfg = cell_config({}, cell.car)
    assert cell.label == "paperlike/identified-on-default"
    assert cfg.vehicle.preset == "f1tenth_gym"
    assert cfg.simulator.vehicle.preset == "real_car_identified"
