"""The tracker (``services.planner.raceline.tracker``): its law on the plan, and the simulated
car on a straight, on a circle at the grip limit and through the proportional speed loop, at the
raceline planner's 20 Hz with the bench's 2 ms compute delay."""

from __future__ import annotations

import math

import numpy as np
import pytest

from services.planner.raceline.planner import planner_timing, tracker_gains
from services.planner.raceline.tracker import ReferenceLap, Tracker, TrackerGains, TrackerTiming
from services.simulator import Command, Simulator
from shared.config.planner import PlannerSettings
from shared.config.simulator import SimulatorSettings
from shared.config.vehicle import F1TENTH_GYM, GRAVITY_MPS2
from shared.track import Track

CAR = F1TENTH_GYM
SETTINGS = PlannerSettings()
#: The bench's compute delay [s] (``services.tools.bench.closed_loop``).
COMPUTE_DELAY_S = 0.002


def circle(radius: float, spacing: float = 0.05) -> Track:
    """A counter-clockwise circle (left turn), 1 m each side."""
    n = round(2 * math.pi * radius / spacing)
    t = np.arange(n) * 2 * math.pi / n
    xy = radius * np.column_stack([np.cos(t), np.sin(t)])
    return Track("circle", xy, np.ones(n), np.ones(n))


def stadium(straight: float, radius: float, spacing: float = 0.05) -> Track:
    """Two straights of `straight` [m] along x (the first from (0, 0) towards +x) joined by
    left semicircles of `radius` [m]."""
    pts = []
    n_s = round(straight / spacing)
    n_c = round(math.pi * radius / spacing)
    for i in range(n_s):
        pts.append((i * straight / n_s, 0.0))
    for i in range(n_c):
        a = -math.pi / 2 + i * math.pi / n_c
        pts.append((straight + radius * math.cos(a), radius + radius * math.sin(a)))
    for i in range(n_s):
        pts.append((straight - i * straight / n_s, 2 * radius))
    for i in range(n_c):
        a = math.pi / 2 + i * math.pi / n_c
        pts.append((radius * math.cos(a), radius + radius * math.sin(a)))
    xy = np.array(pts)
    return Track("stadium", xy, np.ones(len(xy)), np.ones(len(xy)))


def make_tracker(plan: ReferenceLap) -> Tracker:
    """The raceline planner's tracker (default settings) on `plan`."""
    return Tracker.for_vehicle(
        plan, planner_timing(SETTINGS), tracker_gains(SETTINGS.raceline), CAR
    )


def drive(
    tracker: Tracker, pose: tuple[float, float, float], speed: float, seconds: float
) -> dict[str, np.ndarray]:
    """The simulated car (default settings) driven by `tracker` every 50 ms, each command
    acting 2 ms after the pose it comes from; per tick: time, projection, speeds."""
    period = tracker.timing.period_s
    sim = Simulator(SimulatorSettings())
    plan = tracker.plan
    s0, _ = tracker.project(pose[0], pose[1])
    sim.reset(pose, speed_mps=speed, steering_rad=plan.at("delta", s0))
    tracker.reset(s0)
    prev = Command(speed, plan.at("delta", s0))
    rows = []
    while sim.t_s < seconds:
        st = sim.state
        c = tracker.command(st.x_m, st.y_m, st.yaw_rad)
        rows.append((sim.t_s, c.s_m, c.e_m, st.v_mps, plan.at("v", c.s_m), c.steering_rad))
        cmd = Command(c.speed_mps, min(max(c.steering_rad, -0.35), 0.35))
        sim.step(prev, COMPUTE_DELAY_S)
        sim.step(cmd, period - COMPUTE_DELAY_S)
        prev = cmd
    arr = np.array(rows)
    return {k: arr[:, i] for i, k in enumerate(("t", "s", "e", "v", "v_plan", "steer"))}


