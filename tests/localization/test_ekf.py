"""The fused estimator (EKF over a measurement history): latency compensation, the gate and
its re-opening, stamp checks, drop-out, past poses. Plain loops, no Zenoh, seeded."""

from __future__ import annotations

import math

import numpy as np
import pytest

from services.localization_bridge import FusedEstimator, Verdict
from services.simulator import Command, Pose2D, SensorSuite, Simulator, rear_axle
from shared.config.localization import LocalizationSettings
from shared.config.simulator import PoseSensorSettings, SimulatorSettings

YEAR_S = 365.25 * 86400.0


def slalom_errors(compensate: bool, seconds: float = 6.0, seed: int = 3) -> tuple[float, float]:
    """RMS position error [m] of the fused state and of the newest raw pose, against the
    truth at 100 Hz, on a seeded slalom with 2 cm / 2 degree poses at 30 Hz, 30 ms late."""
    pose = PoseSensorSettings(
        rate_hz=30.0, latency_s=0.03, position_noise_std_m=0.02,
        yaw_noise_std_rad=math.radians(2.0),
    )
    s = SimulatorSettings(pose=pose, seed=seed)
    sim = Simulator(s)
    sim.reset(Pose2D(0.0, 0.0, 0.0), speed_mps=0.0)
    sensors = SensorSuite(s, None)
    est = FusedEstimator(LocalizationSettings(latency_compensation=compensate))
    fused, raw, last = [], [], None
    while sim.t_s < seconds:
        t = sim.t_s
        out = sim.step(Command(3.0 + math.sin(0.5 * t), 0.25 * math.sin(0.8 * t)), 0.01)
        now = out.t_s
        got = sensors.update(out)
        for m in got.imu:
            est.imu(m.stamp_s, m.yaw_rate_radps, now)
        for o in got.odometry:
            est.odom(o.stamp_s, o.speed_mps, o.steering_rad, None, now)
        for p in got.pose:
            est.pose(p.stamp_s, p.x_m, p.y_m, p.yaw_rad, None, now)
            last = p
        if now > 1.0 and last is not None:
            st = out.state
            x, y, _ = rear_axle(st.x_m, st.y_m, st.yaw_rad, s.vehicle.lr_m)
            e = est.estimate(now)
            fused.append(math.hypot(e.x_m - x, e.y_m - y))
            raw.append(math.hypot(last.x_m - x, last.y_m - y))
    return float(np.sqrt(np.mean(np.square(fused)))), float(np.sqrt(np.mean(np.square(raw))))


def test_fused_error_below_the_pose_noise_and_lower_with_latency_compensation() -> None:
    with_comp, raw = slalom_errors(True)
    without, _ = slalom_errors(False)
    assert with_comp < 0.02 * math.sqrt(2.0)  # the poses' own 2-D noise: 2.8 cm RMS
    assert with_comp < without < raw


def moving(est: FusedEstimator, t0: float, t1: float, v: float = 2.0, dt: float = 0.01,
           pose_every: int = 3, pose_lag_s: float = 0.02, poses: bool = True) -> float:
    """Drive `est` along +x at `v` from `t0` to `t1`: odometry and gyro every `dt`, a pose
    every `pose_every` steps, each arriving `pose_lag_s` after its capture; returns t1."""
    n = round((t1 - t0) / dt)
    for k in range(1, n + 1):
        now = t0 + k * dt
        est.odom(now, v, 0.0, None, now)
        est.imu(now, 0.0, now)
        if poses and k % pose_every == 0:
            tc = now - pose_lag_s
            est.pose(tc, v * tc, 0.0, 0.0, None, now)
    return t0 + n * dt


def started(**kw) -> FusedEstimator:
    est = FusedEstimator(LocalizationSettings(**kw))
    assert est.pose(0.0, 0.0, 0.0, 0.0, None, 0.0) is Verdict.INITIALISED
    moving(est, 0.0, 1.0)
    return est


def test_outlier_is_gated_counted_and_not_applied() -> None:
    est = started()
    before = est.estimate(1.0)
    assert est.pose(0.99, 2.0, 5.0, 0.0, None, 1.0) is Verdict.GATED
    after = est.estimate(1.0)
    assert est.counts["pose_gated"] == 1
    assert abs(after.y_m - before.y_m) < 1e-9 and abs(after.x_m - before.x_m) < 1e-9


def test_consistent_gated_poses_reinitialise_the_filter() -> None:
    est = started(reinit_after_gated=5)
    verdicts = [est.pose(1.0 + 0.02 * k, 2.0, 5.0, 0.0, None, 1.0 + 0.02 * k) for k in range(5)]
    assert verdicts[:4] == [Verdict.GATED] * 4 and verdicts[4] is Verdict.REINIT
    assert abs(est.estimate(1.08).y_m - 5.0) < 0.05
    # scattered outliers never re-open the gate
    est = started(reinit_after_gated=5)
    for k in range(20):
        assert est.pose(1.0, 2.0, 5.0 * (-1) ** k, 0.0, None, 1.0) is Verdict.GATED


