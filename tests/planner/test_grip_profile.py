"""The line's speed profile re-planned for the grip found (``services.planner.raceline.
grip_profile``) and the raceline planner re-planning once its grip adaptation has settled."""

from __future__ import annotations

import numpy as np
import pytest

from services.planner.raceline.grip_profile import (
    GripReplan,
    grip_raceline,
    grip_speed_profile,
    line_grip_mps2,
)
from services.planner.raceline.planner import (
    FEED_FORWARD_SCALES,
    Raceline,
    RacelinePlanner,
    speed_profile,
)
from services.planner.raceline.tracker import ReferenceLap
from shared.config.planner import PlannerSettings, RacelineSettings
from shared.config.vehicle import F1TENTH_GYM
from tests.planner.test_raceline_margins import _rear_axle_at
from tests.planner.test_tracker import stadium

CAP_MPS = 4.18


def _line(straight: float = 12.0, radius: float = 1.5) -> Raceline:
    """A stadium driven at 9 m/s^2 in its bends and the cap on its straights (widths 1 m)."""
    track = stadium(straight, radius)
    kappa = track.signed_curvature()
    seg = np.hypot(*(np.roll(track.xy, -1, axis=0) - track.xy).T)
    v = speed_profile(kappa, seg, RacelineSettings(a_lat_mps2=9.0, v_max_mps=CAP_MPS,
                                                   a_accel_mps2=6.0, a_brake_mps2=8.0))
    ref = ReferenceLap.from_path(track, kappa, v, F1TENTH_GYM)
    return Raceline(track, np.zeros(len(v)), kappa, v, ref)


def test_the_profile_keeps_the_straights_and_slows_the_bends_within_the_grip() -> None:
    line = _line()
    ref = line.reference
    a_line = line_grip_mps2(ref.v_mps, ref.kappa_1pm)
    assert a_line == pytest.approx(9.0, rel=0.02)
    scale, share = 0.75, 0.7
    slow = grip_raceline(line, scale, F1TENTH_GYM, share)
    v, v_line, k = slow.speed_mps, line.speed_mps, np.abs(ref.kappa_1pm)
    grip = scale**2 * a_line
    assert np.all(v <= v_line + 1e-9)  # never faster than the line
    assert np.all(v**2 * k <= grip * (1 + 1e-9))  # within the grip found
    assert v.max() == pytest.approx(CAP_MPS, rel=1e-6)  # the straights at the cap
    bend = k > 0.9 / 1.5
    assert np.allclose(v[bend], scale * v_line[bend], rtol=0.02)  # the bends at c v
    seg = np.diff(np.append(ref.s_m, ref.length_m))
    dv2 = (np.roll(v, -1) ** 2 - v**2) / (2 * seg)  # along the track, on the ellipse
    room = share * grip * np.sqrt(np.clip(1 - (v**2 * k / grip) ** 2, 0, 1))
    room_next = np.roll(room, -1)
    assert np.all((dv2 <= room + 1e-6) | (dv2 <= 0)) and np.all(-dv2 <= room_next + 1e-6)
    # faster than the whole line at c of its speeds, slower than the line
    assert line.lap_time_s < slow.lap_time_s < line.lap_time_s / scale
    # the plan follows the new profile on the same path
    assert np.array_equal(slow.reference.v_mps, v) and slow.track is line.track
    assert grip_raceline(line, 1.0, F1TENTH_GYM, share) is line


def test_the_profile_rejects_a_bad_grip_and_a_per_node_share_equals_one_number() -> None:
    line = _line()
    ref = line.reference
    with pytest.raises(ValueError):
        grip_speed_profile(ref.v_mps, ref.kappa_1pm, np.ones(len(ref.v_mps)), 0.0, 0.5)
    with pytest.raises(ValueError):
        grip_raceline(line, 1.2, F1TENTH_GYM, 0.5)
    with pytest.raises(ValueError):
        ref.slower(np.full(3, 0.8), F1TENTH_GYM)  # not one per node
    one = ref.slower(0.8, F1TENTH_GYM)
    each = ref.slower(np.full(len(ref.v_mps), 0.8), F1TENTH_GYM)
    assert np.allclose(one.delta_rad, each.delta_rad) and np.allclose(one.v_mps, each.v_mps)


