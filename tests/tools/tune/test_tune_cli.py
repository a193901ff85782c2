"""``racestack tune`` end to end: a tiny study, bad input, a crashing trial, two workers."""

from __future__ import annotations

import csv
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import optuna
import pytest

from services.tools.tune import cli
from services.tools.tune import study as st
from services.tools.tune.evaluate import Evaluator
from shared.config import load_config

ROOT = Path(__file__).resolve().parents[2]
TINY = ["--track", "paperlike", "--laps", "1", "--seeds", "0"]


def _run(capsys, *argv: str) -> tuple[int, str, str]:
    code = cli.main(list(argv))
    out, err = capsys.readouterr()
    return code, out, err


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["--method", "pid"], "unknown method 'pid'; choose from cimpcc, mpcc, raceline"),
        (["--method", "cimpcc", "--seeds", "a,b"], "--seeds must be integers"),
        (["--method", "cimpcc", "--seeds", "1,1"], "--seeds must be distinct"),
        (["--method", "cimpcc", "--laps", "0"], "--laps must be at least 1"),
        (["--method", "cimpcc", "--trials", "0"], "--trials must be at least 1"),
        (["--method", "cimpcc", "--track", "nosuchtrack"], "nosuchtrack"),
        (["--method", "mpcc", "--v-max", "99"], "--v-max must be in"),
        (["--method", "cimpcc", "--storage", "nosuchdb://x"], "cannot open storage"),
    ],
)
def test_bad_input_is_one_line_and_exit_2(tmp_path: Path, capsys, argv, message) -> None:
    code, _, err = _run(capsys, *argv, "--out", str(tmp_path / "o"))
    assert code == 2
    assert err.startswith("racestack tune: error: ") and message in err
    assert len(err.strip().splitlines()) == 1 and "Traceback" not in err


def test_a_study_of_another_track_in_dir_is_an_error(tmp_path: Path, capsys) -> None:
    meta = {"method": "cimpcc", "track": "gentle", "track_fingerprint": "x",
            "objective": {"laps": 1, "seeds": [0]}}
    st.open_study(st.default_storage(tmp_path), "cimpcc@gentle-x", meta, 0, exclusive=True)
    code, _, err = _run(capsys, "--method", "cimpcc", *TINY, "--out", str(tmp_path))
    assert code == 2
    assert "holds the study 'cimpcc@gentle-x' (method cimpcc, track gentle" in err
    assert len(err.strip().splitlines()) == 1


@pytest.mark.slow
def test_crashing_trials_are_failed_trials_with_their_error(
    tmp_path: Path, capsys, monkeypatch
) -> None:
    def boom(self, params):
        raise ValueError("planner diverged")

    monkeypatch.setattr(Evaluator, "__call__", boom)
    code, _, err = _run(capsys, "--method", "cimpcc", *TINY, "--trials", "2",
                        "--out", str(tmp_path))
    assert code == 1  # no feasible trial, so no best.toml
    assert "FAILED: ValueError: planner diverged" in err and "Traceback" not in err
    rows = list(csv.DictReader((tmp_path / "trials.csv").open()))
    assert [r["state"] for r in rows] == ["FAIL", "FAIL"]
    assert rows[0]["error"] == "ValueError: planner diverged"
    assert not (tmp_path / "best.toml").exists()


