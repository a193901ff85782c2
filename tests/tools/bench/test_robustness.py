"""The robustness benchmark (``benchmarks/robustness.py``): its cell and summary functions
(spin detection on crafted slip traces, the ratio, the counts, the cap), and a tiny matrix
raced in process (slow)."""

from __future__ import annotations

import json
import math
import re
from pathlib import Path

import numpy as np
import pytest

from benchmarks import robustness as rb
from services.planner import limit_request
from shared.config import config_from_dict
from shared.config.methods import CIMPCC_LINE, RACELINE
from shared.config.vehicle import F1TENTH_GYM, REAL_CAR_IDENTIFIED
from shared.evaluation import LapRecord, MethodRun, Trace, results_document

PEAK = 0.1
DT = 0.05


def _slip_trace(over_s: float, dt: float = DT, total_s: float = 2.0, sign: float = 1.0,
                level: float = 2.0) -> tuple[list[float], list[float]]:
    """A slip trace sampled every `dt`: under the peak, then `over_s` beyond it from 0.5 s."""
    t = np.arange(round(total_s / dt)) * dt
    slip = np.full(t.shape, 0.5 * PEAK)
    n_over = round(over_s / dt)
    start = round(0.5 / dt)
    slip[start:start + n_over] = sign * level * PEAK
    return t.tolist(), slip.tolist()


@pytest.mark.parametrize("dt", [0.05, 0.01])
def test_a_short_slide_is_no_spin_and_a_long_one_is(dt: float) -> None:
    assert rb.spin_events(*_slip_trace(0.15, dt), PEAK) == 0
    assert rb.spin_events(*_slip_trace(0.25, dt), PEAK) == 1
    assert rb.spin_events(*_slip_trace(0.25, dt, sign=-1.0), PEAK) == 1  # either direction


def test_cornering_just_past_the_peak_is_no_spin() -> None:
    """Saturated tyres hold the slip just past the peak at the friction limit: not a spin."""
    assert rb.spin_events(*_slip_trace(1.0, level=1.3), PEAK) == 0
    assert rb.spin_events(*_slip_trace(1.0, level=1.6), PEAK) == 1


def test_spins_are_counted_per_slide_and_at_the_trace_end() -> None:
    t, slip = _slip_trace(0.3)
    slip = np.asarray(slip)
    slip[20:26] = -2 * PEAK  # a second slide of 0.3 s
    slip[-5:] = 2 * PEAK  # 0.25 s beyond the peak until the trace ends
    assert rb.spin_events(t, slip, PEAK) == 3
    assert rb.spin_events([], [], PEAK) == 0
    assert rb.spin_events(t, np.zeros(len(t)), PEAK) == 0


def test_the_rear_peak_slip_of_each_tyre_model() -> None:
    assert rb.rear_peak_slip_rad(F1TENTH_GYM) == pytest.approx(
        1.0 / F1TENTH_GYM.cornering_stiffness_rear_per_rad)
    # the identified rear: B 20, C 1.5, E 0 peaks at B alpha = tan(pi / (2 C))
    assert rb.rear_peak_slip_rad(REAL_CAR_IDENTIFIED) == pytest.approx(
        math.tan(math.pi / 3.0) / 20.0, rel=1e-6)


def test_linear_tyres_have_no_peak_so_a_spin_is_judged_against_their_limit_lap() -> None:
    """The gym's unbounded linear tyres: the car's own limit lap asks for several times
    ``1 / C_Sr`` at the rear, so that lap's largest rear slip is their reference."""
    linear = F1TENTH_GYM.model_copy(update={"tyre_model": "linear"})
    nominal = 1.0 / linear.cornering_stiffness_rear_per_rad
    n = 50
    v, r = np.full(n, 3.0), np.full(n, 2.0)
    beta = np.linspace(-0.3, 0.3, n)
    states = np.zeros((n, len(rb.STATE_NAMES)))
    states[:, rb.V_MPS], states[:, rb.BETA], states[:, rb.R_RADPS] = v, beta, r
    lap = type("Lap", (), {"states": states})()
    alpha = np.arctan(np.tan(beta) - linear.lr_m * r / (v * np.cos(beta)))
    assert rb.lap_rear_slip_rad(lap, linear) == pytest.approx(np.abs(alpha).max())
    lap_slip = rb.lap_rear_slip_rad(lap, linear)
    assert rb.rear_peak_slip_rad(linear, lap_slip) == pytest.approx(
        max(nominal, np.abs(alpha).max()))
    assert rb.rear_peak_slip_rad(linear) == pytest.approx(nominal)  # no lap: nominal
    # the other tyres keep their own peak whatever the lap
    assert rb.rear_peak_slip_rad(F1TENTH_GYM, lap_slip) == pytest.approx(nominal)
    assert rb.rear_peak_slip_rad(REAL_CAR_IDENTIFIED, lap_slip) == rb.rear_peak_slip_rad(
        REAL_CAR_IDENTIFIED)