# --------------------------------------------------------------------------- the law
def test_on_the_plan_the_command_is_the_feed_forward() -> None:
    """Exactly on a steady circle: steering = the single-track model's, speed = the plan's
    plus the drive against the cornering drag; off the line, the feedback's share."""
    tr = circle(2.0)
    v = 3.0
    plan = ReferenceLap.from_path(tr, np.full(tr.n_points, 0.5), np.full(tr.n_points, v), CAR)
    a_y = v**2 * 0.5
    mu_g = CAR.mu * GRAVITY_MPS2
    c_f, c_r = CAR.cornering_stiffness_front_per_rad, CAR.cornering_stiffness_rear_per_rad
    # kinematic + understeer gradient (equal loads); the drive's load transfer adds a little
    k_us = (1 / c_f - 1 / c_r) / mu_g
    delta = float(plan.delta_rad[0])
    assert delta == pytest.approx(math.atan(CAR.wheelbase_m * 0.5) + k_us * a_y, abs=5e-3)
    drive_ = float(plan.a_mps2[0])  # the drag of the steered front tyre and of the slip
    assert 0.3 < drive_ < 0.8
    tracker = make_tracker(plan)
    s = 1.0
    x, y = tr.point_at(s)
    c = tracker.command(float(x), float(y), plan.at("yaw", s))
    assert c.e_m == pytest.approx(0.0, abs=1e-3)
    assert c.steering_rad == pytest.approx(delta, abs=2e-3)
    assert c.speed_mps == pytest.approx(v + drive_ / CAR.speed_gain_accel_per_s, abs=1e-9)
    # 5 cm right of the line (outside the bend): steer further left, ask for less speed
    h = float(tr.heading_at(s))
    xr, yr = float(x) + 0.05 * math.sin(h), float(y) - 0.05 * math.cos(h)
    out = tracker.command(xr, yr, plan.at("yaw", s), s_hint_m=s)
    assert out.e_m == pytest.approx(0.05, abs=1e-3) and out.yaw_error_rad == pytest.approx(0.0)
    k_e, k_out = SETTINGS.raceline.k_lateral_radpm, SETTINGS.raceline.k_outward_per_s2
    assert out.steering_rad == pytest.approx(c.steering_rad + k_e * 0.05, abs=2e-3)
    cut = k_out * 0.05 * math.tanh(0.5 / 0.1)
    assert out.accel_mps2 == pytest.approx(drive_ - cut, rel=1e-3)
    assert out.speed_mps == pytest.approx(v + (drive_ - cut) / CAR.speed_gain_brake_per_s, abs=1e-3)


def test_the_speed_command_asks_the_loop_for_the_planned_acceleration() -> None:
    """``v_cmd = <v_p> + a_p / k``: with a planned 3 m/s^2 the command leads the plan by
    3 / 4.755 m/s, braking at 6 m/s^2 by -6 / 19.02 m/s (the car's two loop gains)."""
    tr = stadium(20.0, 2.0)
    n = tr.n_points
    s = tr.s_m
    v = np.full(n, 2.0)
    acc = (s > 1.0) & (s < 8.0)
    v[acc] = np.sqrt(4.0 + 2 * 3.0 * (s[acc] - 1.0))
    top = float(v[acc].max())
    brk = (s >= 8.0) & (s < 20.0)
    v[brk] = np.maximum(2.0, np.sqrt(np.maximum(top**2 - 2 * 6.0 * (s[brk] - 8.0), 0.0)))
    plan = ReferenceLap.from_path(tr, tr.signed_curvature(), v, CAR)
    timing = TrackerTiming(0.05, 0.0, 0.0)
    tracker = Tracker.for_vehicle(plan, timing, TrackerGains(k_outward_per_s2=0.0), CAR)
    for s_car, a_p, k in (
        (4.0, 3.0, CAR.speed_gain_accel_per_s),
        (10.0, -6.0, CAR.speed_gain_brake_per_s),
    ):
        x, y = tr.point_at(s_car)
        c = tracker.command(float(x), float(y), plan.at("yaw", s_car), s_hint_m=s_car)
        assert c.accel_mps2 == pytest.approx(a_p, rel=0.02)
        t0 = plan.at("t", s_car)
        mean_v = np.mean(plan.at("v", plan.s_at_time(t0 + timing.window(0.0))))
        assert c.speed_mps == pytest.approx(mean_v + a_p / k, abs=0.02)


def test_the_timing_windows_cover_one_period_after_the_delay() -> None:
    t = TrackerTiming(0.05, 0.012, 0.06)
    w = t.window(t.steering_delay_s)
    assert len(w) == 5 and w[0] == pytest.approx(0.065) and w[-1] == pytest.approx(0.105)
    assert TrackerTiming(0.005, 0.01, 0.04).window(0.04).tolist() == pytest.approx([0.0425])
    with pytest.raises(ValueError):
        TrackerTiming(0.0, 0.0, 0.0)