def test_the_re_plan_done_a_slice_per_tick_is_the_re_plan_done_at_once() -> None:
    """``GripReplan``: the same line and the same slower plans as made at once, each tick
    within its work (one slice beyond it only when a single slice is larger)."""
    line = _line(straight=20.0)
    ref = line.reference
    n = len(ref.v_mps)
    shares = FEED_FORWARD_SCALES[:-1]
    at_once = grip_raceline(line, 0.8, F1TENTH_GYM, 0.7)
    work = 500
    job = GripReplan(line, 0.8, F1TENTH_GYM, 0.7, None, shares)
    ticks, before = 0, 0
    while not job.advance(work):
        ticks += 1
        step = job.work_done - before
        before = job.work_done
        assert 0 < step <= work  # every slice (at most PLAN_CHUNK nodes) within it
        assert ticks < 200
    assert job.ticks == ticks + 1 and job.ticks >= job.work_done / work
    assert job.work_done >= 4 * n + 6 * n  # the passes and six plans over the nodes
    done = job.result
    assert done.scale == 0.8 and job.advance(work) and job.result is done
    for name in ("v_mps", "delta_rad", "yaw_rad", "a_mps2", "t_s"):
        assert np.allclose(getattr(done.raceline.reference, name),
                           getattr(at_once.reference, name), rtol=1e-12, atol=1e-12)
    assert np.array_equal(done.raceline.speed_mps, at_once.speed_mps)  # the passes alike
    assert len(done.slow_plans) == len(shares)
    for k, plan in zip(shares, done.slow_plans, strict=True):
        alone = at_once.reference.slower(k, F1TENTH_GYM)
        assert np.allclose(plan.delta_rad, alone.delta_rad, rtol=1e-12, atol=1e-12)
        assert np.array_equal(plan.v_mps, alone.v_mps)
    with pytest.raises(ValueError):
        GripReplan(line, 0.8, F1TENTH_GYM, 0.7, None).advance(0)
    with pytest.raises(ValueError):  # the scale is checked as the job starts
        GripReplan(line, 1.3, F1TENTH_GYM, 0.7, None).advance(work)


def _planner(vehicle=None, **raceline) -> RacelinePlanner:
    options = {"start_speed_scale": 1.0, "grip_error_m": 0.2, "grip_step": 0.05,
               "grip_min_scale": 0.8, "grip_yaw_error_radps": 0.0,
               "servo_lag_estimate": False,
               "grip_replan_work_per_tick": 10**6,  # at once (sliced: its own test below)
               **raceline}
    settings = PlannerSettings(method="raceline", raceline=RacelineSettings(**options))
    line = _line()
    return RacelinePlanner(line.track, settings, raceline=line, vehicle=vehicle)


def test_the_planner_re_plans_its_profile_once_the_scale_has_settled() -> None:
    planner = _planner(grip_profile_settle_ticks=5)
    step = 0.15
    for k in range(10):  # on the line: the plan
        planner.step(*_rear_axle_at(planner, step * k))
    assert planner.raceline is planner.built_line and planner.profile_scale == 1.0
    for k in range(10, 16):  # a slide: cut tick by tick, the line scaled meanwhile
        planner.step(*_rear_axle_at(planner, step * k, 0.3))
        assert planner.raceline is planner.built_line
    assert planner.speed_scale == pytest.approx(0.8)
    for k in range(16, 32):  # back on the line: re-planned after the settle ticks
        planner.step(*_rear_axle_at(planner, step * k))
    assert planner.profile_scale == planner.speed_scale and planner.tracker_scale == 1.0
    assert planner.raceline is not planner.built_line
    assert planner.raceline.speed_mps.max() == pytest.approx(CAP_MPS, rel=1e-6)
    # on the straight the car is asked for the line's speed, not 0.8 of it
    cmd = planner.step(*_rear_axle_at(planner, 6.0)).command
    assert cmd.speed_mps > 0.95 * CAP_MPS
    planner.reset()  # a new run: the line as built, for the told grip
    assert planner.raceline is planner.built_line and planner.profile_scale == 1.0
    assert planner.tracker.plan is planner.built_line.reference


def test_the_planner_drives_the_line_it_has_until_the_re_plan_is_done() -> None:
    """A small work per tick: the re-plan takes several ticks; meanwhile the car drives the
    line as built at the scale found, then the re-planned one with its slower trackers on
    the new plan's slower plans; a reset drops a re-plan under way."""
    planner = _planner(grip_profile_settle_ticks=2, grip_replan_work_per_tick=300)
    n = len(planner.built_line.speed_mps)
    _slide_then_line(planner, 18)  # settled at 17: the job started
    job = planner._grip_job
    assert planner.replanning and planner.raceline is planner.built_line
    k = 18
    while planner.replanning:
        work = planner.replan_work_done
        planner.step(*_rear_axle_at(planner, 0.15 * k))
        k += 1
        assert k < 200
        assert 0 < planner.replan_work_done - work <= 300  # each tick within its work
        if planner.replanning:  # under way: the line as built, scaled
            assert planner.raceline is planner.built_line and planner.tracker_scale < 1.0
    assert job.ticks > 10 * n / 300  # the passes and six plans over the nodes
    assert planner.raceline is job.result.raceline and planner.profile_scale == 0.8
    assert [t.plan for t in planner._slow_trackers] == list(job.result.slow_plans)
    # a slide again, a re-plan started, then a reset: the line as built, nothing under way
    for j in range(k, k + 6):
        planner.step(*_rear_axle_at(planner, 0.15 * j, 0.3))
    for j in range(k + 6, k + 9):
        planner.step(*_rear_axle_at(planner, 0.15 * j))
    planner.reset()
    assert not planner.replanning and planner.raceline is planner.built_line
    assert [t.plan for t in planner._slow_trackers] == list(planner._built_slow_plans)


