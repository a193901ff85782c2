"""Opponent detection (box fit on synthetic scans) and tracking (services/localization_bridge/
opponents.py). Scans are made with the simulator's lidar seeing the opponent's footprint."""

from __future__ import annotations

import math

import numpy as np
import pytest

from services.localization_bridge.opponents import (
    DetectorParams,
    OpponentDetector,
    OpponentTracker,
    fit_car_box,
)
from services.simulator.lidar import LidarScanner
from shared.car import CAR
from shared.track import OccupancyGrid, Track

L, W = CAR.length_m, CAR.width_m
NOISE_M = 0.01


def _on_track(track: Track, s: float, lateral_m: float) -> np.ndarray:
    yaw = float(track.heading_at(s))
    x, y = (float(v) for v in track.point_at(s))
    return np.array([x - lateral_m * math.sin(yaw), y + lateral_m * math.cos(yaw), yaw])


def _scenes(track: Track, n: int, seed: int) -> list[tuple[np.ndarray, np.ndarray]]:
    """n (ego pose, opponent pose) pairs, the opponent 0.8-5 m ahead along the track."""
    rng = np.random.default_rng(seed)
    out = []
    for _ in range(n):
        s = rng.uniform(0.0, track.length_m)
        ego = _on_track(track, s, rng.uniform(-0.2, 0.2))
        opp = _on_track(track, s + rng.uniform(0.8, 5.0), rng.uniform(-0.35, 0.35))
        out.append((ego, opp))
    return out


@pytest.fixture(scope="module")
def setup(paperlike: tuple[OccupancyGrid, Track]) -> tuple[LidarScanner, OpponentDetector, Track]:
    grid, track = paperlike
    sc = LidarScanner(grid, beams=1080, fov_rad=4.7, range_max_m=30.0)
    return sc, OpponentDetector(grid, track=track), track


def _detect(sc: LidarScanner, det: OpponentDetector, ranges: np.ndarray, ego: np.ndarray):
    return det.detect(ranges, sc.angle_min_rad, sc.angle_increment_rad, sc.range_max_m, ego)


def _noisy(r: np.ndarray, rng: np.random.Generator, rmax: float) -> np.ndarray:
    return np.where(r < rmax, r + rng.normal(0.0, NOISE_M, r.shape), r)


def test_recall_and_position_error_on_synthetic_scans(setup) -> None:
    sc, det, track = setup
    rng = np.random.default_rng(11)
    visible, errors = 0, []
    for ego, opp in _scenes(track, 80, seed=1):
        empty = sc.scan(*ego)
        seen = sc.scan(*ego, boxes=opp[None, :])
        on_car = int(np.sum(seen < empty - 1e-3))
        if on_car < 4 or math.hypot(*(opp[:2] - ego[:2])) > 5.0:
            continue  # hidden behind a wall of the hairpins: nobody can see it
        visible += 1
        dets = _detect(sc, det, _noisy(seen.astype(float), rng, sc.range_max_m), ego)
        e = min((math.hypot(d.x_m - opp[0], d.y_m - opp[1]) for d in dets), default=math.inf)
        assert len(dets) <= 1  # nothing else on the track
        if e <= 0.3:
            errors.append(e)
    assert visible >= 40
    assert len(errors) / visible >= 0.95
    assert math.sqrt(np.mean(np.square(errors))) <= 0.05


def test_no_detection_on_the_empty_track(setup) -> None:
    sc, det, track = setup
    rng = np.random.default_rng(12)
    for ego, _ in _scenes(track, 60, seed=2):
        ranges = _noisy(sc.scan(*ego).astype(float), rng, sc.range_max_m)
        assert _detect(sc, det, ranges, ego) == []


def test_bad_ranges_are_no_returns(setup) -> None:
    sc, det, track = setup
    ego = _on_track(track, 3.0, 0.0)
    bad = np.full(sc.beams, np.nan)
    bad[::3] = -1.0
    bad[1::3] = np.inf
    assert _detect(sc, det, bad, ego) == []
    assert _detect(sc, det, np.zeros(0), ego) == []


def _face(a: np.ndarray, b: np.ndarray, n: int) -> np.ndarray:
    return a + np.linspace(0.0, 1.0, n)[:, None] * (b - a)


