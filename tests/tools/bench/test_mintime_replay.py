"""The minimum-time lap is drivable: replayed in the simulator it keeps its time, on track."""

from __future__ import annotations

from pathlib import Path

import pytest

from services.planner.mintime.ocp import MinTimeSettings
from services.planner.mintime.store import make_min_time_lap
from services.tools.bench.replay import ReplayOptions, replay_min_time
from shared.config import load_config
from shared.track import load_track


@pytest.mark.slow
def test_replayed_min_time_lap_on_map416(shared_tracks: Path) -> None:
    track = load_track(shared_tracks / "map416")
    cfg = load_config(None)
    lap = make_min_time_lap(track, cfg.simulator.vehicle, MinTimeSettings(v_max_mps=4.18))
    # an independent solve with the simulator's older linear_saturated tyres: 7.171 s
    assert 7.0 < lap.lap_time_s < 7.25
    assert lap.min_clearance_m > 0.015
    res = replay_min_time(lap, track, cfg.simulator, ReplayOptions(laps=2))
    assert len(res.lap_times_s) == 2
    assert res.off_track_events == 0
    for t in res.lap_times_s:
        # within 1 % of the OCP, and not below it (beyond the grid's accuracy)
        assert lap.lap_time_s * 0.999 < t < lap.lap_time_s * 1.01
    assert res.max_abs_error_m < 0.05