def test_the_target_line_names_the_worst_cell_per_pose_source_and_the_verdict() -> None:
    m = RACELINE
    cells = [
        _cell("a", "default", "truth", **{m: _rec(1.01)}),
        _cell("b", "identified", "truth", **{m: _rec(1.02)}),
        _cell("a", "default", "ekf", **{m: _rec(1.06, False)}),
        _cell("a", "identified-on-default", "truth", **{m: _rec(1.12)}),
    ]
    s = rb.summarise(cells, m)
    assert s["worst_cell"] == {"truth": "b identified", "ekf": "a default", "lidar": None}
    assert s["worst_cell_mismatch"] == "a identified-on-default"
    assert rb.target_line(m, s) == (
        f"targets {m}: truth 1.020 (b identified) vs 1.03 met; ekf 1.060 (a default) vs "
        "1.05 NOT met; lidar -; mismatch 1.120 (a identified-on-default) vs 1.15 met; "
        "clean 3/4 cells")
    assert rb.wall_line({"minimum-time laps": 30.0, "cells": 1770.0}) == (
        "wall time: 1800 s (30.0 min; minimum-time laps 30 s, cells 1770 s) vs 30 min met")
    assert rb.wall_line({"cells": 1801.0}).endswith("NOT met")


def _run(laps: list[float], off: int = 0, recoveries: int = 0, slip_over_s: float = 0.0,
         requested: int | None = None, speed: float = 4.0) -> MethodRun:
    t, slip = _slip_trace(slip_over_s)
    trace = Trace(t_s=t, speed_mps=[speed] * len(t), rear_slip_rad=slip)
    records = [LapRecord(x, 30.0 / x, 0, 0.1) for x in laps]
    return MethodRun("m", records, trace, [0.5, 0.7, 1.9], 0,
                     requested if requested is not None else len(laps),
                     {"recoveries": recoveries}, off, 0)


def _record(run: MethodRun, limit_s: float = 7.0, cap: float = 4.18) -> dict:
    doc = results_document("t", 30.0, [run], reference={"min_time_lap_s": limit_s,
                                                         "v_max_mps": cap})
    return rb.method_record(run, doc["methods"]["m"], PEAK)


def test_a_method_record_has_the_ratio_the_counts_and_the_verdict() -> None:
    rec = _record(_run([7.07, 7.21]))
    assert rec["ratio"] == pytest.approx(7.14 / 7.0)
    assert (rec["laps_completed"], rec["laps_requested"]) == (2, 2)
    assert (rec["off_track"], rec["recoveries"], rec["spins"]) == (0, 0, 0)
    assert rec["below_limit_laps"] == 0 and rec["over_cap_events"] == 0
    assert rec["solve_ms_median"] == pytest.approx(0.7)
    assert rec["clean"]
    for run in (_run([7.1, 7.2], off=1), _run([7.1, 7.2], recoveries=2),
                _run([7.1, 7.2], slip_over_s=0.3), _run([7.1], requested=2),
                _run([6.9, 7.1]), _run([7.1, 7.2], speed=4.3)):
        assert not _record(run)["clean"]
    assert _record(_run([7.1, 7.2], slip_over_s=0.3))["spins"] == 1
    assert _record(_run([6.9, 7.1]))["below_limit_laps"] == 1
    assert _record(_run([7.1, 7.2], speed=4.3))["over_cap_events"] == 1


def _cell(track: str, car: str, pose: str, **recs: dict) -> dict:
    return {"key": f"{track}|{car}|{pose}", "track": track, "track_spec": track, "car": car,
            "knows_car": rb.CARS[car].knows_car, "pose": pose, "methods": recs,
            "wall_s": 2.0}