# --------------------------------------------------------------------------- in the car
@pytest.mark.slow
def test_the_car_settles_on_a_straight_from_a_lateral_offset() -> None:
    """10 cm off the line at 4 m/s on a straight: back within 1 cm in under a second,
    without overshooting by more than 2 cm."""
    tr = stadium(30.0, 3.0)
    plan = ReferenceLap.from_path(tr, tr.signed_curvature(), np.full(tr.n_points, 4.0), CAR)
    out = drive(make_tracker(plan), (1.0, -0.10, 0.0), 4.0, 3.0)
    straight = out["s"] < 28.0
    e, t = out["e"][straight], out["t"][straight]
    assert e[0] == pytest.approx(0.10, abs=1e-3)  # right of the line
    assert np.all(np.abs(e[t > 1.0]) < 0.01)
    assert e.min() > -0.02
    assert np.all(np.abs(out["v"][straight & (out["t"] > 1.0)] - 4.0) < 0.02)


@pytest.mark.slow
def test_the_car_holds_a_circle_at_the_grip_limit() -> None:
    """A 1.5 m circle at 90 % of mu g (3.73 m/s, 9.3 m/s^2 lateral, 1.7 m/s^2 of drive
    against the cornering drag): about the car's limit there (at 92 % it no longer
    settles: the drive's share of the friction and its load transfer off the front axle).
    From the simulator's kinematic reset the car settles within 5 mm of the line, at the
    planned speed."""
    radius = 1.5
    tr = circle(radius)
    v = math.sqrt(0.90 * CAR.mu * GRAVITY_MPS2 * radius)
    kappa = np.full(tr.n_points, 1.0 / radius)
    plan = ReferenceLap.from_path(tr, kappa, np.full(tr.n_points, v), CAR)
    s0 = 0.0
    x, y = tr.point_at(s0)
    out = drive(make_tracker(plan), (float(x), float(y), plan.at("yaw", s0)), v, 4.0)
    assert np.abs(out["e"]).max() < 0.06  # the reset's transient (measured 4.5 cm)
    settled = out["t"] > 2.5
    assert np.abs(out["e"][settled]).max() < 0.005  # measured 1.6 mm
    assert np.abs(out["v"][settled] - v).max() < 0.02
    assert np.abs(out["steer"][settled]).max() < 0.3  # the steering keeps room to correct


@pytest.mark.slow
def test_the_car_reaches_the_planned_acceleration_through_its_speed_loop() -> None:
    """A stadium straight planned at +3 m/s^2 then -4 m/s^2: the car's measured
    acceleration is the plan's and its speed stays within 0.1 m/s of it."""
    tr = stadium(20.0, 2.5)
    s = tr.s_m
    v_turn = 3.0
    v = np.full(tr.n_points, v_turn)
    acc = (s > 1.0) & (s < 5.0)
    v[acc] = np.sqrt(v_turn**2 + 2 * 3.0 * (s[acc] - 1.0))
    top = float(v[acc].max())  # 5.7 m/s
    brk = (s >= 5.0) & (s < 20.0)
    v[brk] = np.maximum(v_turn, np.sqrt(np.maximum(top**2 - 2 * 4.0 * (s[brk] - 5.0), 0.0)))
    plan = ReferenceLap.from_path(tr, tr.signed_curvature(), v, CAR)
    out = drive(make_tracker(plan), (0.0, 0.0, 0.0), v_turn, 2 * plan.lap_time_s)
    lap2 = out["t"] > plan.lap_time_s
    t, sc, vc = out["t"][lap2], out["s"][lap2], out["v"][lap2]
    a_car = np.gradient(vc, t)
    ramp = (sc > 1.8) & (sc < 4.5)
    brake = (sc > 5.8) & (sc < 7.5)
    assert ramp.sum() >= 5 and brake.sum() >= 5
    assert np.median(a_car[ramp]) == pytest.approx(3.0, rel=0.1)
    assert np.median(a_car[brake]) == pytest.approx(-4.0, rel=0.1)
    assert np.abs(vc - out["v_plan"][lap2]).max() < 0.1


