"""The simulated lidar seeing other cars (cast_on_boxes) against analytic cases."""

from __future__ import annotations

import math

import numpy as np
import pytest

from services.simulator.lidar import LidarScanner, cast_on_boxes
from shared.car import CAR
from shared.track.occupancy import FREE, OCCUPIED, OccupancyGrid

L, W = CAR.length_m, CAR.width_m


def _corridor() -> OccupancyGrid:
    """Free for 1 <= y < 3 m over 0 <= x < 20 m, walls below and above (5 cm cells)."""
    cells = np.full((80, 400), FREE, dtype=np.int8)
    cells[:20] = OCCUPIED
    cells[60:] = OCCUPIED
    return OccupancyGrid(cells=cells, resolution_m=0.05, origin_xy_m=np.array([0.0, 0.0]))


def test_rays_meet_the_near_faces() -> None:
    box = np.array([[5.0, 0.0, 0.0]])
    r = cast_on_boxes(0.0, 0.0, np.array([0.0, math.pi, 0.5 * math.pi]), box, 30.0)
    assert r[0] == pytest.approx(5.0 - L / 2)
    assert r[1] == 30.0 and r[2] == 30.0  # behind and beside: no hit
    # a box turned 90 deg seen from below: its nose faces the sensor
    side = np.array([[5.0, 0.0, 0.5 * math.pi]])
    r = cast_on_boxes(5.0, -3.0, np.array([0.5 * math.pi]), side, 30.0)
    assert r[0] == pytest.approx(3.0 - L / 2)


def test_rotated_box_corner_and_nearest_of_two() -> None:
    # a 45 deg box: the ray through its centre meets a long side W / 2 * sqrt(2) before it
    box = np.array([[4.0, 0.0, math.pi / 4], [2.0, 0.0, 0.0]])
    r = cast_on_boxes(0.0, 0.0, np.array([0.0]), box, 30.0)
    assert r[0] == pytest.approx(2.0 - L / 2)  # the nearer box wins
    r = cast_on_boxes(0.0, 0.0, np.array([0.0]), box[:1], 30.0)
    assert r[0] == pytest.approx(4.0 - W / 2 * math.sqrt(2.0))
    # a ray just grazing its front corner (at x = 4 - h, y = +-.. ) from far below-left misses
    h = (L / 2 + W / 2) / math.sqrt(2.0)  # half extent of the 45 deg box along x and y
    r = cast_on_boxes(0.0, h + 0.01, np.array([0.0]), box[:1], 30.0)
    assert r[0] == 30.0


def test_inside_a_box_reads_zero_and_beyond_range_reads_max() -> None:
    box = np.array([[0.1, 0.0, 0.3]])
    assert cast_on_boxes(0.0, 0.0, np.array([1.0]), box, 30.0)[0] == 0.0
    far = np.array([[50.0, 0.0, 0.0]])
    assert cast_on_boxes(0.0, 0.0, np.array([0.0]), far, 30.0)[0] == 30.0
    assert cast_on_boxes(0.0, 0.0, np.array([0.0]), np.zeros((0, 3)), 30.0)[0] == 30.0


def test_scan_with_an_opponent_in_the_corridor() -> None:
    sc = LidarScanner(_corridor(), beams=1081, fov_rad=math.pi, range_max_m=30.0)
    empty = sc.scan(2.0, 2.0, 0.0)
    np.testing.assert_array_equal(sc.scan(2.0, 2.0, 0.0, boxes=np.zeros((0, 3))), empty)
    seen = sc.scan(2.0, 2.0, 0.0, boxes=np.array([[5.0, 2.1, 0.0]]))
    assert seen[540] == pytest.approx(3.0 - L / 2, abs=1e-5)  # straight ahead: the rear face
    changed = seen < empty - 1e-6
    assert 20 < changed.sum() < 200  # the car's angular width only
    assert np.all(seen <= empty)
