"""The bench's minimum-time reference: results.json, the table, and no lap below the limit."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from services.tools.bench.run import main
from shared.evaluation import LapRecord, MethodRun, Trace, format_table, results_document


def _run(name: str, laps: list[float]) -> MethodRun:
    records = [LapRecord(t, 30.0 / t, 0, 0.1) for t in laps]
    return MethodRun(name, records, Trace(), [0.5, 0.6], 0, len(laps))


def test_reference_adds_the_ratio_per_method_and_a_table_row() -> None:
    ref = {"min_time_lap_s": 7.5, "v_max_mps": 4.18}
    doc = results_document("t", 30.0, [_run("a", [9.0, 10.0]), _run("b", [])], reference=ref)
    assert doc["reference"] == ref
    assert doc["methods"]["a"]["ratio_to_min_time"] == pytest.approx(9.5 / 7.5)
    assert doc["methods"]["b"]["ratio_to_min_time"] is None
    text = format_table(doc)
    assert "7.500 s at v_max 4.18 m/s" in text
    row = next(line for line in text.splitlines() if "mean lap / min-time" in line)
    assert "1.267" in row and "-" in row
    plain = results_document("t", 30.0, [_run("a", [9.0])])
    assert "reference" not in plain and "ratio_to_min_time" not in plain["methods"]["a"]
    assert "min-time" not in format_table(plain)


@pytest.mark.slow
def test_no_method_is_faster_than_the_minimum_time_lap(tmp_path: Path, capsys) -> None:
    """A lap below the physical limit of the simulated car would be a bug (in the timing,
    the simulator or the OCP)."""
    out = tmp_path / "out"
    code = main(["--track", "paperlike", "--laps", "2", "--methods", "cimpcc,raceline",
                 "--no-figures", "--out", str(out)])
    assert code == 0
    doc = json.loads((out / "results.json").read_text())
    ref = doc["reference"]
    assert ref["v_max_mps"] == 4.18
    # paperlike at 4.18 m/s; an independent solve with the simulator's older tyres: 9.561 s
    assert 9.3 < ref["min_time_lap_s"] < 9.7
    for name, m in doc["methods"].items():
        assert m["completed_laps"] == 2, name
        assert m["lap_time_s"]["min"] > ref["min_time_lap_s"], name
        assert m["ratio_to_min_time"] == pytest.approx(
            m["lap_time_s"]["mean"] / ref["min_time_lap_s"]
        )
        assert 1.0 < m["ratio_to_min_time"] < 2.0, name
    printed = capsys.readouterr().out
    assert "mean lap / min-time" in printed and "minimum-time lap" in printed


@pytest.mark.slow
def test_no_reference_option_skips_it(tmp_path: Path) -> None:
    out = tmp_path / "out"
    code = main(["--track", "paperlike", "--laps", "1", "--methods", "raceline",
                 "--no-figures", "--no-reference", "--out", str(out)])
    assert code == 0
    doc = json.loads((out / "results.json").read_text())
    assert "reference" not in doc
    assert "ratio_to_min_time" not in doc["methods"]["raceline"]