def test_the_lateral_gain_falls_with_the_square_of_the_speed_above_its_speed() -> None:
    """``k_lateral_speed_mps``: k_e itself up to it (the paper's 4.18 m/s cap races exactly
    as before), ``k_e (v_k / v)^2`` above (the heading gain ``k_e l_d v / L`` would grow
    with v^2); None: k_e at every speed."""
    from shared.config.planner import RacelineSettings

    g = TrackerGains(k_lateral_radpm=0.5, k_lateral_speed_mps=5.0)
    assert g.k_lateral_at(0.0) == 0.5 and g.k_lateral_at(5.0) == 0.5
    assert g.k_lateral_at(10.0) == pytest.approx(0.125)
    assert TrackerGains(k_lateral_radpm=0.5).k_lateral_at(10.0) == 0.5
    o = RacelineSettings(k_lateral_speed_mps=6.0, k_lateral_speed_exponent=2.0)
    assert tracker_gains(o).k_lateral_at(12.0) == pytest.approx(0.25 * o.k_lateral_radpm)


def test_the_lateral_gain_schedule_is_on_by_default_at_the_papers_cap() -> None:
    """``[planner.raceline]``'s default turns the schedule on at the paper's 4.18 m/s cap:
    every lap at or below it keeps k_e (the bench regression), 10 m/s gets (4.18 / 10)^2 of
    it (issue #21: the tracker weaved wall to wall at 9-10 m/s)."""
    from shared.config.planner import RacelineSettings

    o = RacelineSettings(k_lateral_speed_exponent=2.0)
    assert o.k_lateral_speed_mps == 4.18
    g = tracker_gains(o)
    assert g.k_lateral_at(4.18) == o.k_lateral_radpm
    assert g.k_lateral_at(10.0) == pytest.approx(o.k_lateral_radpm * 0.4180**2)
    assert tracker_gains(RacelineSettings(k_lateral_speed_mps=None)).k_lateral_at(10.0) == (
        o.k_lateral_radpm
    )


def test_above_its_speed_the_outward_cut_gives_up_drive_but_never_brakes() -> None:
    """``outward_drive_only_speed_mps`` (default 4.18 m/s): above it a drift to a bend's
    outside takes the acceleration down to ``min(a_p, 0)`` at most (the braking would take
    the same friction ellipse the lateral force needs); at or below it, the cut as before."""
    from dataclasses import replace

    tr = circle(3.0)
    n = tr.n_points
    timing = TrackerTiming(0.05, 0.0, 0.0)
    s_car = 5.0
    x, y = tr.point_at(s_car)
    # 0.2 m outside the left bend: to the right of the path (e right +)
    heading = float(tr.heading_at(s_car))
    px, py = float(x) + 0.2 * math.sin(heading), float(y) - 0.2 * math.cos(heading)
    for v_plan, a_plan in ((6.0, 1.0), (6.0, -3.0), (3.0, -3.0), (4.18 + 1e-7, -3.0)):
        base = ReferenceLap.from_path(tr, tr.signed_curvature(), np.full(n, v_plan), CAR)
        plan = replace(base, a_mps2=np.full(n, a_plan))
        cut = 25.0 * 0.2 * math.tanh((1.0 / 3.0) / 0.1)
        old = Tracker.for_vehicle(plan, timing, TrackerGains(), CAR)
        new = Tracker.for_vehicle(
            plan, timing, TrackerGains(outward_drive_only_speed_mps=4.18), CAR
        )
        a_old = old.command(px, py, plan.at("yaw", s_car), s_hint_m=s_car).accel_mps2
        a_new = new.command(px, py, plan.at("yaw", s_car), s_hint_m=s_car).accel_mps2
        assert a_old == pytest.approx(a_plan - cut, abs=0.05)
        if v_plan > 5.18:  # 1 m/s over: the rule in full
            assert a_new == pytest.approx(max(a_plan - cut, min(a_plan, 0.0)), abs=0.05)
        else:  # at the cap (and over it by IPOPT's tolerance): the cut as before
            assert a_new == pytest.approx(a_old, abs=1e-5)
    assert tracker_gains(SETTINGS.raceline).outward_drive_only_speed_mps == 4.18


