"""racestack tune's study: identity checks, the ask-and-tell loop, outputs (fake races)."""

from __future__ import annotations

from pathlib import Path

import pytest
from optuna.trial import TrialState

from services.tools.tune import output
from services.tools.tune import study as st
from services.tools.tune.evaluate import TrialOutcome
from services.tools.tune.search import SeedResult, score, space_for
from shared.config import load_config

SPACE = space_for("cimpcc", 4.18)


def _meta(track: str = "paperlike", laps: int = 1) -> dict:
    return {
        "method": "cimpcc",
        "track": track,
        "track_fingerprint": f"fp-{track}",
        "track_source": f"builtin:{track}",
        "objective": {"laps": laps, "seeds": [0], "margin_m": 0.05},
        "v_max_mps": 4.18,
        "config": "c0",
        "study": f"cimpcc@{track}-fp",
    }


def _open(tmp_path: Path, meta: dict | None = None, exclusive: bool = True):
    meta = meta or _meta()
    url = st.default_storage(tmp_path)
    return st.open_study(url, meta["study"], meta, seed=0, exclusive=exclusive)


def fake_evaluate(params) -> TrialOutcome:
    """A lap time from the point (smaller gamma: slower), clean when v_up_p < 3.7."""
    lap = 13.0 + 10.0 / params["gamma"]
    clean = params["v_up_p"] < 3.7
    seed = SeedResult(0, (lap,), 0 if clean else 1, 0, 0.2)
    return TrialOutcome(score([seed], 1, 1, 0.05), (seed,), SPACE.overlay(params))


@pytest.mark.slow
def test_loop_fills_the_budget_and_picks_the_best_feasible(tmp_path: Path) -> None:
    study = _open(tmp_path)
    st.enqueue_baseline(study, SPACE.baseline(load_config(None)))
    seen = []
    rep = st.run_trials(study, SPACE, fake_evaluate, budget=6, report=seen.append)
    assert rep.told == 6 and not rep.interrupted and len(seen) == 6
    trials = study.get_trials()
    assert len(trials) == 6 and all(t.state == TrialState.COMPLETE for t in trials)
    assert trials[0].user_attrs["baseline"] and trials[0].params["gamma"] == 40.0
    best = st.best_trial(study)
    feasible = [t for t in trials if t.user_attrs["feasible"]]
    assert best is not None and best.value == min(t.value for t in feasible)
    assert all(set(t.constraints) == set(st.CONSTRAINTS) for t in trials)
    # the budget is the study's: a second loop adds nothing
    assert st.run_trials(study, SPACE, fake_evaluate, budget=6).told == 0


def test_a_trial_that_raises_is_a_failed_trial_with_its_error(tmp_path: Path, capsys) -> None:
    study = _open(tmp_path)
    calls = {"n": 0}

    def flaky(params):
        calls["n"] += 1
        if calls["n"] == 2:
            raise RuntimeError("solver exploded\nsecond line")
        return fake_evaluate(params)

    rep = st.run_trials(study, SPACE, flaky, budget=3)
    assert rep.told == 3 and rep.failed == 1
    failed = [t for t in study.get_trials() if t.state == TrialState.FAIL]
    assert len(failed) == 1
    assert failed[0].user_attrs["error"] == "RuntimeError: solver exploded"
    err = capsys.readouterr().err
    assert "Traceback" not in err


def test_ctrl_c_fails_the_running_trial_and_keeps_the_rest(tmp_path: Path) -> None:
    study = _open(tmp_path)
    calls = {"n": 0}

    def interrupted(params):
        calls["n"] += 1
        if calls["n"] == 3:
            raise KeyboardInterrupt
        return fake_evaluate(params)

    rep = st.run_trials(study, SPACE, interrupted, budget=10)
    assert rep.interrupted and rep.told == 2
    states = [t.state for t in study.get_trials()]
    assert states == [TrialState.COMPLETE, TrialState.COMPLETE, TrialState.FAIL]
    assert study.get_trials()[2].user_attrs["interrupted"]
    assert st.finished_count(study) == (2, 0)  # an interrupted trial is not in the budget


def test_resuming_with_another_track_or_objective_is_an_error(tmp_path: Path) -> None:
    _open(tmp_path)
    # the same study name made for other laps
    with pytest.raises(st.StudyMismatchError, match="differs in: objective"):
        _open(tmp_path, _meta(laps=3))
    # the default study file of DIR holds another track's study
    with pytest.raises(st.StudyMismatchError, match=r"holds the study 'cimpcc@paperlike-fp'"):
        _open(tmp_path, _meta(track="gentle"))
    # a shared storage may hold several studies
    _open(tmp_path, _meta(track="gentle"), exclusive=False)
    with pytest.raises(st.StudyMismatchError, match="was made for method cimpcc, track gentle"):
        st.open_study(st.default_storage(tmp_path), "cimpcc@gentle-fp", _meta(), 0, False)


