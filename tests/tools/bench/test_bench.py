"""The in-process bench: a short run's results.json, figures, and errors before running."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from services.tools.bench.run import main

STATS = {"max", "min", "mean"}


@pytest.mark.slow
def test_short_bench_run_writes_results_and_figures(tmp_path: Path, capsys) -> None:
    out = tmp_path / "out"
    code = main(
        [
            "--track",
            "paperlike",
            "--laps",
            "2",
            "--methods",
            "cimpcc,mpcc-tuned,raceline",
            "--sweep",
            "2.4,2.6",
            "--sweep-laps",
            "1",
            "--out",
            str(out),
        ]
    )
    assert code == 0
    doc = json.loads((out / "results.json").read_text())
    assert doc["track"] == "paperlike"
    assert doc["track_length_m"] == pytest.approx(42.53, abs=0.05)
    assert set(doc["methods"]) == {"cimpcc", "mpcc-tuned", "raceline"}
    for name, m in doc["methods"].items():
        assert m["completed_laps"] == 2, name
        assert len(m["laps"]) == 2
        for lap in m["laps"]:
            assert set(lap) >= {
                "lap_time_s",
                "mean_speed_mps",
                "off_track_events",
                "max_abs_e_con_m",
            }
            assert 8.0 < lap["lap_time_s"] < 30.0
            assert lap["mean_speed_mps"] == pytest.approx(
                doc["track_length_m"] / lap["lap_time_s"], rel=1e-6
            )
        assert set(m["lap_time_s"]) == STATS and set(m["mean_speed_mps"]) == STATS
        assert m["lap_time_s"]["min"] <= m["lap_time_s"]["mean"] <= m["lap_time_s"]["max"]
        assert set(m["solve_time_ms"]) == {"median", "p95", "p99", "max"}
        assert 0 < m["solve_time_ms"]["median"] <= m["solve_time_ms"]["p99"]
        assert isinstance(m["solver_failures"], int)
    # the paper's CiMPCC and the raceline baseline stay on the paper-like track
    for name in ("cimpcc", "raceline"):
        assert all(lap["off_track_events"] == 0 for lap in doc["methods"][name]["laps"])
    assert 8.0 < doc["methods"]["raceline"]["profile_lap_time_s"] < 30.0
    tuned = doc["methods"]["mpcc-tuned"]
    assert tuned["chosen_v_p_ref_mps"] in (2.4, 2.6)
    assert tuned["u_ref"] == [
        pytest.approx(1.1 * tuned["chosen_v_p_ref_mps"]),
        0.0,
        tuned["chosen_v_p_ref_mps"],
    ]
    assert len(tuned["sweep"]) == 2
    for fig in (
        "fig4_curvature",
        "fig5_speed_vs_s",
        "fig6_trajectories",
        "fig7_laps",
        "fig8_solve_time",
    ):
        png = out / f"{fig}.png"
        assert png.stat().st_size > 10_000, fig
    printed = capsys.readouterr().out
    assert "Lap time [s]" in printed and "vs best" in printed and "mpcc-tuned" in printed


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["--track", "no-such-track"], "no-such-track"),
        (["--methods", "cimpcc,pid"], "unknown method(s) pid"),
        (["--laps", "0"], "--laps"),
        (["--methods", ""], "no method"),
    ],
)
def test_bad_arguments_fail_before_running(tmp_path: Path, capsys, argv, message) -> None:
    assert main([*argv, "--out", str(tmp_path / "o")]) == 2
    assert message in capsys.readouterr().err
    assert not (tmp_path / "o" / "results.json").exists()


def test_unwritable_output_folder_is_an_error(tmp_path: Path, capsys) -> None:
    blocker = tmp_path / "file"
    blocker.write_text("not a folder")
    assert main(["--out", str(blocker / "sub"), "--laps", "1"]) == 2
    assert "not writable" in capsys.readouterr().err