@pytest.mark.parametrize("ahead_s", [3600.0, 300 * YEAR_S])
def test_future_stamped_poses_are_rejected_and_counted(ahead_s: float) -> None:
    est = started()
    stamp = min(1.0 + ahead_s, 9.9e9)
    assert est.pose(stamp, 2.0, 0.0, 0.0, None, 1.0) is Verdict.FUTURE
    assert est.counts["pose_future"] == 1
    assert est.estimate(1.0).pose_stamp_s < 1.0  # not taken as fresh
    assert est.imu(stamp, 0.0, 1.0) is Verdict.FUTURE and est.counts["imu_future"] == 1


def test_stale_poses_older_than_the_history_are_rejected_and_counted() -> None:
    est = started(history_s=0.5)
    assert est.pose(0.3, 0.6, 0.0, 0.0, None, 1.0) is Verdict.STALE
    assert est.odom(0.1, 9.0, 0.0, None, 1.0) is Verdict.STALE
    assert est.counts["pose_stale"] == 1 and est.counts["odom_stale"] == 1
    # within the history, an old pose is applied at its own stamp
    assert est.pose(0.8, 1.6, 0.0, 0.0, None, 1.0) is Verdict.APPLIED


def test_pose_dropout_degrades_then_invalidates_and_recovers() -> None:
    est = started(degraded_after_s=0.1, invalid_after_s=0.25)
    t = 1.0
    assert est.estimate(t).valid and not est.estimate(t).degraded
    quality = []
    t_end = moving(est, t, t + 0.3, poses=False)  # 300 ms without poses, IMU and odometry go on
    for k in range(1, 31):
        e = est.estimate(t + 0.01 * k)
        quality.append("invalid" if not e.valid else "degraded" if e.degraded else "ok")
    assert quality[0] == "ok" and "degraded" in quality and quality[-1] == "invalid"
    first_bad = quality.index("degraded")
    assert quality.index("invalid") > first_bad  # degraded first, then invalid
    assert est.pose(t_end - 0.02, 2.0 * (t_end - 0.02), 0.0, 0.0, None, t_end) is Verdict.REINIT
    moving(est, t_end, t_end + 0.2)
    e = est.estimate(t_end + 0.2)
    assert e.valid and not e.degraded and abs(e.x_m - 2.0 * (t_end + 0.2)) < 0.05


def test_past_poses_mixed_with_real_ones_do_not_make_the_state_jump_back() -> None:
    est = started()
    t, xs, valid = 1.0, [], []
    for k in range(1, 101):
        now = t + 0.01 * k
        est.odom(now, 2.0, 0.0, None, now)
        est.imu(now, 0.0, now)
        if k % 3 == 0:
            tc = now - 0.02
            est.pose(tc, 2.0 * tc, 0.0, 0.0, None, now)
        if k % 3 == 1:  # a replay of where the car was 0.4 s ago, and 2 s ago
            est.pose(now - 0.4, 2.0 * (now - 0.4), 0.0, 0.0, None, now)
            est.pose(now - 2.0, 2.0 * (now - 2.0), 0.0, 0.0, None, now)
        e = est.estimate(now)
        xs.append(e.x_m)
        valid.append(e.valid)
    assert all(valid)
    assert np.all(np.diff(xs) > 0.0)  # always forwards
    assert abs(xs[-1] - 2.0 * 2.0) < 0.03
    assert est.counts["pose_stale"] >= 30


def test_without_poses_the_estimate_is_invalid_and_inputs_wait() -> None:
    est = FusedEstimator(LocalizationSettings())
    assert est.odom(0.0, 1.0, 0.1, None, 0.0) is Verdict.WAITING
    e = est.estimate(0.0)
    assert not e.valid and e.pose_stamp_s is None
    assert est.pose(0.0, 1.0, 2.0, 0.5, None, 0.0) is Verdict.INITIALISED
    assert est.estimate(0.0).speed_mps == pytest.approx(1.0)


def test_a_pose_covariance_is_used_and_a_broken_one_does_not_break_the_filter() -> None:
    est = started()
    bad = np.array([[1e-12, 1.0, 0.0], [1.0, 1e-12, 0.0], [0.0, 0.0, 1e-12]])
    est.pose(0.995, 1.99, 0.0, 0.0, bad, 1.0)
    e = est.estimate(1.0)
    assert np.all(np.isfinite(e.cov)) and e.valid


