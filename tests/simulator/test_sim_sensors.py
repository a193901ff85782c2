"""Sensors: zero noise gives the truth, rates and latency, seeded noise statistics."""

from __future__ import annotations

import math

import numpy as np
import pytest

from services.simulator.sensors import SensorSuite
from services.simulator.state import Command, Pose2D, rear_axle
from services.simulator.vehicle import Simulator
from shared.angles import wrap_angle
from shared.config.simulator import SimulatorSettings
from shared.track.occupancy import FREE, OCCUPIED, OccupancyGrid

NOISELESS = {
    "pose": {"position_noise_std_m": 0.0, "yaw_noise_std_rad": 0.0},
    "imu": {"yaw_rate_noise_std_radps": 0.0, "accel_noise_std_mps2": 0.0},
    "odometry": {"speed_noise_std_mps": 0.0, "steering_noise_std_rad": 0.0},
    "lidar": {"noise_std_m": 0.0},
}


def _run(settings: SimulatorSettings, seconds: float, grid: OccupancyGrid | None = None):
    sim = Simulator(settings)
    sim.reset(Pose2D(0.0, 0.0, 3.0), speed_mps=2.0)
    suite = SensorSuite(settings, grid)
    truths, readings = [], []
    for k in range(round(seconds / 0.01)):
        res = sim.step(Command(2.5, 0.25 * math.sin(0.02 * k)), 0.01)
        truths.append(res)
        readings.append(suite.update(res))
    return truths, readings


def test_zero_noise_reproduces_truth_with_rate_and_latency() -> None:
    s = SimulatorSettings.model_validate(NOISELESS)
    truths, readings = _run(s, 2.0)
    by_time = {round(r.t_s, 6): r for r in truths}
    poses = [m for r in readings for m in r.pose]
    # 40 Hz over 2 s, the last ones still in flight
    assert 76 <= len(poses) <= 80
    for m in poses:
        truth = by_time[round(m.stamp_s, 6)].state
        # the localiser's pose is the rear axle (base_link), lr behind the CoG
        rx, ry, _ = rear_axle(truth.x_m, truth.y_m, truth.yaw_rad, s.vehicle.lr_m)
        assert (m.x_m, m.y_m) == pytest.approx((rx, ry), abs=1e-12)
        assert m.yaw_rad == pytest.approx(wrap_angle(truth.yaw_rad), abs=1e-12)
        assert m.release_s == pytest.approx(m.stamp_s + 0.02)
    # released at the first step at or after stamp + latency, not before
    for r, step in zip(truths, readings, strict=True):
        for m in step.pose:
            assert r.t_s + 1e-9 >= m.release_s and r.t_s - 0.01 < m.release_s
    gaps = np.diff([m.stamp_s for m in poses])
    assert gaps.min() >= 0.02 - 1e-9 and gaps.max() <= 0.03 + 1e-9
    assert np.mean(gaps) == pytest.approx(0.025, abs=0.001)
    imu = [m for r in readings for m in r.imu]
    assert len(imu) == len(truths)  # 100 Hz = every step
    for m in imu:
        t = by_time[round(m.stamp_s, 6)]
        assert m.yaw_rate_radps == t.state.yaw_rate_radps
        assert (m.accel_long_mps2, m.accel_lat_mps2) == (t.accel_long_mps2, t.accel_lat_mps2)
    odo = [m for r in readings for m in r.odometry]
    assert 99 <= len(odo) <= 101
    for m in odo:
        st = by_time[round(m.stamp_s, 6)].state
        assert m.speed_mps == st.v_mps * math.cos(st.slip_rad)
        assert m.steering_rad == st.delta_rad


def test_imu_lateral_acceleration_in_steady_cornering() -> None:
    sim = Simulator()
    sim.reset(Pose2D(0.0, 0.0, 0.0), speed_mps=2.0, steering_rad=0.15)
    for _ in range(300):
        res = sim.step(Command(2.0, 0.15), 0.01)
    st = res.state
    # centripetal v * psi_dot, seen in the body frame rotated by the slip angle
    centripetal = st.v_mps * st.yaw_rate_radps
    assert res.accel_lat_mps2 == pytest.approx(centripetal * math.cos(st.slip_rad), rel=1e-3)
    assert res.accel_long_mps2 == pytest.approx(-centripetal * math.sin(st.slip_rad), rel=1e-2)


def test_noise_is_seeded_and_has_the_set_spread() -> None:
    data = {
        "seed": 7,
        "pose": {"rate_hz": 100.0, "latency_s": 0.0, "position_noise_std_m": 0.1},
        "odometry": {"rate_hz": 100.0, "speed_noise_std_mps": 0.2},
    }
    s = SimulatorSettings.model_validate(data)
    truths, readings = _run(s, 20.0)
    by_time = {round(r.t_s, 6): r.state for r in truths}
    lr = s.vehicle.lr_m
    ex = np.array(
        [
            m.x_m - rear_axle(st.x_m, st.y_m, st.yaw_rad, lr)[0]
            for r in readings
            for m in r.pose
            for st in (by_time[round(m.stamp_s, 6)],)
        ]
    )
    ev = np.array(
        [
            m.speed_mps
            - by_time[round(m.stamp_s, 6)].v_mps * math.cos(by_time[round(m.stamp_s, 6)].slip_rad)
            for r in readings
            for m in r.odometry
        ]
    )
    assert ex.size > 1900
    assert np.std(ex) == pytest.approx(0.1, rel=0.1) and abs(np.mean(ex)) < 0.01
    assert np.std(ev) == pytest.approx(0.2, rel=0.1)
    _, again = _run(s, 1.0)
    _, other = _run(SimulatorSettings.model_validate({**data, "seed": 8}), 1.0)
    first = [m.x_m for r in readings[:100] for m in r.pose]
    assert first == [m.x_m for r in again for m in r.pose]
    assert first != [m.x_m for r in other for m in r.pose]


def test_lidar_scans_at_its_rate() -> None:
    cells = np.full((200, 200), FREE, dtype=np.int8)
    cells[:5] = cells[-5:] = OCCUPIED
    cells[:, :5] = cells[:, -5:] = OCCUPIED
    grid = OccupancyGrid(cells=cells, resolution_m=0.1, origin_xy_m=np.array([-10.0, -10.0]))
    s = SimulatorSettings.model_validate(NOISELESS)
    _, readings = _run(s, 1.0, grid)
    scans = [m for r in readings for m in r.scans]
    assert len(scans) == 20
    sc = scans[0]
    assert sc.ranges_m.dtype == np.float32 and sc.ranges_m.shape == (1080,)
    assert sc.angle_min_rad == pytest.approx(-2.35)
    assert sc.angle_min_rad + 1079 * sc.angle_increment_rad == pytest.approx(2.35)
    assert np.all(sc.ranges_m > 0.0) and np.all(sc.ranges_m < 30.0)