def _slide_then_line(planner: RacelinePlanner, ticks: int) -> None:
    """10 ticks on the line, 6 ticks 0.3 m off it (a slide), then on it up to `ticks`, every
    0.15 m."""
    for k in range(ticks):
        planner.step(*_rear_axle_at(planner, 0.15 * k, 0.3 if 10 <= k < 16 else 0.0))


def test_without_the_grip_profile_the_whole_line_is_scaled() -> None:
    """Off, the cuts scale the line as built."""
    planner = _planner(grip_profile=False, grip_profile_settle_ticks=1)
    _slide_then_line(planner, 40)
    assert planner.raceline is planner.built_line and planner.speed_scale == pytest.approx(0.8)
    cmd = planner.step(*_rear_axle_at(planner, 6.0)).command
    assert cmd.speed_mps < 0.85 * CAP_MPS


def test_linear_tyres_are_neither_cut_nor_re_planned() -> None:
    """The gym's unbounded linear tyres have no grip to find: the same slide cuts nothing,
    and the line stays as built at its own speeds."""
    linear = F1TENTH_GYM.model_copy(update={"tyre_model": "linear"})
    planner = _planner(vehicle=linear, grip_profile_settle_ticks=1)
    _slide_then_line(planner, 40)
    assert planner.raceline is planner.built_line and planner.speed_scale == 1.0
    assert planner.replan_work_done == 0


def test_no_profile_is_re_planned_before_the_servo_s_lag_is_measured() -> None:
    """The estimator on and no estimate yet (synthetic poses on the line): the cuts scale
    the line as built."""
    planner = _planner(servo_lag_estimate=True, grip_profile_settle_ticks=1)
    _slide_then_line(planner, 30)
    assert planner.servo_lag.estimate() is None and planner.speed_scale == pytest.approx(0.8)
    assert planner.raceline is planner.built_line and planner.profile_scale == 1.0


def test_cuts_before_the_servo_was_measured_are_learnt_afresh_once_settled() -> None:
    """``grip_relearn_on_servo``: the scale cut to its floor while the tracker believed the
    told servo; the lag measured (a slow servo) and the scale settled, it returns to the
    cautious start's scale on the line as built, then the profile is re-planned there."""
    from services.planner.raceline.servo_lag import ServoLagEstimate

    planner = _planner(servo_lag_estimate=True, grip_profile_settle_ticks=3,
                       start_speed_scale=0.9, grip_min_scale=0.7, grip_relearn_on_servo=True)
    planner.speed_scale = 1.0  # (the cautious start is off in these tests: asked at 1)
    for k in range(10):
        planner.step(*_rear_axle_at(planner, 0.15 * k))
    for k in range(10, 20):  # a slide with the told servo: down to the floor
        planner.step(*_rear_axle_at(planner, 0.15 * k, 0.3))
    assert planner.speed_scale == pytest.approx(0.7)
    slow = ServoLagEstimate(0.2, 1.0, 10.0, 3.0, (0.0,))
    planner.servo_lag.estimate = lambda: slow  # the lag measured from here on
    for k in range(20, 40):
        planner.step(*_rear_axle_at(planner, 0.15 * k))
    assert planner.tracker.timing.servo_time_constant_s > 0.1  # inverted
    assert planner.speed_scale == pytest.approx(0.9)  # learnt afresh from the start's
    assert planner.profile_scale == pytest.approx(0.9)  # ... and re-planned there
    planner.reset()
    assert planner.raceline is planner.built_line and not planner._relearn


def test_the_cautious_start_rises_no_further_than_the_grip_shown_allows() -> None:
    """``start_probe_share``: past the hold, the scale rises only to 1.2 times the scale
    whose lateral acceleration the car has held on its line: on the straight (no grip
    shown) it stays at the start's, in the bend it steps up to 1.2 x 0.8, then on."""
    planner = _planner(start_speed_scale=0.8, start_hold_share=0.05, start_rise_per_tick=0.5,
                       start_probe_share=0.2)
    assert planner._start_phase == "hold" and planner.speed_scale == 0.8
    s = 0.0
    while s < 11.0:  # the first straight
        planner.step(*_rear_axle_at(planner, s))
        s += 0.15
    assert planner._start_phase == "rise" and planner.speed_scale == 0.8
    scales = []
    while s < 14.0:  # into the first bend (radius 1.5 m, at the line's grip)
        planner.step(*_rear_axle_at(planner, s))
        scales.append(planner.speed_scale)
        s += 0.15
    rising = [c for c in scales if c > 0.8]
    assert rising[0] == pytest.approx(0.96, abs=0.01)  # 1.2 x the 0.8 held
    assert rising[-1] == 1.0 and planner._start_phase is None
