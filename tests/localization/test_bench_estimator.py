"""The bench's estimator in the loop (``--estimator ekf|lidar``): the simulator's sensors
through the bridge's filter in the same process; ``truth`` adds nothing."""

from __future__ import annotations

import math

import pytest

from services.simulator import Command, centreline_pose, rear_axle
from services.tools.bench import build_parser
from services.tools.bench.closed_loop import LoopOptions, SimulatorPlant
from services.tools.bench.estimation import InLoopEstimator
from shared.config.localization import LocalizationSettings
from shared.config.simulator import SimulatorSettings
from shared.track import load_track


def test_the_estimator_option_parses_and_defaults_to_truth() -> None:
    assert build_parser().parse_args([]).estimator == "truth"
    assert build_parser().parse_args(["--estimator", "lidar"]).estimator == "lidar"


def test_truth_has_no_estimator_and_ekf_tracks_the_car() -> None:
    track = load_track("paperlike")
    sim = SimulatorSettings()
    assert SimulatorPlant(track, sim, LoopOptions(laps=1)).estimator is None
    plant = SimulatorPlant(track, sim, LoopOptions(laps=1, estimator="ekf"))
    est = plant.estimator
    assert isinstance(est, InLoopEstimator)
    for _ in range(150):  # 1.5 s along the first straight at 2 m/s
        est.feed(plant.sim.step(Command(2.0, 0.0), 0.01))
    x, y, yaw = plant.pose()
    tx, ty, tyaw = plant.true_pose()
    assert math.hypot(x - tx, y - ty) < 0.05 and abs(yaw - tyaw) < 0.05
    err = est.errors()
    assert err["estimator"] == "ekf" and err["invalid_ticks"] == 0
    assert err["counts"]["pose_applied"] > 40


def test_the_start_pose_is_the_rear_axle_of_the_bench_start() -> None:
    track = load_track("paperlike")
    sim = SimulatorSettings()
    p = centreline_pose(track, 0.3)
    start = rear_axle(p.x_m, p.y_m, p.yaw_rad, sim.vehicle.lr_m)
    est = InLoopEstimator("ekf", track, sim, LocalizationSettings(), start)
    e = est.filter.estimate(0.0)
    assert e.valid and math.hypot(e.x_m - start[0], e.y_m - start[1]) < 1e-9


def test_the_lidar_grid_is_made_once_per_track_in_a_process(monkeypatch) -> None:
    from services.tools.bench import estimation

    made: list[str] = []
    monkeypatch.setattr(estimation, "occupancy_for", lambda t: made.append(t.name) or object())
    monkeypatch.setattr(estimation, "_GRIDS", {})
    monkeypatch.setattr(estimation, "GRID_CACHE_SIZE", 2)
    a, b = load_track("paperlike"), load_track("paperlike")  # two loads of one track
    grid = estimation.track_grid(a)
    assert estimation.track_grid(b) is grid and made == ["paperlike"]
    other = estimation.track_grid(load_track("gen:1"))
    assert other is not grid and len(made) == 2
    estimation.track_grid(load_track("gen:2"))  # a bounded cache: the oldest goes
    assert len(estimation._GRIDS) == 2
    assert estimation.track_grid(a) is not grid and made[-1] == "paperlike"


def test_the_lateral_error_is_the_error_across_the_car() -> None:
    track = load_track("paperlike")
    sim = SimulatorSettings()
    est = InLoopEstimator("ekf", track, sim, LocalizationSettings(), (0.0, 0.0, 0.0))
    e = est.filter.estimate(0.0)
    # the car heads along +y: an estimate 3 cm behind it and 1 cm to its right
    truth = (e.x_m + 0.01, e.y_m + 0.03, math.pi / 2)
    est.pose(0.0, truth)
    err = est.errors()
    assert err["rms_position_m"] == pytest.approx(math.hypot(0.01, 0.03))
    assert err["rms_lateral_m"] == pytest.approx(0.01)
    assert err["p95_lateral_m"] == pytest.approx(0.01)
    assert err["max_lateral_m"] == pytest.approx(0.01)


def test_the_lidar_and_filter_maps_are_made_once_and_change_nothing(monkeypatch) -> None:
    from services.tools.bench import estimation

    for cache in ("_GRIDS", "_MARCHERS", "_FILTER_MAPS"):
        monkeypatch.setattr(estimation, cache, {})
    track = load_track("paperlike")
    sim = SimulatorSettings()
    loc = LocalizationSettings()
    grid, marcher, fmap = estimation.lidar_maps(track, sim, loc)
    again = estimation.lidar_maps(load_track("paperlike"), sim, loc)
    assert again[0] is grid and again[1] is marcher and again[2] is fmap

    def race(shared: bool) -> list[tuple[float, float, float]]:
        if not shared:  # every cache empty: this run builds its own maps
            for cache in ("_GRIDS", "_MARCHERS", "_FILTER_MAPS"):
                monkeypatch.setattr(estimation, cache, {})
        plant = SimulatorPlant(track, sim, LoopOptions(laps=1, estimator="lidar"))
        out = []
        for _ in range(60):  # 0.6 s, a dozen scans
            plant.estimator.feed(plant.sim.step(Command(2.0, 0.0), 0.01))
            out.append(plant.pose())
        return out

    assert race(shared=False) == race(shared=True)
