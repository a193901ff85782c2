"""The bench's cimpcc-tuned column: the tuned file's weights beside the paper's."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from services.tools.bench.run import main as bench_main
from services.tools.bench.tuned import load_tuned
from shared.config import RacestackConfig

TUNED = """
[planner.cimpcc]
v_up_mps = [4.07, 3.7]
gamma = 50.0

[curvature]
alpha = 3.0
"""


def test_load_tuned_takes_the_files_cimpcc_and_curvature(tmp_path: Path) -> None:
    path = tmp_path / "best.toml"
    path.write_text(TUNED)
    tuned = load_tuned(path, RacestackConfig())
    assert tuned.weights.v_up_mps == (4.07, 3.7) and tuned.weights.gamma == 50.0
    assert tuned.curvature.alpha == 3.0 and tuned.curvature.window_m == 1.2
    assert "from" in tuned.describe() and str(path) in tuned.describe()
    own = load_tuned(None, RacestackConfig())
    assert own.source is None and own.weights == RacestackConfig().planner.cimpcc
    assert "no --tuned file given" in own.describe()


def test_a_bad_tuned_file_is_exit_2(tmp_path: Path, capsys) -> None:
    bad = tmp_path / "bad.toml"
    bad.write_text("[planner.cimpcc]\ngamma = -1\n")
    for tuned in (str(bad), str(tmp_path / "missing.toml")):
        code = bench_main(["--methods", "cimpcc-tuned", "--tuned", tuned, "--laps", "1",
                           "--no-reference", "--no-figures", "--out", str(tmp_path / "o")])
        assert code == 2
        assert capsys.readouterr().err.startswith("racestack bench: error: ")


@pytest.mark.slow
def test_bench_races_the_tuned_column(tmp_path: Path, capsys) -> None:
    path = tmp_path / "best.toml"
    path.write_text(TUNED)
    out = tmp_path / "bench"
    code = bench_main(["--track", "paperlike", "--laps", "1", "--methods", "cimpcc,cimpcc-tuned",
                       "--tuned", str(path), "--no-reference", "--no-figures", "--out", str(out)])
    assert code == 0
    assert "cimpcc-tuned: [planner.cimpcc] and [curvature] from" in capsys.readouterr().err
    doc = json.loads((out / "results.json").read_text())
    tuned, paper = doc["methods"]["cimpcc-tuned"], doc["methods"]["cimpcc"]
    assert tuned["completed_laps"] == 1 and tuned["tuned_file"] == str(path)
    assert tuned["v_up_mps"] == [4.07, 3.7] and tuned["alpha"] == 3.0
    assert tuned["lap_time_s"]["mean"] != paper["lap_time_s"]["mean"]
