"""shared.track.raycast: the simulator's lidar is the shared ray marcher; its scans end on
the walls of the particle filter's likelihood field (within a cell)."""

from __future__ import annotations

import math

import numpy as np

from services.localization_bridge.likelihood_field import LikelihoodField, wall_distance_m
from services.simulator.lidar import LidarScanner
from shared.track import Track
from shared.track.occupancy import FREE, OCCUPIED, OccupancyGrid
from shared.track.raycast import RayMarcher, blocked_cells, to_grid_frame

RES = 0.05


def _free_poses(grid: OccupancyGrid, n: int, seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    clear = wall_distance_m(blocked_cells(grid), RES, 0.5)
    rc = np.argwhere((np.asarray(grid.cells) == FREE) & (clear >= 0.2))
    pick = rc[rng.integers(0, len(rc), n)]
    x = grid.origin_xy_m[0] + (pick[:, 1] + 0.5) * RES
    y = grid.origin_xy_m[1] + (pick[:, 0] + 0.5) * RES
    return np.stack([x, y, rng.uniform(-math.pi, math.pi, n)], axis=1)


def test_the_lidar_is_the_shared_ray_marcher(paperlike: tuple[OccupancyGrid, Track]) -> None:
    grid = paperlike[0]
    lidar = LidarScanner(grid, beams=541, fov_rad=4.7, range_max_m=30.0)
    marcher = RayMarcher(grid)
    for x, y, yaw in _free_poses(grid, 10, 1):
        expect = lidar.scan(float(x), float(y), float(yaw))
        ang = lidar.angle_min_rad + lidar.angle_increment_rad * np.arange(541) + yaw
        got = marcher.cast(x, y, ang, 30.0).astype(np.float32)
        np.testing.assert_array_equal(got, expect)


def test_many_poses_at_once_match_one_at_a_time(paperlike: tuple[OccupancyGrid, Track]) -> None:
    grid = paperlike[0]
    marcher = RayMarcher(grid)
    poses = _free_poses(grid, 50, 2)
    ang = poses[:, 2:3] + np.linspace(-2.0, 2.0, 30)
    batch = marcher.cast(poses[:, 0:1], poses[:, 1:2], ang, 20.0)
    assert batch.shape == (50, 30)
    for i in range(0, 50, 7):
        np.testing.assert_allclose(batch[i], marcher.cast(poses[i, 0], poses[i, 1], ang[i], 20.0))


def test_ranges_match_fine_stepping_within_a_cell(paperlike: tuple[OccupancyGrid, Track]) -> None:
    grid = paperlike[0]
    marcher = RayMarcher(grid)
    poses = _free_poses(grid, 10, 3)
    ang = poses[:, 2:3] + np.linspace(-2.3, 2.3, 20)
    got = marcher.cast(poses[:, 0:1], poses[:, 1:2], ang, 15.0)
    # brute force: 5 mm steps until an occupied cell
    t = np.arange(0.0, 15.0, 0.005)
    px = poses[:, 0:1, None] + t * np.cos(ang)[..., None]
    py = poses[:, 1:2, None] + t * np.sin(ang)[..., None]
    occ = grid.occupied_at(np.stack([px, py], axis=-1))
    first = np.where(occ.any(-1), t[np.argmax(occ, axis=-1)], 15.0)
    err = np.abs(got - first)
    # within half a cell, but for rays that graze a cell corner (the marcher's half-cell
    # steps may cut it): those stay within two cells
    assert np.percentile(err, 98) <= 0.5 * RES
    assert np.max(err) <= 2 * RES


def test_scan_end_points_lie_on_the_likelihood_field_walls(
    paperlike: tuple[OccupancyGrid, Track],
) -> None:
    grid = paperlike[0]
    field = LikelihoodField(grid, (0.05,), 0.9, 0.1, cap_m=1.0, upsample=2)
    lidar = LidarScanner(grid, beams=361, fov_rad=4.7, range_max_m=30.0)
    for x, y, yaw in _free_poses(grid, 8, 4):
        r = lidar.scan(float(x), float(y), float(yaw)).astype(float)
        hit = r < 30.0
        a = lidar.angle_min_rad + lidar.angle_increment_rad * np.arange(361) + yaw
        ex, ey = x + r * np.cos(a), y + r * np.sin(a)
        gx, gy = to_grid_frame(grid, ex, ey)
        col = np.floor(gx / field.cell_m).astype(int) + 2
        row = np.floor(gy / field.cell_m).astype(int) + 2
        d = field.distance_m[row, col]
        assert np.all(d[hit] <= RES + 1e-6)


def test_wall_distance_is_measured_from_both_sides() -> None:
    cells = np.full((20, 20), FREE, dtype=np.int8)
    cells[:, 10:] = OCCUPIED
    d = wall_distance_m(cells == OCCUPIED, 1.0, 5.0)
    np.testing.assert_allclose(d[5, 7:13], [2.5, 1.5, 0.5, 0.5, 1.5, 2.5])
