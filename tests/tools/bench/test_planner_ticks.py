"""The tick-cost benchmark's bookkeeping (``benchmarks/planner_ticks.py``): the timing
wrapper, the figures and the table, on a fake planner (the races themselves are the
benchmark's, not a test's)."""

from __future__ import annotations

import pytest

from benchmarks import planner_ticks as pt
from benchmarks.robustness import BenchError


class _Fake:
    """A planner whose ticks 3 and 4 do grip re-plan work."""

    def __init__(self) -> None:
        self.replan_work_done = 0
        self.ticks = 0

    def step(self, x: float) -> float:
        self.ticks += 1
        if self.ticks in (3, 4):
            self.replan_work_done += 500
        return 2.0 * x


def test_the_wrapper_times_each_tick_and_marks_the_re_plan_ones() -> None:
    planner, times = _Fake(), pt.TickTimes()
    times.attach(planner)
    assert [planner.step(float(k)) for k in range(30)] == [2.0 * k for k in range(30)]
    assert len(times.cpu_ms) == len(times.wall_ms) == 30
    assert times.replan == [k in (2, 3) for k in range(30)]
    assert all(c >= 0.0 for c in times.cpu_ms) and all(w >= 0.0 for w in times.wall_ms)


def test_the_figures_keep_the_start_and_the_re_plan_ticks_apart() -> None:
    cpu = [3.0] + [0.5] * 29 + [2.5] + [0.6] * 9
    replan = [False] * 30 + [True] + [False] * 9
    t = pt.TickTimes(wall_ms=[c + 0.1 for c in cpu], cpu_ms=cpu, replan=replan)
    f = pt.tick_figures(t)
    assert f["ticks"] == 40 and f["replan_ticks"] == 1
    assert f["cpu_max_ms"] == 3.0 and f["cpu_first_ticks_max_ms"] == 3.0
    assert f["cpu_max_after_start_ms"] == 2.5 and f["cpu_replan_max_ms"] == 2.5
    assert f["cpu_over_budget"] == 2 and f["wall_max_ms"] == pytest.approx(3.1)
    assert pt.tick_figures(pt.TickTimes()) == {"ticks": 0}
    rec = {"cell": "gen:3/identified-on-default/truth", "mode": "sliced", "ratio": 1.07,
           "off_track": 2, "spins": 0, "error": None, **f}
    assert pt.row(rec).startswith("gen:3/identified-on-default/truth")
    assert len(pt.row(rec)) == len(pt.HEADER)
    at_once = {**rec, "mode": "at-once", "cpu_max_ms": 19.0, "cpu_replan_max_ms": 19.0}
    lines = pt.summary([rec, at_once])
    assert lines[0].startswith("ticks sliced: 40 ticks in 1 cells, CPU max 3.00 ms")
    assert "re-plan ticks 1 with CPU max 19.00 ms" in lines[1]


def test_a_malformed_cell_is_a_clear_error() -> None:
    with pytest.raises(BenchError, match="TRACK/CAR/POSE"):
        pt.run(["gen:3/nocar/truth"], ["sliced"], 1, "raceline")
    assert pt.main(["--cells", "gen:3/identified"]) == 2