def test_a_bad_storage_url_is_a_clear_error() -> None:
    with pytest.raises(st.StudyMismatchError, match="cannot open storage"):
        st.make_storage("nosuchdb://x")


@pytest.mark.parametrize("message", [
    "(sqlite3.OperationalError) table studies already exists",
    # both workers insert alembic's version row (seen in CI, 2026-12-06)
    "(sqlite3.IntegrityError) UNIQUE constraint failed: alembic_version.version_num",
])
def test_a_worker_that_loses_the_table_creation_race_retries(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, message: str
) -> None:
    """Two workers started at once on a new database: the second sees the first's tables."""
    real = st.optuna.storages.RDBStorage
    calls = []

    def racing(url, **kwargs):
        calls.append(url)
        if len(calls) == 1:
            raise RuntimeError(message)
        return real(url, **kwargs)

    monkeypatch.setattr(st.optuna.storages, "RDBStorage", racing)
    monkeypatch.setattr(st.time, "sleep", lambda s: None)
    assert st.make_storage(st.default_storage(tmp_path)) is not None
    assert len(calls) == 2


def test_a_storage_error_that_persists_is_not_retried_forever(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    def always(url, **kwargs):
        raise RuntimeError("table studies already exists")

    monkeypatch.setattr(st.optuna.storages, "RDBStorage", always)
    monkeypatch.setattr(st.time, "sleep", lambda s: None)
    with pytest.raises(st.StudyMismatchError, match="already exists"):
        st.make_storage("sqlite:///x.db")


@pytest.mark.slow
def test_outputs_best_toml_loads_and_history_is_written(tmp_path: Path) -> None:
    study = _open(tmp_path)
    st.run_trials(study, SPACE, fake_evaluate, budget=4)
    best = st.best_trial(study)
    assert best is not None
    base = {"planner": {"horizon_steps": 12, "cimpcc": {"q_lag": 700.0}}}
    cfg = output.write_best(tmp_path, base, best, _meta())
    assert cfg == load_config(tmp_path / "best.toml")
    w = cfg.planner.cimpcc
    assert cfg.planner.horizon_steps == 12 and w.q_lag == 700.0  # the base is kept
    assert list(w.v_up_mps) == best.user_attrs["overlay"]["planner"]["cimpcc"]["v_up_mps"]
    assert cfg.track.source == "builtin:paperlike"
    trials = study.get_trials()
    doc = output.trials_document(_meta(), trials, best, SPACE.names())
    output.write_history(tmp_path, doc, SPACE.names(), trials)
    output.plot_history(tmp_path / "history.png", trials, "test")
    lines = (tmp_path / "trials.csv").read_text().splitlines()
    assert len(lines) == 5 and "param_gamma" in lines[0]
    assert (tmp_path / "history.png").read_bytes()[:4] == b"\x89PNG"


def test_a_signal_between_races_stops_before_the_next_trial(tmp_path: Path) -> None:
    study = _open(tmp_path)
    stop = st.GracefulStop()

    def report(frozen) -> None:
        if frozen.number == 1:
            stop.handler(2, None)  # as if Ctrl-C came while the trial was being stored

    rep = st.run_trials(study, SPACE, fake_evaluate, budget=10, report=report, stop=stop)
    assert rep.interrupted and rep.told == 2
    assert [t.state for t in study.get_trials()] == [TrialState.COMPLETE] * 2
    # inside a race the same signal interrupts the race itself
    with pytest.raises(KeyboardInterrupt), stop.racing():
        stop.handler(2, None)


def test_a_worker_whose_budget_is_taken_waits_for_the_other_workers_trials(
    tmp_path: Path, monkeypatch
) -> None:
    study = _open(tmp_path)
    other = study.ask()  # another worker's trial, still running
    said: list[str] = []
    looks = {"n": 0}

    def finish_it(_s: float) -> None:
        looks["n"] += 1
        if looks["n"] == 2:  # the other worker tells its trial while this one waits
            study.tell(other, 13.5)

    monkeypatch.setattr(st.time, "sleep", finish_it)
    rep = st.run_trials(study, SPACE, fake_evaluate, budget=2, say=said.append)
    assert rep.told == 1 and looks["n"] == 2
    assert said == ["the budget is taken; waiting for 1 trial(s) of other workers "
                    "(at most 900 s)"]
    assert st.finished_count(study) == (2, 0)


def test_the_wait_for_a_dead_workers_trial_gives_up(tmp_path: Path) -> None:
    study = _open(tmp_path)
    study.ask()  # left RUNNING by a worker that died
    assert st.wait_for_others(study, 1, st.GracefulStop(), wait_s=0.3) == 1
