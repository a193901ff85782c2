"""The lidar particle filter (services/localization_bridge/particle_filter.py) against the
simulator's car, sensors and lidar, in plain loops (simulated time only, no timing checks)."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from pydantic import ValidationError

from benchmarks.particle_filter import drive, pf_settings_for, sim_settings, time_to_localise
from services.localization_bridge.motion_model import MotionNoise, propagate
from services.localization_bridge.particle_filter import FilterMap, ParticleFilter, PfEstimate
from services.localization_bridge.resampling import effective_sample_size, low_variance_indices
from services.simulator.lidar import LidarScanner
from shared.config.particle_filter import ParticleFilterSettings
from shared.messages import Scan
from shared.track import OccupancyGrid, Track, load_ros_map, load_track

SIM = sim_settings(0)
PFS = pf_settings_for(SIM)
Grid = tuple[OccupancyGrid, Track]


def _rear_pose(track: Track, s_m: float) -> tuple[float, float, float]:
    x, y = (float(c) for c in track.point_at(s_m))
    return x, y, float(track.heading_at(s_m))


def _scan(lidar: LidarScanner, pose: tuple[float, float, float], lidar_x_m: float) -> Scan:
    x, y, yaw = pose
    ranges = lidar.scan(x + lidar_x_m * math.cos(yaw), y + lidar_x_m * math.sin(yaw), yaw)
    return Scan(
        stamp_s=0.0,
        angle_min_rad=lidar.angle_min_rad,
        angle_increment_rad=lidar.angle_increment_rad,
        ranges_m=ranges,
    )


def _err(est: PfEstimate, pose: tuple[float, float, float]) -> tuple[float, float]:
    return (
        math.hypot(est.x_m - pose[0], est.y_m - pose[1]),
        abs(math.remainder(est.yaw_rad - pose[2], math.tau)),
    )


def test_converges_on_a_known_pose_from_a_wrong_one(paperlike: Grid) -> None:
    grid, track = paperlike
    off = (0.3 * math.cos(1.0), 0.3 * math.sin(1.0), math.radians(10.0))  # 0.3 m, 10 deg
    log, pf = drive(grid, track, PFS, duration_s=1.5, init="pose", init_offset=off, seed=1)
    assert log.err_pos_m[0] > 0.1  # it did start off
    assert max(log.err_pos_m[-20:]) < 0.05
    assert max(log.err_yaw_rad[-20:]) < math.radians(1.0)
    assert log.converged[-1] and not any(log.lost)  # never 'lost' while converging
    assert pf.estimate().particles == PFS.particles


def test_tracks_a_short_simulated_drive(paperlike: Grid) -> None:
    grid, track = paperlike
    log, _ = drive(
        grid, track, PFS, duration_s=3.0, speed_mps=4.5, seed=2, init_std=(0.02, 0.01)
    )
    e, a = np.asarray(log.err_pos_m), np.asarray(log.err_yaw_rad)
    assert len(e) >= 100  # 40 Hz for 3 s
    assert math.sqrt(np.mean(e**2)) < 0.03 and e.max() < 0.08
    assert math.sqrt(np.mean(a**2)) < math.radians(1.0)
    assert all(log.converged) and not any(log.lost)


def test_global_initialisation_on_the_builtin_track(paperlike: Grid) -> None:
    grid, track = paperlike
    log, pf = drive(grid, track, PFS, duration_s=2.0, init="global", start_s_m=17.0, seed=3)
    assert time_to_localise(log) <= 2.0
    assert pf.estimate().converged and pf.estimate().particles == PFS.particles


def test_global_initialisation_on_map416(shared_tracks: Path) -> None:
    grid = load_ros_map(shared_tracks / "map416" / "map416.yaml")
    track = load_track(shared_tracks / "map416")
    log, _ = drive(grid, track, PFS, duration_s=2.0, init="global", start_s_m=20.0, seed=4)
    assert time_to_localise(log) <= 2.0


def test_infinite_and_out_of_range_beams_are_skipped(paperlike: Grid) -> None:
    grid, track = paperlike
    lidar = LidarScanner(grid, beams=1080)
    pose = _rear_pose(track, 5.0)
    pf = ParticleFilter(grid, PFS, seed=0)
    pf.init_pose(*pose, std_xy_m=0.05, std_yaw_rad=0.02)
    scan = _scan(lidar, pose, PFS.lidar_x_m)
    ranges = np.array(scan.ranges_m)
    ranges[::2] = np.inf
    ranges[1::4] = 1e6  # beyond range_max: no return either
    holed = Scan(stamp_s=0.0, angle_min_rad=scan.angle_min_rad,
                 angle_increment_rad=scan.angle_increment_rad, ranges_m=ranges)
    for _ in range(10):
        pf.predict(0.025, 0.0, 0.0)
        est = pf.update(holed)
    assert np.all(np.isfinite(est.cov)) and _err(est, pose)[0] < 0.05
    none = Scan(stamp_s=0.0, angle_min_rad=scan.angle_min_rad,
                angle_increment_rad=scan.angle_increment_rad, ranges_m=np.full(1080, np.inf))
    before = pf.poses
    est2 = pf.update(none)
    assert pf.skipped_scans == 1 and np.array_equal(pf.poses, before)
    assert math.isfinite(est2.x_m) and est2.x_m == pytest.approx(est.x_m, abs=0.02)


def test_bad_motion_input_is_counted_not_applied(paperlike: Grid) -> None:
    grid, track = paperlike
    pf = ParticleFilter(grid, PFS, seed=0)
    pf.init_pose(*_rear_pose(track, 5.0))
    before = pf.poses
    pf.predict(0.01, math.nan, 0.0)
    pf.predict(math.inf, 1.0, 0.0)
    pf.predict(-0.01, 1.0, 0.0)
    assert pf.rejected_inputs == 2 and np.array_equal(pf.poses, before)
    with pytest.raises(ValueError):
        pf.init_pose(math.nan, 0.0, 0.0)


def test_same_seed_same_output(paperlike: Grid) -> None:
    grid, track = paperlike
    lidar = LidarScanner(grid, beams=360)
    poses = [_rear_pose(track, 3.0 + 0.1 * k) for k in range(6)]
    scans = [_scan(lidar, p, PFS.lidar_x_m) for p in poses]

    def run(seed: int) -> np.ndarray:
        pf = ParticleFilter(grid, PFS, seed=seed)
        pf.init_pose(*poses[0])
        for sc in scans:
            pf.predict(0.025, 4.0, 0.0)
            pf.update(sc)
        return pf.poses

    a, b, c = run(7), run(7), run(8)
    assert np.array_equal(a, b) and not np.array_equal(a, c)


def test_a_shared_filter_map_gives_the_same_output_and_is_checked(paperlike: Grid) -> None:
    grid, track = paperlike
    lidar = LidarScanner(grid, beams=360)
    poses = [_rear_pose(track, 3.0 + 0.1 * k) for k in range(6)]
    scans = [_scan(lidar, p, PFS.lidar_x_m) for p in poses]
    fmap = FilterMap.build(grid, PFS)

    def run(filter_map: FilterMap | None) -> np.ndarray:
        pf = ParticleFilter(grid, PFS, seed=3, filter_map=filter_map)
        pf.init_pose(*poses[0])
        for sc in scans:
            pf.predict(0.025, 4.0, 0.0)
            pf.update(sc)
        return pf.poses

    # one map built once serves several filters, each as if it had built its own
    assert np.array_equal(run(None), run(fmap)) and np.array_equal(run(fmap), run(fmap))
    with pytest.raises(ValueError, match="another grid or other settings"):
        ParticleFilter(grid, PFS.model_copy(update={"z_rand": 0.2}), filter_map=fmap)
    other = OccupancyGrid(grid.cells.copy(), grid.resolution_m, grid.origin_xy_m,
                          grid.origin_yaw_rad)
    with pytest.raises(ValueError, match="another grid"):
        ParticleFilter(other, PFS, filter_map=fmap)


def test_a_kidnapped_filter_says_lost_and_starts_over(paperlike: Grid) -> None:
    grid, track = paperlike
    settings = pf_settings_for(SIM, lost_reinit_scans=5)
    lidar = LidarScanner(grid, beams=720)
    here, there = _rear_pose(track, 5.0), _rear_pose(track, 25.0)
    pf = ParticleFilter(grid, settings, seed=0)
    pf.init_pose(*here, std_xy_m=0.02, std_yaw_rad=0.01)
    for _ in range(5):
        est = pf.update(_scan(lidar, here, settings.lidar_x_m))
    assert est.converged and not est.lost and est.fitness > 0.5
    inits = pf.global_inits
    lost_seen = False
    for _ in range(30):
        est = pf.update(_scan(lidar, there, settings.lidar_x_m))
        lost_seen |= est.lost
    # 20 m away: first a search near where it tracked (it finds nothing), then the map
    assert lost_seen and pf.local_inits == 1 and pf.global_inits > inits


def test_a_filter_lost_in_a_spin_searches_near_where_it_was_first(paperlike: Grid) -> None:
    """A spin: the scans stop matching the motion (here: the car turned 90 degrees and
    moved 0.5 m between two scans, the odometry saying nothing of it). The random
    particles and the re-initialisation stay within the local radius of the last tracked
    pose, so the filter never jumps to a look-alike stretch elsewhere."""
    grid, track = paperlike
    settings = pf_settings_for(SIM, lost_reinit_scans=10)
    lidar = LidarScanner(grid, beams=720)
    here = _rear_pose(track, 5.0)
    pf = ParticleFilter(grid, settings, seed=1)
    pf.init_pose(*here, std_xy_m=0.02, std_yaw_rad=0.01)
    for _ in range(5):
        pf.update(_scan(lidar, here, settings.lidar_x_m))
    spun = (here[0] + 0.5 * math.cos(here[2]), here[1] + 0.5 * math.sin(here[2]),
            here[2] + math.pi / 2)
    far = 0.0
    for _ in range(60):
        est = pf.update(_scan(lidar, spun, settings.lidar_x_m))
        pf.predict(0.025, 0.0, 0.0)
        far = max(far, float(np.max(np.hypot(pf.poses[:, 0] - here[0],
                                             pf.poses[:, 1] - here[1]))))
    # no particle beyond the radius (and the motion noise) of the poses it tracked
    assert far <= settings.local_reinit_radius_m + 1.0
    assert pf.global_inits == 1  # the constructor's only
    x, yaw = _err(est, spun)  # (along a straight, seen across it, 0.25 m is ambiguous)
    assert x < 0.3 and yaw < 0.05 and est.converged and not est.lost


def test_settings_are_validated() -> None:
    assert PFS.particles >= 1000 and PFS.beams >= 60
    assert PFS.lidar_x_m == pytest.approx(SIM.vehicle.lr_m + SIM.lidar.mount_x_m)
    with pytest.raises(ValidationError):
        ParticleFilterSettings(particels=10)  # type: ignore[call-arg]
    with pytest.raises(ValidationError):
        ParticleFilterSettings(z_rand=0.0)
    with pytest.raises(ValidationError):
        ParticleFilterSettings(range_min_m=5.0, range_max_m=4.0)


def test_low_variance_resampling_keeps_the_proportions() -> None:
    w = np.array([0.5, 0.25, 0.125, 0.125])
    idx = low_variance_indices(w, 800, np.random.default_rng(0))
    np.testing.assert_array_equal(np.bincount(idx, minlength=4), [400, 200, 100, 100])
    assert effective_sample_size(np.full(10, 0.1)) == pytest.approx(10.0)
    assert effective_sample_size(np.array([1.0, 0.0])) == pytest.approx(1.0)


def test_noise_free_motion_follows_the_arc() -> None:
    poses = np.zeros((3, 3))
    still = MotionNoise(0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
    rng = np.random.default_rng(0)
    for _ in range(100):  # a quarter circle of radius 2 m at 1 m/s in pi s
        propagate(poses, math.pi / 100, 1.0, 0.5, still, rng)
    np.testing.assert_allclose(poses[0], [2.0, 2.0, math.pi / 2], atol=1e-3)
    noisy = MotionNoise(0.01, 0.0, 0.01, 0.0, 0.01, 0.0)
    many = np.zeros((4000, 3))
    for _ in range(100):  # 1 s in 100 steps: std 0.01 * sqrt(1 s) whatever the step count
        propagate(many, 0.01, 0.0, 0.0, noisy, rng)
    assert np.std(many[:, 0]) == pytest.approx(0.01, rel=0.1)
    assert np.std(many[:, 2]) == pytest.approx(0.01, rel=0.1)
