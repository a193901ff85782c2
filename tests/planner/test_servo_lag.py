"""The servo's lag measured from the yaw response (``services.planner.raceline.servo_lag``)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from services.planner.raceline.servo_lag import (
    ServoLagEstimator,
    ServoLagSettings,
    yaw_lag_s,
    yaw_lag_table,
)
from shared.config.vehicle import F1TENTH_GYM, REAL_CAR_IDENTIFIED

PERIOD_S = 0.05
DELAY_S = 0.032
WHEELBASE_M = 0.33


def _drive(est: ServoLagEstimator, tau_s: float, seconds: float = 30.0, speed: float = 3.0,
           delay_s: float = DELAY_S, seed: int = 0, gain: float = 1.0,
           yaw_noise_rad: float = 0.0) -> None:
    """A kinematic car (rear-axle pose) at `speed` [m/s] whose wheels follow the commands
    through `delay_s` and a first-order lag `tau_s`, simulated at 1 ms; the commands a
    random walk of steps and a sweep at 20 Hz, given to the estimator as the planner does."""
    rng = np.random.default_rng(seed)
    dt = 0.001
    sub = round(PERIOD_S / dt)
    x = y = yaw = 0.0
    wheels = 0.0
    pending: list[tuple[float, float]] = []  # (time it reaches the servo, target)
    target = 0.0
    t = 0.0
    cmd = 0.0
    for k in range(round(seconds / PERIOD_S)):
        noisy = yaw + (rng.normal(0.0, yaw_noise_rad) if yaw_noise_rad else 0.0)
        est.observe(x, y, noisy)
        cmd = float(np.clip(0.6 * cmd + 0.15 * rng.normal() + 0.12 * math.sin(0.9 * k * PERIOD_S),
                            -0.35, 0.35))
        est.commanded(cmd)
        pending.append((t + delay_s, cmd))
        for _ in range(sub):
            while pending and pending[0][0] <= t + 1e-12:
                target = pending.pop(0)[1]
            wheels += (target - wheels) * (1.0 - math.exp(-dt / tau_s)) if tau_s > 0 else (
                target - wheels)
            r = gain * speed * math.tan(wheels) / WHEELBASE_M
            x += speed * math.cos(yaw) * dt
            y += speed * math.sin(yaw) * dt
            yaw += r * dt
            t += dt


def _estimator(**kw) -> ServoLagEstimator:
    return ServoLagEstimator(ServoLagSettings(PERIOD_S, DELAY_S, WHEELBASE_M, **kw))


@pytest.mark.parametrize("tau_s", [0.01, 0.08, 0.158, 0.25])
def test_the_lag_of_a_kinematic_car_is_measured_within_a_hundredth_of_a_second(tau_s) -> None:
    est = _estimator()
    _drive(est, tau_s, gain=0.85)  # understeer: the gain is fitted, not assumed
    out = est.estimate()
    assert out is not None
    assert out.tau_s == pytest.approx(tau_s, abs=0.01)
    assert out.gain == pytest.approx(0.85, abs=0.03)
    assert out.speed_mps == pytest.approx(3.0, abs=0.05)
    assert est.samples > 500


def test_a_noisy_pose_still_tells_a_slow_servo_from_a_fast_one() -> None:
    slow, fast = _estimator(), _estimator()
    _drive(slow, 0.158, yaw_noise_rad=0.003, seed=1)
    _drive(fast, 0.01, yaw_noise_rad=0.003, seed=1)
    assert slow.estimate().tau_s == pytest.approx(0.158, abs=0.03)
    assert fast.estimate().tau_s < 0.04


def test_no_estimate_without_enough_steering_or_speed() -> None:
    est = _estimator()
    assert est.estimate() is None
    for k in range(200):  # straight ahead, no steering: nothing to tell the lag from
        est.observe(0.15 * k, 0.0, 0.0)
        est.commanded(0.0)
    assert est.estimate() is None
    slow = _estimator()
    _drive(slow, 0.1, speed=0.5)  # below min_speed_mps: every sample left out
    assert slow.estimate() is None and slow.samples == 0 and slow.dropped > 0


def test_bad_poses_are_dropped_and_a_jump_starts_afresh() -> None:
    est = _estimator()
    _drive(est, 0.1, seconds=10.0)
    n = est.samples
    est.observe(math.nan, 0.0, 0.0)
    est.commanded(math.inf)
    assert est.samples == n  # ignored, nothing raised
    est.observe(1e3, 1e3, 0.0)  # a teleport: the history no longer belongs to this pose
    assert est.samples == 0 and est.estimate() is None


def test_the_settings_reject_a_bad_grid() -> None:
    with pytest.raises(ValueError):
        ServoLagSettings(PERIOD_S, DELAY_S, WHEELBASE_M, taus_s=(0.01, 0.02, 0.03))
    with pytest.raises(ValueError):
        ServoLagSettings(0.0, DELAY_S, WHEELBASE_M)


def test_the_car_s_own_yaw_lag_is_a_few_hundredths_of_a_second() -> None:
    for car in (F1TENTH_GYM, REAL_CAR_IDENTIFIED):
        lags = [yaw_lag_s(car, v) for v in (1.5, 3.5, 7.0)]
        assert all(0.005 < lag < 0.05 for lag in lags)
        speeds, table = yaw_lag_table(car)  # what the planner reads each tick
        assert np.interp(3.3, speeds, table) == pytest.approx(yaw_lag_s(car, 3.3), abs=1e-3)


@pytest.mark.slow
def test_the_planner_measures_a_slower_servo_than_told_and_inverts_it() -> None:
    """The default car's raceline planner races the identified car (0.158 s servo): it
    measures the lag while racing and its tracker inverts it; racing its own car, it keeps
    the timing it was told. A reset forgets the measurement."""
    from services.planner.mintime.store import ensure_artefacts
    from services.planner.raceline.planner import RacelinePlanner
    from services.tools.bench import LoopOptions, run_method
    from shared.config.methods import RACELINE
    from shared.config.planner import PlannerSettings
    from shared.config.simulator import SimulatorSettings
    from shared.config.vehicle import vehicle_preset
    from shared.track import load_track

    track = load_track("builtin:paperlike")
    settings = PlannerSettings()
    ensure_artefacts(RACELINE, track, settings)
    planner = RacelinePlanner(track, settings)
    told = planner.tracker.timing
    assert told.servo_time_constant_s == 0.0
    identified = SimulatorSettings(vehicle=vehicle_preset("real_car_identified"))
    run = run_method(RACELINE, planner, track, identified, LoopOptions(laps=1))
    assert run.completed_laps == 1
    assert 0.12 < planner.servo_lag_s < 0.25  # 0.158 s and the estimator's few hundredths
    assert planner.tracker.timing.servo_time_constant_s == planner.servo_lag_s
    planner.reset()
    assert planner.tracker.timing == told and planner.servo_lag.samples == 0
    run = run_method(RACELINE, planner, track, SimulatorSettings(), LoopOptions(laps=1))
    assert run.completed_laps == 1 and run.run_off_track_events == 0
    assert planner.tracker.timing == told  # its own car: nothing to change
    assert planner.servo_lag_s == pytest.approx(F1TENTH_GYM.steering_time_constant_s)
