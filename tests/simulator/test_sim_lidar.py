"""Lidar ray marching against analytic cases; the distance transform against brute force."""

from __future__ import annotations

import math

import numpy as np
import pytest

from services.simulator.lidar import LidarScanner, distance_transform
from shared.track import load_track, rasterize_track
from shared.track.occupancy import FREE, OCCUPIED, UNKNOWN, OccupancyGrid

RES = 0.05


def _corridor() -> OccupancyGrid:
    """Free for 1 <= y < 3 m over 0 <= x < 20 m, walls below and above."""
    cells = np.full((80, 400), FREE, dtype=np.int8)
    cells[:20] = OCCUPIED
    cells[60:] = OCCUPIED
    return OccupancyGrid(cells=cells, resolution_m=RES, origin_xy_m=np.array([0.0, 0.0]))


def test_distance_transform_matches_brute_force() -> None:
    rng = np.random.default_rng(3)
    blocked = rng.random((50, 64)) < 0.015
    cap = 12
    d = distance_transform(blocked, cap)
    occ = np.argwhere(blocked)
    ii, jj = np.mgrid[0:50, 0:64]
    exact = np.sqrt(((ii[..., None] - occ[:, 0]) ** 2 + (jj[..., None] - occ[:, 1]) ** 2).min(-1))
    np.testing.assert_allclose(d, np.minimum(exact, cap), atol=1e-5)
    assert d.dtype == np.float32


def test_perpendicular_beams_measure_the_half_width() -> None:
    sc = LidarScanner(_corridor(), beams=1081, fov_rad=math.pi, range_max_m=30.0)
    ranges = sc.scan(10.0, 2.0, 0.0)  # beam 0 at -pi/2 (right), 540 ahead, 1080 left
    assert ranges[0] == pytest.approx(1.0, abs=RES)
    assert ranges[1080] == pytest.approx(1.0, abs=RES)
    assert ranges[540] == 30.0  # ahead leaves the map: no return


def test_oblique_beams_match_the_analytic_walls() -> None:
    sc = LidarScanner(_corridor(), beams=721, fov_rad=4.7, range_max_m=30.0)
    x0, y0, yaw = 10.0, 1.7, 0.3
    ranges = sc.scan(x0, y0, yaw).astype(float)
    ang = sc.angle_min_rad + sc.angle_increment_rad * np.arange(721) + yaw
    s = np.sin(ang)
    with np.errstate(divide="ignore"):
        to_wall = np.where(s > 0, (3.0 - y0) / s, (1.0 - y0) / s)
    x_hit = x0 + to_wall * np.cos(ang)
    ok = (np.abs(s) > 0.05) & (x_hit > 0.2) & (x_hit < 19.8) & (to_wall < 30.0)
    assert ok.sum() > 500
    assert np.max(np.abs(ranges[ok] - to_wall[ok])) <= RES


def test_rasterised_track_half_widths() -> None:
    track = load_track("gentle")
    grid = rasterize_track(track, resolution_m=0.1, margin_m=0.5)
    sc = LidarScanner(grid, beams=1081, fov_rad=math.pi)
    # the straight along y = 0 at the start (heading +x)
    s0 = 2.0
    x, y = track.point_at(s0)
    yaw = float(track.heading_at(s0))
    assert abs(yaw) < 1e-6
    ranges = sc.scan(float(x), float(y), yaw)
    w_r, w_l = track.interp_width(s0)
    assert ranges[0] == pytest.approx(float(w_r), abs=0.1)
    assert ranges[1080] == pytest.approx(float(w_l), abs=0.1)


def test_special_cases() -> None:
    grid = _corridor()
    sc = LidarScanner(grid, beams=1080, fov_rad=4.7)
    assert np.all(sc.scan(10.0, 0.5, 0.0) == 0.0)  # inside a wall
    cells = np.array(grid.cells)
    cells[60:] = UNKNOWN
    open_top = OccupancyGrid(cells=cells, resolution_m=RES, origin_xy_m=np.zeros(2))
    up = LidarScanner(open_top, beams=1081, fov_rad=math.pi, unknown_is_occupied=False)
    assert up.scan(10.0, 2.0, 0.0)[1080] == 30.0  # unknown is free: leaves the map
    stops = LidarScanner(open_top, beams=1081, fov_rad=math.pi, unknown_is_occupied=True)
    assert stops.scan(10.0, 2.0, 0.0)[1080] == pytest.approx(1.0, abs=RES)