@pytest.mark.slow
def test_tiny_tune_writes_a_valid_overlay_and_resumes(tmp_path: Path, capsys) -> None:
    out = tmp_path / "tune"
    code, printed, _ = _run(capsys, "--method", "cimpcc", *TINY, "--trials", "2",
                            "--out", str(out))
    assert code == 0
    for name in ("best.toml", "trials.json", "trials.csv", "history.png", "study.db"):
        assert (out / name).is_file(), name
    cfg = load_config(out / "best.toml")  # the overlay validates
    assert cfg.track.source == "builtin:paperlike"
    doc = json.loads((out / "trials.json").read_text())
    assert doc["study"]["method"] == "cimpcc" and doc["study"]["track"] == "paperlike"
    assert len(doc["trials"]) == 2 and doc["trials"][0]["baseline"]
    best = doc["best"]
    assert best is not None and 12.0 < best["mean_lap_s"] < 16.0
    assert list(cfg.planner.cimpcc.v_up_mps) == best["overlay"]["planner"]["cimpcc"]["v_up_mps"]
    assert cfg.curvature.alpha == best["overlay"]["curvature"]["alpha"]
    assert "best: trial" in printed
    # the bench accepts the overlay as its configuration
    from services.tools.bench.run import main as bench_main

    assert bench_main(["--config", str(out / "best.toml"), "--laps", "1", "--methods",
                       "cimpcc", "--no-reference", "--no-figures",
                       "--out", str(tmp_path / "bench")]) == 0
    # resuming with the budget met adds nothing; a larger budget adds the difference
    code, _, err = _run(capsys, "--method", "cimpcc", *TINY, "--trials", "2", "--out", str(out))
    assert code == 0 and "2 of 2 trials done" in err
    code, _, _ = _run(capsys, "--method", "cimpcc", *TINY, "--trials", "3", "--out", str(out))
    assert code == 0
    assert len(json.loads((out / "trials.json").read_text())["trials"]) == 3
    # the same DIR with other laps is another objective: a clear error
    code, _, err = _run(capsys, "--method", "cimpcc", "--track", "paperlike", "--laps", "2",
                        "--seeds", "0", "--out", str(out))
    assert code == 2 and "differs in: objective" in err


def _default_sigint() -> None:
    """In the child: Ctrl-C as in a terminal (a shell's background job inherits it ignored)."""
    signal.signal(signal.SIGINT, signal.SIG_DFL)


def _workers(storage: str, trials: list) -> set[str]:
    done = [t for t in trials if t.state.is_finished() and not st.interrupted(t)]
    return {t.user_attrs.get("worker", "") for t in done}


@pytest.mark.slow
def test_two_workers_share_one_sqlite_study(tmp_path: Path) -> None:
    storage = f"sqlite:///{tmp_path / 'shared.db'}"
    env = {**os.environ, "MPLBACKEND": "Agg"}
    procs = []
    for k in (1, 2):
        cmd = [sys.executable, "-m", "services.tools.tune.cli", "--method", "cimpcc", *TINY,
               "--trials", "200", "--storage", storage, "--seed", str(k),
               "--out", str(tmp_path / f"w{k}")]
        procs.append(subprocess.Popen(cmd, cwd=ROOT, env=env, stdout=subprocess.PIPE,
                                      stderr=subprocess.PIPE, text=True,
                                      preexec_fn=_default_sigint))
    try:
        deadline = time.monotonic() + 240.0
        workers: set[str] = set()
        while time.monotonic() < deadline and len(workers) < 2:
            time.sleep(1.0)
            if any(p.poll() is not None for p in procs):
                break  # a worker ended early: reported below
            try:
                names = [s.study_name for s in optuna.get_all_study_summaries(storage)]
                if names:
                    workers = _workers(storage, optuna.load_study(
                        study_name=names[0], storage=storage).get_trials())
            except Exception:  # the database is being created by the workers
                continue
    finally:
        ended_early = [p.returncode for p in procs]
        # stopped by PID: the first as by Ctrl-C, the second as by kill
        for p, sig in zip(procs, (signal.SIGINT, signal.SIGTERM), strict=True):
            if p.poll() is None:
                os.kill(p.pid, sig)
        results = [p.communicate(timeout=60) for p in procs]
    assert ended_early == [None, None], results
    assert len(workers) == 2, f"finished trials came from {workers}"
    assert {w.split(":")[-1] for w in workers} == {str(p.pid) for p in procs}
    for p, (_, err) in zip(procs, results, strict=True):
        assert p.returncode == 130, err
        assert "interrupted; writing what was found" in err and "Traceback" not in err
    summaries = optuna.get_all_study_summaries(storage)
    assert len(summaries) == 1  # one study, both workers in it
    for k in (1, 2):
        doc = json.loads((tmp_path / f"w{k}" / "trials.json").read_text())
        assert doc["study"]["study"] == summaries[0].study_name
        assert (tmp_path / f"w{k}" / "best.toml").is_file()
