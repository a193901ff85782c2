"""benchmarks.sysid's loop: the planner told the identified car, the simulator the true
one; the table's honesty count (no racing, no fit: the helpers only)."""

from __future__ import annotations

import numpy as np
import pytest

from benchmarks import sysid as bench
from shared.vehicle.identification import Estimate, SysidResult


def _fitted(rear_d: float) -> SysidResult:
    est = {"pacejka_rear_D": Estimate("pacejka_rear_D", rear_d, 0.001, True),
           "speed_gain_accel_per_s": Estimate("speed_gain_accel_per_s", 4.0, 0.01, True)}
    return SysidResult("pacejka", est, 180.0, np.zeros(2))


def test_the_loop_tells_the_planner_the_identified_car_and_simulates_the_true_one() -> None:
    true = bench.car("softer")
    base = bench.base_for(true)
    ident = bench.identified_table(_fitted(0.45), base)
    cfg = bench.loop_config(ident, true)
    assert cfg.vehicle.pacejka_rear[2] == 0.45
    assert cfg.vehicle.speed_gain_accel_per_s == 4.0
    assert cfg.vehicle.pacejka_front[:3] == bench.NEUTRAL_BCD  # not fitted: the base's
    assert cfg.simulator.vehicle == true


def test_the_table_counts_estimates_within_three_sigmas() -> None:
    res = _fitted(0.45)
    rows, good, told = bench.table("x", res, {"pacejka_rear_D": 0.4635,
                                             "speed_gain_accel_per_s": 4.0})
    # rear D: -2.9 %, within its 5 % but 13.5 sigmas off (not honest); the gain: exact
    assert told == 2 and good == 2
    assert rows[-1].strip().startswith("sigma honest") and "1 of 2" in rows[-1]


def test_a_loop_line_names_the_ratio_and_the_off_track_events() -> None:
    got = {"mean_lap_s": 8.4, "limit_s": 8.1, "ratio": 8.4 / 8.1, "off_track": 3,
           "off_track_out_lap": 3, "laps": 3, "lines_wall_s": 1.0, "race_wall_s": 2.0}
    line = bench.loop_line("told the identified car", "map416", got)
    assert "1.037" in line and "off-track 3 (3 in the out lap)" in line


def test_the_loop_races_with_the_true_pose_s_tube(monkeypatch) -> None:
    """The loop races on the true pose, so it builds its lines and planner as the bench
    does for it (``for_pose_source(..., "truth")``: the raceline's truth tube)."""
    from services.planner import for_pose_source

    true = bench.car("softer")
    cfg = bench.loop_config(bench.identified_table(_fitted(0.45), bench.base_for(true)), true)
    seen: dict = {}

    def solve(track, car, settings, use, progress):
        seen["line_margin_m"] = settings.margin_m

    class Pool:
        def __init__(self, track, vehicle):
            pass

        def planner(self, settings, method, curvature):
            seen["settings"] = settings
            raise RuntimeError("stop here")

    monkeypatch.setattr(bench, "make_min_time_lap", solve)
    monkeypatch.setattr(bench, "min_time_reference", lambda track, cfg: None)
    monkeypatch.setattr(bench, "PlannerPool", Pool)
    with pytest.raises(RuntimeError, match="stop here"):
        bench.race_identified(cfg, "paperlike", "raceline", 1)
    want = for_pose_source(cfg.planner, "truth")
    assert seen["settings"] == want
    assert want.raceline.min_time_margin_m > cfg.planner.raceline.min_time_margin_m
    # the line solved is the one the planner loads: the tube's margin (plus the servo's)
    assert seen["line_margin_m"] >= want.raceline.min_time_margin_m