def test_the_schedules_exponent() -> None:
    """``k_lateral_speed_exponent`` n: ``k_e (v_k / v)^n`` above v_k (default 3), k_e at
    and below it whatever n."""
    g = TrackerGains(k_lateral_radpm=0.5, k_lateral_speed_mps=4.0, k_lateral_speed_exponent=4.0)
    assert g.k_lateral_at(4.0) == 0.5 and g.k_lateral_at(2.0) == 0.5
    assert g.k_lateral_at(8.0) == pytest.approx(0.5 / 16.0)
    o = SETTINGS.raceline
    assert o.k_lateral_speed_exponent == 3.0
    assert tracker_gains(o).k_lateral_at(10.0) == pytest.approx(o.k_lateral_radpm * 0.418**3)


def test_a_slower_plan_keeps_a_power_of_the_plans_dynamic_part() -> None:
    """``ReferenceLap.slower``: the steady state at the slower speeds plus
    share^``DYNAMIC_SHARE_EXPONENT`` of what the plan steers and yaws beyond its own steady
    state (the yaw's part wrapped: a plan's unwrapped yaw may start a turn away from the
    steady state's)."""
    from services.planner.raceline.tracker import DYNAMIC_SHARE_EXPONENT

    k = 0.8**DYNAMIC_SHARE_EXPONENT
    track = stadium(4.0, 1.5)
    kappa = track.signed_curvature()
    steady = ReferenceLap.from_path(track, np.asarray(kappa), np.full(len(track.xy), 3.0), CAR)
    rng = np.random.default_rng(0)
    dyn_delta = 0.05 * rng.standard_normal(len(steady.s_m))
    dyn_yaw = 0.02 * rng.standard_normal(len(steady.s_m))
    plan = ReferenceLap(
        line=steady.line, s_m=steady.s_m, yaw_rad=steady.yaw_rad + dyn_yaw + 2 * math.pi,
        kappa_1pm=steady.kappa_1pm, v_mps=steady.v_mps, a_mps2=steady.a_mps2,
        delta_rad=steady.delta_rad + dyn_delta, t_s=steady.t_s, lap_time_s=steady.lap_time_s,
    )
    assert plan.slower(1.0, CAR) is plan
    slow = plan.slower(0.8, CAR)
    bare = ReferenceLap.from_path(track, np.asarray(kappa), 0.8 * plan.v_mps, CAR)
    assert slow.v_mps == pytest.approx(0.8 * plan.v_mps)
    assert slow.t_s == pytest.approx(bare.t_s)
    assert slow.delta_rad == pytest.approx(bare.delta_rad + k * dyn_delta)
    assert slow.yaw_rad == pytest.approx(bare.yaw_rad + k * dyn_yaw)
    with pytest.raises(ValueError, match="share"):
        plan.slower(0.0, CAR)


def test_the_feedback_is_scheduled_on_the_cars_own_speed_when_it_is_given() -> None:
    """``speed_mps``: a car far below its plan (joining from rest a line planned at 8 m/s)
    has the feedback of its own speed, ``k_e(min(v_p, v))``; at or above the plan's, or
    with both at or below ``k_lateral_speed_mps``, the plan's as before."""
    tr = circle(20.0)
    n = tr.n_points
    plan = ReferenceLap.from_path(tr, tr.signed_curvature(), np.full(n, 8.0), CAR)
    gains = TrackerGains(k_lateral_radpm=0.5, k_lateral_speed_mps=4.18,
                         k_lateral_speed_exponent=3.0)
    timing = TrackerTiming(0.05, 0.0, 0.0)
    s_car = 3.0
    x, y = tr.point_at(s_car)
    heading = float(tr.heading_at(s_car))
    px, py = float(x) + 0.2 * math.sin(heading), float(y) - 0.2 * math.cos(heading)
    yaw = plan.at("yaw", s_car)

    def steer(**kw) -> float:
        t = Tracker.for_vehicle(plan, timing, gains, CAR)
        return t.command(px, py, yaw, s_hint_m=s_car, **kw).steering_rad

    ff = steer(speed_mps=8.0) - gains.k_lateral_at(8.0) * 0.2  # the feed-forward (e_la = e)
    assert steer() == pytest.approx(steer(speed_mps=8.0)) == pytest.approx(steer(speed_mps=9.0))
    assert steer(speed_mps=2.0) - ff == pytest.approx(0.5 * 0.2, rel=1e-6)
    assert steer(speed_mps=6.0) - ff == pytest.approx(gains.k_lateral_at(6.0) * 0.2, rel=1e-6)
    assert steer(speed_mps=2.0) - ff > 5.0 * (steer() - ff)