def _rec(ratio: float | None, clean: bool = True, **kw) -> dict:
    base = {"ratio": ratio, "laps_completed": 2, "laps_requested": 2, "off_track": 0,
            "recoveries": 0, "spins": 0, "below_limit_laps": 0, "over_cap_events": 0,
            "solve_ms_median": 0.8, "solve_ms_p99": 1.5, "clean": clean, "errors": [],
            "aborted": ""}
    return {**base, **kw}


def test_the_summary_counts_and_worst_ratios() -> None:
    m = CIMPCC_LINE
    cells = [
        _cell("a", "default", "truth", **{m: _rec(1.01)}),
        _cell("a", "default", "ekf", **{m: _rec(1.04, False, off_track=3, spins=1)}),
        _cell("a", "identified", "lidar", **{m: _rec(1.07)}),
        _cell("a", "identified-on-default", "truth",
              **{m: _rec(1.30, False, laps_completed=1, recoveries=2)}),
        _cell("b", "default", "truth", **{m: _rec(None, False, laps_completed=0,
                                                  solve_ms_p99=2.5, solve_ms_max=3.25)}),
    ]
    s = rb.summarise(cells, m)
    assert s["cells"] == 5 and s["clean"] == 2
    assert s["worst_ratio"] == {"truth": 1.01, "ekf": 1.04, "lidar": 1.07}
    assert s["worst_ratio_mismatch"] == 1.30
    assert (s["off_track"], s["spins"], s["recoveries"], s["unfinished"]) == (3, 1, 2, 2)
    assert s["worst_solve_ms_p99"] == 2.5 and s["worst_solve_ms_max"] == 3.25
    line = rb.summary_line(m, s)
    assert line == (
        f"robustness {m}: 5 cells, clean 2/5, worst ratio (truth/ekf/lidar) 1.01/1.04/1.07, "
        "mismatch 1.30, off-track 3, recoveries 2, spins 1, below-limit 0, over-cap 0, "
        "unfinished 2, solve p99 max 2.50 ms, slowest tick 3.2 ms")
    table = rb.format_table(cells, [m, RACELINE]).splitlines()
    assert len(table) == 3 + len(cells) + 1  # two header lines, a rule, the rows, the legend
    assert all(len(row) == len(table[1]) for row in table[3:-1])
    grouped = rb.grouped_table(cells, [m]).splitlines()
    # two header lines, one row per (group, car, pose): tracks a and b are one group here
    assert len(grouped) == 2 + 4
    assert grouped[2].split()[:7] == ["other", "default", "truth", "|", "1/2", "1.010", "1.010"]
    worst = rb.worst_cells(cells, [m])
    assert worst[0].startswith("b ") and worst[1].startswith("a ")  # fewest laps first


def test_the_cap_follows_v_max_for_every_method_and_the_limit() -> None:
    cfg = rb.config_for("default", 10.0)
    assert cfg.planner.cimpcc.v_up_mps[0] == pytest.approx(10.0)
    assert cfg.planner.cimpcc.v_up_mps[0] == pytest.approx(1.1 * cfg.planner.cimpcc.v_up_mps[1],
                                                           abs=0.01)
    assert cfg.planner.cimpcc_line.v_max_mps == pytest.approx(10.0)
    assert cfg.planner.raceline.v_max_mps == pytest.approx(10.0)
    assert limit_request(cfg.planner, cfg.simulator.vehicle).settings.v_max_mps == (
        pytest.approx(10.0))
    plain = rb.config_for("default")
    assert plain.planner == config_from_dict({}).planner  # no --v-max: the config's own
    assert plain.planner.cimpcc.v_up_mps[0] == pytest.approx(4.18)


def test_a_coarser_grid_puts_the_limit_and_the_raceline_s_line_on_it() -> None:
    cfg = rb.config_for("default", 10.0, 0.25)
    assert cfg.planner.raceline.ds_m == pytest.approx(0.25)
    assert limit_request(cfg.planner, cfg.simulator.vehicle, 0.25).settings.ds_m == 0.25
    matrix = rb.Matrix(("paperlike",), ("default",), ("truth",), (RACELINE,), 1, 10.0, 0.25)
    tasks = rb.lap_tasks(matrix)
    assert sorted(t.use for t in tasks) == sorted(["limit", RACELINE])
    assert all(t.settings.ds_m == pytest.approx(0.25) for t in tasks)
    assert all(t.settings.v_max_mps == pytest.approx(10.0) for t in tasks)
    args = rb.build_parser().parse_args(["--tracks", "paperlike", "--min-time-ds", "0.25"])
    assert rb.matrix_from_args(args).ds_m == 0.25
    assert rb.config_for("default").planner.raceline.ds_m == pytest.approx(0.1)
    with pytest.raises(rb.BenchError, match="min-time-ds"):
        rb.matrix_from_args(rb.build_parser().parse_args(["--tracks", "paperlike",
                                                          "--min-time-ds", "5"]))