# --- a teleport (issue 25): re-initialised at once, the gate does not hold the old position
def test_a_teleport_reinitialises_at_once_where_the_gate_would_hold_the_old_position() -> None:
    est = started()  # 1 s along +x at 2 m/s: at x = 2 m
    assert est.pose(0.99, 2.0, 5.0, 0.0, None, 1.0) is Verdict.GATED  # the jump alone: gated
    assert est.teleport(1.0, -3.0, 4.0, 1.5, 0.0, 1.0) is Verdict.TELEPORT
    e = est.estimate(1.01)  # the next output
    assert math.hypot(e.x_m + 3.0, e.y_m - 4.0) < 1e-3 and abs(e.yaw_rad - 1.5) < 1e-6
    assert e.speed_mps == 0.0 and e.valid and e.pose_stamp_s == 1.0
    assert est.counts["teleport_applied"] == 1
    # what was measured before the teleport (arriving late) is the car before it: dropped
    assert est.pose(0.995, 2.0, 0.0, 0.0, None, 1.01) is Verdict.STALE
    assert est.pose(1.0, 2.0, 0.0, 0.0, None, 1.01) is Verdict.STALE  # the same instant
    assert est.odom(0.999, 2.0, 0.0, None, 1.01) is Verdict.STALE
    assert est.imu(0.998, 0.0, 1.01) is Verdict.STALE
    assert est.counts["pose_before_teleport"] == 2 and est.counts["odom_before_teleport"] == 1
    assert est.counts["imu_before_teleport"] == 1
    # the poses after it are applied (not gated) and the car stays where it was put
    for k in range(1, 21):
        now = 1.0 + 0.01 * k
        est.odom(now, 0.0, 0.0, None, now)
        est.imu(now, 0.0, now)
        if k % 3 == 0:
            assert est.pose(now - 0.02, -3.0, 4.0, 1.5, None, now) is Verdict.APPLIED
    e = est.estimate(1.2)
    assert math.hypot(e.x_m + 3.0, e.y_m - 4.0) < 0.01 and abs(e.speed_mps) < 0.05
    assert est.counts["pose_gated"] == 1


def test_a_teleport_keeps_the_later_readings_and_the_gyro_bias() -> None:
    est = started()
    bias = est.estimate(1.0).bias_radps
    est.odom(1.005, 1.0, 0.0, None, 1.006)  # after the teleport's stamp, arrived before it
    assert est.teleport(1.0, 0.0, 0.0, 0.0, 0.0, 1.01) is Verdict.TELEPORT
    e = est.estimate(1.01)
    assert 0.0 < e.speed_mps <= 1.0  # the later wheel speed re-applied on the new start
    assert e.bias_radps == bias


def test_a_teleport_with_a_speed_starts_moving() -> None:
    est = started()
    est.teleport(1.0, 0.0, 0.0, 0.0, 2.5, 1.0)
    e = est.estimate(1.05)
    assert e.speed_mps == 2.5 and e.x_m == pytest.approx(0.125, abs=1e-6)


def test_teleports_are_checked_like_every_input() -> None:
    est = started()
    assert est.teleport(1.0 + 3600.0, 0.0, 0.0, 0.0, 0.0, 1.0) is Verdict.FUTURE
    assert est.teleport(0.2, 0.0, 0.0, 0.0, 0.0, 1.0) is Verdict.STALE  # older than the history
    assert est.teleport(1.0, math.nan, 0.0, 0.0, 0.0, 1.0) is Verdict.STALE
    assert est.counts["teleport_future"] == 1 and est.counts["teleport_stale"] == 1
    assert est.counts["teleport_not_finite"] == 1
    assert est.teleport(1.0, 0.0, 0.0, 0.0, 0.0, 1.0) is Verdict.TELEPORT
    assert est.teleport(1.0, 5.0, 0.0, 0.0, 0.0, 1.0) is Verdict.STALE  # the same one again
    assert est.teleport(1.01, 5.0, 0.0, 0.0, 0.0, 1.01) is Verdict.TELEPORT  # a newer one


def test_a_teleport_starts_a_filter_that_had_no_pose_yet() -> None:
    est = FusedEstimator(LocalizationSettings())
    est.odom(0.0, 0.0, 0.0, None, 0.0)
    assert est.teleport(0.0, 1.0, 2.0, 0.3, 0.0, 0.0) is Verdict.TELEPORT
    assert est.initialised and est.estimate(0.01).valid
    moving(est, 0.0, 0.3, v=0.0, poses=False)
    e = est.estimate(0.3)
    assert e.x_m == pytest.approx(1.0, abs=1e-6) and e.y_m == pytest.approx(2.0, abs=1e-6)


def test_without_latency_compensation_readings_are_still_judged_by_their_own_stamps() -> None:
    est = started(latency_compensation=False)
    assert est.teleport(1.0, -3.0, 4.0, 0.0, 0.0, 1.02) is Verdict.TELEPORT
    assert est.pose(0.99, 2.0, 0.0, 0.0, None, 1.03) is Verdict.STALE
    assert est.pose(1.025, -3.0, 4.0, 0.0, None, 1.03) is Verdict.APPLIED


