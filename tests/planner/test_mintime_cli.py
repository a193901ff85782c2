"""``racestack mintime``: the files it writes, the cache, and one-line errors (exit code 2)."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

from services.tools.cli import main as racestack_main
from services.tools.mintime import main
from shared.track import load_f1tenth_raceline


def write_circle_csv(path: Path, radius_m: float, half_width_m: float) -> Path:
    """An F1TENTH centreline CSV of a counter-clockwise circle."""
    n = int(2 * math.pi * radius_m / 0.06)
    th = np.arange(n) * 2 * math.pi / n
    rows = [f"{radius_m * math.cos(t):.6f}, {radius_m * math.sin(t):.6f}, "
            f"{half_width_m}, {half_width_m}" for t in th]
    path.write_text("# x_m, y_m, w_tr_right_m, w_tr_left_m\n" + "\n".join(rows) + "\n")
    return path


@pytest.fixture(scope="module")
def circle_csv(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return write_circle_csv(tmp_path_factory.mktemp("tracks") / "ring_centerline.csv", 3.0, 0.3)


def test_writes_json_csv_and_figures_then_hits_the_cache(
    circle_csv: Path, tmp_path: Path, capsys
) -> None:
    out = tmp_path / "out"
    assert main(["--track", str(circle_csv), "--ds", "0.2", "--out", str(out)]) == 0
    doc = json.loads((out / "mintime.json").read_text())
    for key in ("lap_time_s", "v_max_mps", "track", "solve_time_s", "ds_m", "iterations",
                "tyre_model", "status", "min_clearance_m", "cache_hit"):
        assert key in doc, key
    assert doc["track"] == "ring" and doc["v_max_mps"] == 4.18 and doc["success"]
    assert doc["tyre_model"] == "linear_saturated" and not doc["cache_hit"]
    assert doc["ds_m"] == pytest.approx(0.2, rel=0.02)
    # the raceline reads back with the project's reader
    lines = (out / "raceline.csv").read_text().splitlines()
    assert lines[0].startswith("#") and lines[1].startswith("#")
    assert lines[2] == "# s_m; x_m; y_m; psi_rad; kappa_radpm; vx_mps; ax_mps2"
    table = load_f1tenth_raceline(out / "raceline.csv")
    assert len(table.s_m) == doc["grid_points"]
    assert np.all((table.psi_rad >= 0.0) & (table.psi_rad < 2 * math.pi))
    assert np.allclose(table.vx_mps, 4.18, atol=1e-3)
    radius = np.hypot(table.x_m, table.y_m)
    assert np.allclose(table.kappa_radpm, 1.0 / radius, rtol=0.02)  # left turn: kappa > 0
    seg = np.hypot(np.diff(table.x_m), np.diff(table.y_m))
    assert np.allclose(np.diff(table.s_m), seg, atol=1e-6)
    lap = np.sum(np.append(seg, np.hypot(table.x_m[0] - table.x_m[-1],
                                         table.y_m[0] - table.y_m[-1])) / 4.18)
    assert lap == pytest.approx(doc["lap_time_s"], rel=1e-3)
    for fig in ("mintime_line.png", "mintime_speed.png"):
        assert (out / fig).stat().st_size > 10_000
    printed = capsys.readouterr().out
    assert "solved in" in printed
    # second run: from the cache, same lap
    assert racestack_main(["mintime", "--track", str(circle_csv), "--ds", "0.2",
                           "--out", str(out), "--no-figures"]) == 0
    again = json.loads((out / "mintime.json").read_text())
    assert again["cache_hit"] and again["lap_time_s"] == doc["lap_time_s"]
    assert "from the cache" in capsys.readouterr().out


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["--track", "no-such-track"], "no-such-track"),
        (["--v-max", "fast"], "--v-max must be a number"),
        (["--v-max", "nan"], "--v-max must be finite"),
        (["--v-max", "-1"], "--v-max must be"),
        (["--ds", "0"], "--ds must be"),
        (["--margin", "-0.1"], "--margin must be"),
    ],
)
def test_bad_input_is_one_line_and_exit_code_2(
    tmp_path: Path, capsys, argv: list[str], message: str
) -> None:
    assert main([*argv, "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err
    assert message in err and err.count("\n") == 1, err
    assert not (tmp_path / "o" / "mintime.json").exists()


def test_unwritable_output_folder(tmp_path: Path, capsys) -> None:
    blocker = tmp_path / "file"
    blocker.write_text("not a folder")
    assert main(["--track", "paperlike", "--out", str(blocker / "sub")]) == 2
    err = capsys.readouterr().err
    assert "not writable" in err and err.count("\n") == 1


def test_too_narrow_track_is_one_line_and_exit_code_2(tmp_path: Path, capsys) -> None:
    narrow = write_circle_csv(tmp_path / "narrow_centerline.csv", 3.0, 0.17)
    code = racestack_main(["mintime", "--track", str(narrow), "--out", str(tmp_path / "o")])
    assert code == 2
    err = capsys.readouterr().err
    assert "no feasible lap" in err and err.count("\n") == 1, err
    assert "Traceback" not in err
