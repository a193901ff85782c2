"""``racestack report`` names the method as the registry does (as ``up`` says it) and adds
the min-time ratio when the minimum-time lap of the car is in the cache (issue #22)."""

from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace

import numpy as np

import services.planner as planner_pkg
from services.tools import report
from shared.config import RacestackConfig
from shared.config.methods import CIMPCC, MPCC
from shared.curvature import track_profile
from shared.evaluation import format_table, results_document
from shared.track import load_track


def _data(method: str) -> report.RecordingData:
    laps = [{"kind": "start", "lap": 0, "t_s": 1.0},
            {"kind": "lap", "lap": 1, "lap_time_s": 10.0, "mean_speed_mps": 4.2,
             "off_track_events": 0, "max_abs_e_con_m": 0.1, "t_s": 11.0}]
    return report.RecordingData(
        path=Path("run/telemetry.rrd"),
        rows={"plan/info": [{"method": method, "t_s": 0.5}], "events/lap": laps},
    )


def test_the_method_keeps_its_registry_name() -> None:
    track = load_track("paperlike")
    profile = track_profile(track, RacestackConfig().curvature)
    for method in (CIMPCC, MPCC):
        assert report.method_run(_data(method), track, profile).name == method
    assert report.method_run(_data("not-a-method"), track, profile).name == "recorded"


def test_no_cached_limit_no_ratio_and_one_line_naming_the_command(monkeypatch, tmp_path) -> None:
    monkeypatch.setenv("RACESTACK_CACHE", str(tmp_path))  # an empty cache
    ref, why = report.limit_reference(load_track("paperlike"), RacestackConfig())
    assert ref is None and why.startswith("no min-time ratio: no minimum-time lap of this car")
    assert "\n" not in why and "mintime --for limit --track builtin:paperlike" in why


def test_a_cached_limit_gives_the_ratio(monkeypatch) -> None:
    lap = SimpleNamespace(lap_time_s=8.0, v_max_mps=4.18, tyre_model="linear", ds_m=0.1,
                          margin_m=0.02, status="Solve_Succeeded", solve_time_s=3.0,
                          cache_hit=True)
    monkeypatch.setattr(planner_pkg, "load_min_time_lap", lambda *a, **k: lap)
    track = load_track("paperlike")
    ref, why = report.limit_reference(track, RacestackConfig())
    assert why == "" and ref["min_time_lap_s"] == 8.0
    profile = track_profile(track, RacestackConfig().curvature)
    run = report.method_run(_data(CIMPCC), track, profile)
    doc = results_document(track.name, track.length_m, [run], reference=ref)
    assert np.isclose(doc["methods"][CIMPCC]["ratio_to_min_time"], 10.0 / 8.0)
    assert "mean lap / min-time" in format_table(doc)