def test_the_prediction_is_the_module_docstrings_model_bit_for_bit() -> None:
    """``predict`` (written for speed) against the model as the docstring writes it: the
    Jacobian F, Q from ``outer(h, h)`` along the heading, ``P = F P F^T + Q``."""
    from services.localization_bridge.ekf import Belief, Ekf, predict
    from shared.angles import wrap_angle
    from shared.config.localization import EkfNoise

    noise = EkfNoise()
    rng = np.random.default_rng(4)
    for _ in range(300):
        m = rng.normal(size=(7, 7))
        b = Belief(0.0, rng.normal(size=7) * [10, 10, 3, 4, 2, 0.1, 0.5], m @ m.T)
        dt = float(rng.uniform(1e-4, 0.2))
        x, y, yaw, v, r, bias, vy = b.s
        yaw_m = yaw + 0.5 * r * dt
        c, s_ = math.cos(yaw_m), math.sin(yaw_m)
        dx, dy = (v * c - vy * s_) * dt, (v * s_ + vy * c) * dt
        F = np.eye(7)
        F[Ekf.X, [Ekf.YAW, Ekf.V, Ekf.VY, Ekf.R]] = [-dy, c * dt, -s_ * dt, -0.5 * dy * dt]
        F[Ekf.Y, [Ekf.YAW, Ekf.V, Ekf.VY, Ekf.R]] = [dx, s_ * dt, c * dt, 0.5 * dx * dt]
        F[Ekf.YAW, Ekf.R] = dt
        qa, qr = noise.accel_psd, noise.yaw_accel_psd
        h = np.array([c, s_])
        Q = np.zeros((7, 7))
        Q[:2, :2] = np.outer(h, h) * (qa * dt**3 / 3.0) + np.eye(2) * (noise.position_psd * dt)
        Q[:2, Ekf.V] = Q[Ekf.V, :2] = h * (qa * dt * dt / 2.0)
        Q[Ekf.V, Ekf.V] = qa * dt
        Q[Ekf.YAW, Ekf.YAW] = qr * dt**3 / 3.0 + noise.yaw_psd * dt
        Q[Ekf.YAW, Ekf.R] = Q[Ekf.R, Ekf.YAW] = qr * dt * dt / 2.0
        Q[Ekf.R, Ekf.R] = qr * dt
        Q[Ekf.BIAS, Ekf.BIAS] = noise.bias_psd * dt
        Q[Ekf.VY, Ekf.VY] = noise.lateral_accel_psd * dt
        P = F @ b.P @ F.T + Q
        got = predict(b, dt, noise)
        want_s = [x + dx, y + dy, wrap_angle(yaw + r * dt), v, r, bias, vy]
        assert np.array_equal(got.s, want_s) and np.array_equal(got.P, 0.5 * (P + P.T))


def test_the_updates_are_the_joseph_form_reference_bit_for_bit() -> None:
    """The fast corrections (speed, wheel yaw rate, gyro, pose) against ``_update``, the
    Joseph form with the full ``H``: the same numbers, bit for bit, on random beliefs."""
    from services.localization_bridge import ekf

    rng = np.random.default_rng(11)
    for _ in range(300):
        m = rng.normal(size=(7, 7)) * rng.uniform(1e-3, 3.0)
        b = ekf.Belief(0.0, rng.normal(size=7) * [10, 10, 3, 4, 2, 0.1, 0.5], m @ m.T)
        z, std = float(rng.normal() * 3), float(rng.uniform(1e-3, 1.0))
        R1 = np.array([[std**2]])
        cases = [
            (ekf.update_speed(b, z, std), ekf._H_SPEED, z - b.s[ekf.Ekf.V]),
            (ekf.update_yaw_rate(b, z, std), ekf._H_YAW_RATE, z - b.s[ekf.Ekf.R]),
            (ekf.update_gyro(b, z, std), ekf._H_GYRO,
             z - b.s[ekf.Ekf.R] - b.s[ekf.Ekf.BIAS]),
        ]
        for got, H, nu in cases:
            want = ekf._update(b, H, np.array([nu]), R1)
            assert np.array_equal(got.s, want.s) and np.array_equal(got.P, want.P)
        pose = b.s[:3] + rng.normal(size=3) * 0.1
        a = rng.normal(size=(3, 3)) * 0.05
        R3 = a @ a.T + np.eye(3) * 1e-4
        got = ekf.update_pose(b, pose, R3)
        nu, _ = ekf.pose_innovation(b, pose, R3)
        want = ekf._update(b, ekf._H_POSE, nu, R3)
        assert np.array_equal(got.s, want.s) and np.array_equal(got.P, want.P)