def test_long_tracks_take_the_coarser_grid_unless_one_grid_is_given(tmp_path: Path) -> None:
    """The whole matrix: the F1TENTH maps (260-460 m) on 0.25 m, the short tracks on the
    configuration's 0.1 m; --min-time-ds one grid for all."""
    long_csv = tmp_path / "long.csv"
    t = np.linspace(0.0, 2.0 * np.pi, 400, endpoint=False)
    rows = [f"{50 * np.cos(a):.4f},{40 * np.sin(a):.4f},1.1,1.1" for a in t]
    long_csv.write_text("# x_m,y_m,w_tr_right_m,w_tr_left_m\n" + "\n".join(rows) + "\n")
    auto = rb.Matrix((str(long_csv), "paperlike"), ("default",), ("truth",), (RACELINE,))
    assert rb._track(str(long_csv)).length_m > rb.LONG_TRACK_M
    assert auto.ds_for(str(long_csv)) == rb.LONG_TRACK_DS_M
    assert auto.ds_for("paperlike") is None
    grids = {(t.track, t.use): t.settings.ds_m for t in rb.lap_tasks(auto)}
    assert grids[(str(long_csv), "limit")] == pytest.approx(rb.LONG_TRACK_DS_M)
    assert grids[(str(long_csv), RACELINE)] == pytest.approx(rb.LONG_TRACK_DS_M)
    assert grids[("paperlike", RACELINE)] == pytest.approx(0.1)
    one = rb.Matrix((str(long_csv), "paperlike"), ("default",), ("truth",), (RACELINE,),
                    ds_m=0.2)
    assert [t.settings.ds_m for t in rb.lap_tasks(one)] == pytest.approx([0.2] * 4)


def test_the_costliest_cells_go_first_each_track_and_car_together() -> None:
    cells = rb.Matrix(("a", "b"), ("default", "linear"), ("truth", "ekf", "lidar"),
                      (RACELINE,)).cells()
    length = {"a": 100.0, "b": 30.0}
    order = rb.cell_order(cells, length.__getitem__)
    assert sorted(order, key=lambda c: c.key) == sorted(cells, key=lambda c: c.key)
    assert [(c.track, c.pose) for c in order[:3]] == [("a", "lidar"), ("a", "ekf"),
                                                      ("a", "truth")]
    assert len({(c.track, c.car) for c in order[:3]}) == 1  # one group at a time
    assert [c.track for c in order] == ["a"] * 6 + ["b"] * 6


def test_the_cars_of_the_matrix() -> None:
    assert rb.config_for("linear").vehicle.tyre_model == "linear"
    assert not rb.config_for("linear").simulates_another_car
    told = rb.config_for("identified")
    assert told.vehicle.tyre_model == "pacejka" and not told.simulates_another_car
    mismatch = rb.config_for("identified-on-default")
    assert mismatch.simulates_another_car
    assert mismatch.vehicle == F1TENTH_GYM
    assert mismatch.simulator.vehicle.tyre_model == "pacejka"
    # a seeded variant of the identified car, the planners told it
    varied = rb.config_for("varied:3")
    assert varied.vehicle.tyre_model == "pacejka" and not varied.simulates_another_car
    assert varied.vehicle.pacejka_front != told.vehicle.pacejka_front
    args = rb.build_parser().parse_args(["--tracks", "paperlike", "--cars", "varied:3,default"])
    assert rb.matrix_from_args(args).cars == ("varied:3", "default")
    with pytest.raises(rb.BenchError, match="varied:SEED"):
        rb.matrix_from_args(rb.build_parser().parse_args(["--tracks", "paperlike",
                                                          "--cars", "varied:x"]))


