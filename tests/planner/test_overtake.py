"""Planning with opponents (issue #24): the prediction along the line, the corridor plan,
and a planner facing a stopped car on a straight (passes it or stops behind it, never
touches it)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from services.planner.opponents import OpponentEstimate, predict_on_line
from services.planner.raceline.overtake import OvertakeParams, corridor_path, plan_around
from services.planner.raceline.planner import RacelinePlanner
from services.planner.raceline.tracker import ReferenceLap
from services.tools.bench.head_to_head import HeadToHeadOptions, race_seed
from shared.car import CAR
from shared.config.planner import PlannerSettings, RacelineSettings
from shared.config.simulator import SimulatorSettings
from shared.config.vehicle import F1TENTH_GYM
from shared.track import Track

CAR_W = CAR.width_m
PLANNER = PlannerSettings(raceline=RacelineSettings(line="min_curvature"))


def stadium(straight_m: float = 20.0, radius_m: float = 4.0, half_width_m: float = 1.0,
            spacing_m: float = 0.1) -> Track:
    """A closed stadium: two straights joined by half circles, counter-clockwise."""
    pts = []
    n_s = int(straight_m / spacing_m)
    n_c = int(math.pi * radius_m / spacing_m)
    for i in range(n_s):
        pts.append((i * spacing_m, -radius_m))
    for i in range(n_c):
        a = -math.pi / 2 + math.pi * i / n_c
        pts.append((straight_m + radius_m * math.cos(a), radius_m * math.sin(a)))
    for i in range(n_s):
        pts.append((straight_m - i * spacing_m, radius_m))
    for i in range(n_c):
        a = math.pi / 2 + math.pi * i / n_c
        pts.append((radius_m * math.cos(a), radius_m * math.sin(a)))
    xy = np.array(pts)
    w = np.full(len(xy), half_width_m)
    return Track("stadium", xy, w, w)


def straight_line_lap(length_m: float = 200.0, v: float = 4.0, half_width_m: float = 1.0):
    """A huge circle (nearly straight) as a plan at constant speed."""
    radius = length_m / (2 * math.pi)
    n = 2000
    t = np.linspace(0, 2 * np.pi, n, endpoint=False)
    xy = radius * np.column_stack([np.cos(t), np.sin(t)])
    line = Track("big", xy, np.full(n, half_width_m), np.full(n, half_width_m))
    kappa = np.full(n, 1.0 / radius)
    return ReferenceLap.from_path(line, kappa, np.full(n, v), F1TENTH_GYM)


def car_on_line(line: Track, s_m: float, v_mps: float, oid: int = 1) -> OpponentEstimate:
    """An opponent at arc length `s_m` [m] of `line`, on it, heading along it at `v_mps`."""
    x, y = (float(v) for v in line.point_at(s_m))
    h = float(line.heading_at(s_m))
    return OpponentEstimate(oid, x, y, v_mps * math.cos(h), v_mps * math.sin(h), h)


def test_an_opponent_is_predicted_along_the_line_at_its_progress_speed() -> None:
    ref = straight_line_lap()
    line = ref.line
    s0 = 10.0
    x, y = (float(v) for v in line.point_at(s0))
    h = float(line.heading_at(s0))
    o = OpponentEstimate(7, x, y, 2.0 * math.cos(h), 2.0 * math.sin(h), h)
    t = np.arange(5) * 0.1
    p = predict_on_line(line, o, t, s_hint_m=s0)
    assert p.id == 7 and p.v_s_mps == pytest.approx(2.0, abs=1e-3)
    np.testing.assert_allclose(p.s_m, s0 + 2.0 * t, atol=1e-3)
    np.testing.assert_allclose(p.e_m, 0.0, atol=1e-3)
    # with the line's profile (4 m/s here, 2 m/s from 10.25 m on) it keeps its share (half)
    v = np.where((ref.s_m > s0 + 0.25) & (ref.s_m < 100.0), 2.0, 4.0)
    slow = ReferenceLap.from_path(line, ref.kappa_1pm, v, F1TENTH_GYM)
    q = predict_on_line(line, o, t, s0, slow)
    assert q.s_m[-1] < p.s_m[-1] - 0.1 and q.s_m[1] == pytest.approx(p.s_m[1], abs=0.02)
    stopped = OpponentEstimate(1, x, y, 0.0, 0.0, h)
    np.testing.assert_allclose(predict_on_line(line, stopped, t, s0, slow).s_m, s0, atol=1e-3)


def test_the_corridor_path_is_rate_limited_and_none_when_out_of_reach() -> None:
    p = OvertakeParams()
    t = p.times()
    lo = np.full(len(t), -1.0)
    hi = np.full(len(t), 1.0)
    lo[15:] = 0.4  # must be 0.4 m right from 1.5 s on
    path = corridor_path(0.0, lo, hi, t, p)
    assert path is not None
    assert np.all(np.abs(np.diff(path)) <= p.lateral_rate_mps * p.stage_s + 1e-9)
    assert np.all(path[15:] >= 0.4 - 1e-9) and path[0] == 0.0
    lo[2:] = 0.4  # in 0.2 s: out of reach
    assert corridor_path(0.0, lo, hi, t, p) is None


@pytest.mark.parametrize(("half_width", "mode"), [(1.0, "pass"), (0.3, "follow")])
def test_a_slow_car_ahead_is_passed_where_there_is_room_else_followed(
    half_width: float, mode: str
) -> None:
    ref = straight_line_lap(half_width_m=half_width)
    line = ref.line
    s_o = 16.0
    o = car_on_line(line, s_o, 1.0)
    p = OvertakeParams()
    pred = predict_on_line(line, o, p.times(), 10.0)
    plan = plan_around(ref, 10.0, 0.0, [pred], 0.0, p, v_e_mps=4.0)
    assert plan.mode == mode and plan.blocking == (1,)
    if mode == "pass":
        assert abs(plan.offset_m) > 0.3 and plan.speed_cap_mps > 4.0
    else:  # and it slows down to keep its gap as it closes in
        assert abs(plan.offset_m) < 0.05
        near = plan_around(ref, s_o - 1.5, 0.0, [predict_on_line(line, o, p.times(), 14.5)],
                           0.0, p, v_e_mps=4.0)
        assert near.mode == "follow" and near.speed_cap_mps < 2.0


def test_a_pass_is_planned_at_the_speeds_the_car_is_held_to() -> None:
    """A car at 0.8 of the line's speeds 1.5 m ahead on a long straight: at the line's
    speeds the ego passes; held to 0.75 of them (a cautious out lap, a grip adaptation) it
    is slower than that car and stays behind it. Planned at the line's speeds, such a pass
    ended squeezed beside the car (Oschersleben seeds 610-637 in the out lap)."""
    ref = straight_line_lap(half_width_m=1.0)
    line = ref.line
    s_o = 11.5
    o = car_on_line(line, s_o, 3.2)
    p = OvertakeParams()
    pred = predict_on_line(line, o, p.times(), s_o, ref)  # 0.8 of the line's 4 m/s
    full = plan_around(ref, 10.0, 0.0, [pred], 0.0, p, v_e_mps=4.0)
    held = plan_around(ref, 10.0, 0.0, [pred], 0.0, p, v_e_mps=3.0, speed_scale=0.75)
    assert full.mode == "pass" and abs(full.offset_m) > 0.3
    assert held.mode in ("line", "follow") and abs(held.offset_m) < 0.05


def test_nobody_near_leaves_the_line_free() -> None:
    ref = straight_line_lap()
    line = ref.line
    x, y = (float(v) for v in line.point_at(60.0))
    o = OpponentEstimate(1, x, y, 0.0, 0.0, 0.0)
    p = OvertakeParams()
    plan = plan_around(ref, 10.0, 0.0, [predict_on_line(line, o, p.times(), 60.0)], 0.0, p,
                       v_e_mps=1.0)
    assert plan.mode == "line" and plan.offset_m == 0.0 and plan.speed_cap_mps == math.inf


class StoppedCar:
    """An opponent that stands still (a stopped car)."""

    def __init__(self, settings: PlannerSettings) -> None:
        self.settings = settings

    def reset(self) -> None:
        """Nothing to forget."""

    def step(self, *pose: float):
        from services.planner.interface import DriveCommand

        class _R:
            command = DriveCommand(0.0, 0.0)

        return _R()


@pytest.mark.parametrize("half_width", [1.0, 0.32])
def test_a_stopped_car_on_a_straight_is_passed_or_waited_behind_never_touched(
    half_width: float,
) -> None:
    track = stadium(half_width_m=half_width)
    ego = RacelinePlanner(track, PLANNER, vehicle=F1TENTH_GYM)
    opts = HeadToHeadOptions(laps=1, gap_m=(10.0, 10.0001))
    r = race_seed(ego, StoppedCar(PLANNER), track, SimulatorSettings(), opts, seed=0)
    assert r.contacts == 0
    assert r.ego_off_track == 0
    if half_width >= 1.0:  # a 2 m wide straight: room beside it
        assert r.overtakes == 1 and not r.aborted
    else:  # 0.64 m: no room, the ego waits behind it
        assert r.overtakes == 0 and r.aborted and 0.3 < r.ego_distance_m < 10.0


def _ahead(line, s: float, v: float, oid: int = 1, e: float = 0.0) -> OpponentEstimate:
    x, y = (float(c) for c in line.point_at(s))
    h = float(line.heading_at(s))
    x, y = x + e * math.sin(h), y - e * math.cos(h)  # e right +
    return OpponentEstimate(oid, x, y, v * math.cos(h), v * math.sin(h), h)


def test_a_pass_that_cannot_be_over_within_the_horizon_is_not_started() -> None:
    ref = straight_line_lap(half_width_m=1.0)
    line = ref.line
    p = OvertakeParams()
    for v_o, s_o, mode in ((3.9, 11.0, "follow"), (2.0, 13.0, "pass")):
        o = _ahead(line, s_o, v_o)
        plan = plan_around(ref, 10.0, 0.0, [predict_on_line(line, o, p.times(), s_o)], 0.0,
                           p, v_e_mps=4.0)
        assert plan.mode == mode, (v_o, plan)


def test_following_waits_beside_the_line_of_the_car_ahead_just_behind_side_by_side() -> None:
    ref = straight_line_lap(half_width_m=1.0)
    line = ref.line
    p = OvertakeParams()
    o = _ahead(line, 11.0, 3.9)  # too little slower to be passed within the horizon
    pred = predict_on_line(line, o, p.times(), 11.0)
    plan = plan_around(ref, 10.0, 0.0, [pred], 0.0, p, v_e_mps=3.9)
    clear = 0.5 * (p.ego_width_m + o.width_m) + p.margin_lateral_m
    assert plan.mode == "follow" and 0.15 < abs(plan.offset_m) <= clear + 0.03
    # there, beside its line, it closes in to just behind side by side, not further
    side = math.copysign(clear + 0.02, plan.offset_m)
    ready = plan_around(ref, 10.0, side, [pred], side, p, v_e_mps=3.9)
    assert ready.mode == "follow" and ready.speed_cap_mps > 3.9 + 0.2
    beside = 0.5 * (p.ego_length_m + o.length_m) + p.margin_longitudinal_m
    close = plan_around(ref, 11.0 - beside, side, [pred], side, p, v_e_mps=3.9)
    assert close.speed_cap_mps < 3.9 + 0.1


def test_the_outside_of_a_bend_is_longer_and_the_inside_slower_but_shorter() -> None:
    from services.planner.raceline.overtake import _progress_on

    p = OvertakeParams()
    s_e = np.linspace(0.0, 10.0, 11)
    kappa = np.full(11, 0.5)  # a left bend: the inside is left (e < 0)
    line_prog = _progress_on(s_e, kappa, np.zeros(11), p)
    outside = _progress_on(s_e, kappa, np.full(11, 0.4), p)
    inside = _progress_on(s_e, kappa, np.full(11, -0.4), p)
    np.testing.assert_allclose(line_prog, s_e)
    assert outside[-1] == pytest.approx(10.0 / 1.2) and inside[-1] == pytest.approx(
        10.0 / math.sqrt(0.8))


def test_the_offset_path_gets_its_own_feed_forward_steering() -> None:
    track = stadium()
    ego = RacelinePlanner(track, PLANNER, vehicle=F1TENTH_GYM)
    ref = ego.raceline.reference
    s = float(ref.s_m[int(np.argmax(ref.kappa_1pm))])
    ego._offset = -0.3  # inside of the left bend: tighter, more steering to the left
    assert ego._offset_steering(s) > 0.0
    ego._offset = 0.3
    assert ego._offset_steering(s) < 0.0


def test_a_start_can_end_once_the_ego_has_passed_and_leads() -> None:
    track = stadium(half_width_m=1.0)
    ego = RacelinePlanner(track, PLANNER, vehicle=F1TENTH_GYM)
    opts = HeadToHeadOptions(laps=1, gap_m=(10.0, 10.0001), stop_lead_m=2.0)
    r = race_seed(ego, StoppedCar(PLANNER), track, SimulatorSettings(), opts, seed=0)
    assert r.overtakes == 1 and r.stopped_at_lead and r.contacts == 0
    assert 12.0 < r.ego_distance_m < 0.5 * track.length_m


def test_side_by_side_where_the_track_is_too_narrow_the_walls_give_way_not_the_car() -> None:
    """Beside a car where the track leaves less than the plan's margins, the ego keeps its
    side of the car: the bound the wall sets gives way, never the one the car sets (the
    bounds were swapped: the target moved 0.15 m towards the car beside, into a contact)."""
    ref = straight_line_lap(half_width_m=0.58)
    line = ref.line
    p = OvertakeParams()
    clear = 0.5 * (p.ego_width_m + CAR_W) + p.margin_lateral_m
    for e_e, v_o in ((-0.36, 3.9), (0.36, 3.9), (-0.36, 4.1)):
        o = _ahead(line, 10.1, v_o)  # side by side, on the line
        pred = predict_on_line(line, o, p.times(), 10.1)
        plan = plan_around(ref, 10.0, e_e, [pred], e_e, p, v_e_mps=4.0)
        assert plan.mode == "follow", plan
        assert abs(plan.offset_m) >= clear - 1e-6 and plan.offset_m * e_e > 0.0, (e_e, plan)


def _narrowing_lap(narrow_from_m: float, narrow_len_m: float = 3.0, hw_m: float = 0.55,
                   length_m: float = 200.0, v: float = 4.0) -> ReferenceLap:
    """A nearly straight line at `v` whose half-width is `hw_m` over ``[narrow_from_m,
    narrow_from_m + narrow_len_m)`` and 1 m elsewhere."""
    radius = length_m / (2 * math.pi)
    n = 2000
    t = np.linspace(0, 2 * np.pi, n, endpoint=False)
    xy = radius * np.column_stack([np.cos(t), np.sin(t)])
    s = np.arange(n) * length_m / n
    w = np.where((s >= narrow_from_m) & (s < narrow_from_m + narrow_len_m), hw_m, 1.0)
    line = Track("narrowing", xy, w, w)
    return ReferenceLap.from_path(line, np.full(n, 1.0 / radius), np.full(n, v), F1TENTH_GYM)


def test_a_pass_keeps_slack_before_the_track_narrows() -> None:
    """A pass predicted to come clear of the car just before the track narrows (no room
    beside it there) is not started with ``pass_slack_s``: a car slower than its plan was
    squeezed between the car and the wall there (Oschersleben, the lidar view). Well
    before the narrowing the pass is taken either way."""
    import dataclasses

    def mode(narrow_from_m: float, slack_s: float) -> str:
        ref = _narrowing_lap(narrow_from_m)
        p = dataclasses.replace(OvertakeParams(), pass_slack_s=slack_s)
        o = _ahead(ref.line, 12.5, 3.0)  # 1 m/s slower: beside from 1.8 s to 3.2 s
        pred = predict_on_line(ref.line, o, p.times(), 12.5)
        return plan_around(ref, 10.0, 0.0, [pred], 0.0, p, v_e_mps=4.0).mode

    assert mode(22.5, 0.0) == "pass" and mode(22.5, 0.2) == "follow"
    assert mode(26.0, 0.0) == "pass" and mode(26.0, 0.2) == "pass"
    assert mode(150.0, 0.2) == "pass"


def _alone_on_the_stadium_line() -> tuple[RacelinePlanner, tuple[float, float, float]]:
    """A raceline planner on the stadium with nobody near, after one step from its line's
    rear-axle pose 5 m in (returned: the planner and that pose [m, m, rad])."""
    track = stadium(half_width_m=1.0)
    ego = RacelinePlanner(track, PLANNER, vehicle=F1TENTH_GYM)
    line = ego.raceline.track
    x, y = (float(v) for v in line.point_at(5.0))
    yaw = float(line.heading_at(5.0))
    lr = F1TENTH_GYM.lr_m
    pose = (x - lr * math.cos(yaw), y - lr * math.sin(yaw), yaw)
    ego.set_opponents([])
    ego.step(*pose)
    return ego, pose


def test_back_towards_the_line_the_offset_eases_in() -> None:
    """Nobody near any more, the offset returns to the line at most at the lateral rate and
    slower as it nears it (a first-order lag, ``RETURN_TAU_S``): at the full rate the car
    reached the line 0.17 rad across it and ran on over an apex's wall."""
    from services.planner.raceline.planner import RETURN_TAU_S

    ego, (rx, ry, yaw) = _alone_on_the_stadium_line()
    lo, hi = ego._offset_room(ego._s_line)  # inside the track ahead (kept there)
    ego._offset = 0.3 if hi >= 0.3 else -0.3  # where a pass left it
    assert lo < ego._offset < hi
    offsets = [ego._offset]
    for _ in range(120):
        ego.step(rx, ry, yaw)
        offsets.append(ego._offset)
    sign = math.copysign(1.0, offsets[0])
    offsets = [sign * o for o in offsets]
    steps = -np.diff(offsets)
    dt = PLANNER.dt_s
    assert np.all(steps >= 0.0) and steps.max() <= 0.7 * dt + 1e-9
    near = [st for o, st in zip(offsets, steps, strict=False) if 0.0 < o < 0.05]
    assert near and max(near) <= 0.05 / RETURN_TAU_S * dt + 1e-9  # slow near the line
    assert offsets[-1] == 0.0  # and on it in the end


def test_where_the_line_runs_nearer_a_wall_than_the_room_the_offset_still_ends_on_it() -> None:
    """With nobody near, the offset is kept inside the track ahead, but never pushed off the
    line for it: where the line runs nearer a wall than the offset's room (an apex), the
    bound left the offset jumping round it and never back to 0 (the car weaved and left the
    track 101 times in 10 two-car starts on map416)."""
    ego, (rx, ry, yaw) = _alone_on_the_stadium_line()
    ego._offset_room = lambda s_m: (0.05, 0.6)  # the line itself outside the room
    ego._offset = 0.3
    for _ in range(200):
        ego.step(rx, ry, yaw)
    assert ego._offset == 0.0