def test_box_fit_rear_face_only_and_l_shape() -> None:
    # a car at (3, 0) heading +x seen from the origin: only its rear face at x = 3 - L / 2
    rear = _face(np.array([3.0 - L / 2, -W / 2]), np.array([3.0 - L / 2, W / 2]), 12)
    x, y, yaw = fit_car_box(rear, (0.0, 0.0), heading_hint_rad=0.0)
    assert (x, y) == pytest.approx((3.0, 0.0), abs=0.01)
    assert math.cos(yaw) ** 2 == pytest.approx(1.0, abs=1e-3)
    # seen from behind-right: the rear face and the right side
    side = _face(np.array([3.0 - L / 2, -W / 2]), np.array([3.0 + L / 2, -W / 2]), 20)
    x, y, _ = fit_car_box(np.vstack([rear[::-1], side]), (0.0, -2.0))
    assert (x, y) == pytest.approx((3.0, 0.0), abs=0.01)


def test_box_fit_rejects_what_is_not_car_sized() -> None:
    wall = _face(np.array([0.0, 1.0]), np.array([1.5, 1.0]), 40)
    assert fit_car_box(wall, (0.0, 0.0)) is None
    speck = _face(np.array([2.0, 0.0]), np.array([2.03, 0.0]), 5)
    assert fit_car_box(speck, (0.0, 0.0)) is None
    assert fit_car_box(wall[:2], (0.0, 0.0), DetectorParams()) is None  # too few points


@pytest.mark.parametrize(("with_yaw", "bound_mps"), [(True, 0.15), (False, 0.4)])
def test_tracker_velocity_of_a_moving_opponent(with_yaw: bool, bound_mps: float) -> None:
    rng = np.random.default_rng(3)
    tr = OpponentTracker()
    v = np.array([3.0, -1.0])
    yaw = math.atan2(v[1], v[0]) + math.pi  # the box's axis: front and back look alike
    for i in range(60):
        t = i / 40.0
        z = np.array([1.0, 2.0]) + v * t + rng.normal(0.0, 0.015, 2)
        tracks = tr.update(t, [(z[0], z[1], yaw) if with_yaw else (z[0], z[1])])
    assert len(tracks) == 1
    assert np.hypot(*(np.array(tracks[0].velocity) - v)) < bound_mps
    assert tracks[0].P.shape == (4, 4)


def test_ids_kept_through_a_pass_and_an_occlusion() -> None:
    # car 1 overtakes car 2 on its left (0.4 m apart at the pass); car 2 hidden for 4 scans
    rng = np.random.default_rng(4)
    tr = OpponentTracker()
    ids: dict[int, set[int]] = {0: set(), 1: set()}
    for i in range(80):
        t = i / 40.0
        cars = [np.array([4.0 * t, 0.4]), np.array([1.0 + 2.5 * t, 0.0])]
        shown = [0, 1] if not 38 <= i < 42 else [0]
        z = [tuple(cars[k] + rng.normal(0.0, 0.01, 2)) for k in shown]
        for trk in tr.update(t, z):
            k = int(np.argmin([np.hypot(*(np.array(trk.position) - c)) for c in cars]))
            if i > 5:
                ids[k].add(trk.track_id)
    assert len(ids[0]) == 1 and len(ids[1]) == 1 and ids[0] != ids[1]
    assert [trk.track_id for trk in tr.tracks] == sorted(ids[0] | ids[1])


def test_tracks_die_after_max_misses_and_are_born_confirmed_late() -> None:
    tr = OpponentTracker()
    assert tr.update(0.0, [(1.0, 1.0)]) == []  # tentative
    tr.update(0.025, [(1.0, 1.0)])
    assert len(tr.update(0.05, [(1.0, 1.0)])) == 1  # confirmed on the third hit
    for i in range(tr.params.max_misses + 1):
        tr.update(0.075 + 0.025 * i, [])
    assert tr.tracks == []


def test_non_finite_detections_are_counted_and_dropped() -> None:
    tr = OpponentTracker()
    tr.update(0.0, [(math.nan, 1.0), (1.0, 2.0, math.inf), (1.0,), (2.0, 2.0)])
    assert tr.dropped == 3
    assert [t.position for t in tr.tracks] == [(2.0, 2.0)]