def test_the_matrix_and_its_laps(tmp_path: Path) -> None:
    groups = rb.track_groups(tmp_path)
    assert [len(groups[g]) for g in ("builtin", "f1tenth", "generated")] == [2, 6, 20]
    assert len(rb.resolve_tracks("all", tmp_path)) == 28
    assert rb.resolve_tracks("map416,paperlike,builtin", tmp_path) == list(groups["builtin"])
    matrix = rb.Matrix(("paperlike",), ("default", "identified-on-default"), ("truth", "ekf"),
                       (CIMPCC_LINE, RACELINE))
    assert len(matrix.cells()) == 4
    # the limits of both simulated cars, the planners' (default) lines once, the raceline's
    # for each pose source's margin (truth_margin_m, ekf_margin_m widen it)
    tasks = rb.lap_tasks(matrix)
    uses = sorted(t.use for t in tasks)
    assert uses == sorted([CIMPCC_LINE, RACELINE, RACELINE, "limit", "limit"])
    margins = sorted(t.settings.margin_m for t in tasks if t.use == RACELINE)
    o = rb.config_for("default").planner.raceline
    assert margins == pytest.approx([o.min_time_margin_m + o.truth_margin_m,
                                     o.min_time_margin_m + o.ekf_margin_m])


@pytest.mark.slow
def test_a_tiny_matrix_races_and_reports(tmp_path: Path, capsys) -> None:
    out = tmp_path / "robust"
    code = rb.main(["--tracks", "paperlike", "--cars", "default", "--poses", "truth",
                    "--methods", RACELINE, "--laps", "1", "--jobs", "1", "--out", str(out)])
    assert code == 0
    printed = capsys.readouterr().out
    doc = json.loads((out / "robustness.json").read_text(encoding="utf-8"))
    assert doc["matrix"]["cells"] == 1 and len(doc["cells"]) == 1
    cell = doc["cells"][0]
    assert (cell["track"], cell["car"], cell["pose"]) == ("paperlike", "default", "truth")
    rec = cell["methods"][RACELINE]
    assert rec["laps_completed"] == 1 and rec["ratio"] is not None and rec["ratio"] > 0.99
    assert len((out / "cells.jsonl").read_text(encoding="utf-8").splitlines()) == 1
    text = (out / "robustness.txt").read_text(encoding="utf-8")
    assert text.strip() in printed
    rows = [r for r in text.splitlines() if r.startswith("paperlike ")]
    assert len(rows) == 2  # the table's row and the worst-cells row
    summary = text.strip().splitlines()[-1]
    assert re.fullmatch(
        rf"robustness {RACELINE}: 1 cells, clean [01]/1, worst ratio \(truth/ekf/lidar\) "
        r"\d\.\d\d/-/-, off-track \d+, recoveries \d+, spins \d+, below-limit \d+, "
        r"over-cap \d+, unfinished [01], solve p99 max \d+\.\d\d ms, slowest tick \d+\.\d ms",
        summary), summary
    assert doc["summary"][RACELINE]["cells"] == 1


def test_a_config_file_lays_its_tables_over_every_car(tmp_path: Path) -> None:
    """``--config FILE``: the file's tables over each car's, the cap's and the grid's (the
    laps it changes keyed on the settings it gives); a wrong file is a BenchError."""
    f = tmp_path / "try.toml"
    f.write_text("[planner.raceline]\nk_lateral_radpm = 0.4\nmin_time_reserve_speed_mps = 6.0\n",
                 encoding="utf-8")
    args = rb.build_parser().parse_args(["--tracks", "paperlike", "--v-max", "10",
                                         "--config", str(f)])
    matrix = rb.matrix_from_args(args)
    assert matrix.extra == {"planner": {"raceline": {"k_lateral_radpm": 0.4,
                                                     "min_time_reserve_speed_mps": 6.0}}}
    for car in ("default", "identified"):
        o = rb.config_for(car, 10.0, None, matrix.extra).planner.raceline
        assert (o.k_lateral_radpm, o.min_time_reserve_speed_mps, o.v_max_mps) == (0.4, 6.0, 10.0)
    tasks = [t for t in rb.lap_tasks(matrix) if t.use == RACELINE]
    assert tasks and all(t.settings.reserve_speed_mps == 6.0 for t in tasks)
    assert rb.matrix_from_args(rb.build_parser().parse_args(["--tracks", "paperlike"])).extra == {}
    f.write_text("[planner.raceline]\nk_lateral_radpm = -1\n", encoding="utf-8")
    with pytest.raises(rb.BenchError, match="--config"):
        rb.matrix_from_args(args)
