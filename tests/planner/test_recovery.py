"""The recovery rule: when it takes over, how it steers, when it hands back; and the
identified real car, which spins in map416's turns, finishing its laps with it."""

from __future__ import annotations

import math

import numpy as np
import pytest

from services.planner.mintime.store import ensure_artefacts
from services.planner.mpc.planner import RECOVERING, SOLVED, Planner
from services.planner.raceline.planner import RacelinePlanner
from services.planner.recovery import (
    STILL_RADIUS_M,
    HandOver,
    Recovery,
    StallWatch,
    track_heading_error,
)
from services.tools.bench import LoopOptions, run_method
from shared.config import RacestackConfig
from shared.config.methods import RACELINE
from shared.config.planner import PlannerSettings, RecoverySettings
from shared.config.simulator import SimulatorSettings
from shared.config.vehicle import vehicle_preset
from shared.track import Track, load_track


@pytest.fixture(scope="module")
def track():
    return load_track("builtin:paperlike")


def _pose_on(track, s: float, e: float, yaw_offset: float = 0.0) -> tuple[float, float, float]:
    """Pose at arc length s, contour error e (right +), heading along the track + offset."""
    x, y = (float(v) for v in track.point_at(s))
    h = float(track.heading_at(s))
    # the right of the heading is (sin h, -cos h)
    return x + e * math.sin(h), y - e * math.cos(h), h + yaw_offset


def test_racing_car_is_left_alone(track) -> None:
    rec = Recovery(track, RecoverySettings(), 0.324, 0.35)
    for s in np.linspace(0.0, track.length_m, 50, endpoint=False):
        x, y, yaw = _pose_on(track, s, 0.2, 0.3)
        assert rec.update(x, y, yaw, s, 0.2) is None
    assert rec.episodes == 0 and not rec.active


def test_enters_off_track_and_hands_back_on_track(track) -> None:
    rec = Recovery(track, RecoverySettings(), 0.324, 0.35)
    w_r = float(track.interp_width(5.0)[0])
    x, y, yaw = _pose_on(track, 5.0, w_r + 0.5)
    cmd = rec.update(x, y, yaw, 5.0, w_r + 0.5)
    assert cmd is not None and rec.active and rec.episodes == 1
    assert cmd.speed_mps == RecoverySettings().speed_mps
    assert cmd.steering_rad > 0.0  # right of the track: steer left, back towards it
    assert "outside" in cmd.reason
    x, y, yaw = _pose_on(track, 5.5, 0.0, 0.1)
    assert rec.update(x, y, yaw, 5.5, 0.0) is None and not rec.active
    assert rec.episodes == 1


def test_a_spun_car_turns_round_at_full_lock(track) -> None:
    rec = Recovery(track, RecoverySettings(), 0.324, 0.35)
    x, y, yaw = _pose_on(track, 8.0, 0.0, math.pi - 0.2)  # on the track, facing backwards
    cmd = rec.update(x, y, yaw, 8.0, 0.0)
    assert cmd is not None and abs(cmd.steering_rad) == pytest.approx(0.35)
    assert "heading" in cmd.reason
    assert rec.update(x, y, yaw, 8.0, 0.0) is not None  # still facing backwards: stays


def _rounded_triangle(side_m: float = 20.0, radius_m: float = 0.85, half_width_m: float = 1.1,
                      step_m: float = 0.1) -> tuple[Track, np.ndarray]:
    """A left-turning loop: three straights joined by 120-degree bends of `radius_m` (the
    centreline's radius below its half-width, like YasMarina's hairpin); the first bend's
    centre."""
    pts, centre0 = [], None
    heading = 0.0
    p = np.array([0.0, 0.0])
    for k in range(3):
        n = int(side_m / step_m)
        d = np.array([math.cos(heading), math.sin(heading)])
        pts += [p + d * step_m * i for i in range(n)]
        p = p + d * step_m * n
        centre = p + radius_m * np.array([-math.sin(heading), math.cos(heading)])
        centre0 = centre if k == 0 else centre0
        arc = int(radius_m * 2.0 * math.pi / 3.0 / step_m)
        for i in range(arc):
            a = heading - math.pi / 2 + (2.0 * math.pi / 3.0) * i / arc
            pts.append(centre + radius_m * np.array([math.cos(a), math.sin(a)]))
        heading += 2.0 * math.pi / 3.0
        p = centre + radius_m * np.array([math.sin(heading), -math.cos(heading)])
    xy = np.array(pts)
    w = np.full(len(xy), half_width_m)
    return Track("rounded-triangle", xy, w, w), centre0


def test_a_car_cutting_a_tight_hairpin_is_not_taken_for_a_spun_one() -> None:
    track, centre = _rounded_triangle()
    rec = Recovery(track, RecoverySettings(), 0.324, 0.35)
    lead = math.radians(75.0)  # the car already turned further than the bend beside it
    for frac in np.linspace(0.1, 0.9, 9):
        a = -math.pi / 2 + (2.0 * math.pi / 3.0) * frac  # round the first bend
        x, y = centre + (0.85 - 0.54) * np.array([math.cos(a), math.sin(a)])  # 0.54 inside
        yaw = a + math.pi / 2 + lead
        s, e = (float(v) for v in track.project(np.array([x, y])))
        assert e == pytest.approx(-0.54, abs=0.02)
        own = abs(math.remainder(yaw - float(track.heading_at(s)), math.tau))
        assert own > RecoverySettings().enter_heading_rad - math.radians(10)
        assert track_heading_error(track, yaw, s, e) < RecoverySettings().enter_heading_rad
        assert rec.update(x, y, yaw, s, e) is None
    # on the outside of the bend the projection's heading is well defined: its own counts
    a = -math.pi / 2 + math.pi / 3  # the bend's middle
    x, y = centre + (0.85 + 0.5) * np.array([math.cos(a), math.sin(a)])
    s, e = (float(v) for v in track.project(np.array([x, y])))
    assert e == pytest.approx(0.5, abs=0.02)
    assert track_heading_error(track, a + math.pi / 2 + lead, s, e) == pytest.approx(
        lead, abs=math.radians(8))
    # the same heading error on a straight, or beside the bend on the line: a spun car
    for s in (5.0, 20.5):
        yaw = float(track.heading_at(s))
        assert track_heading_error(track, yaw + lead, s, 0.0) == pytest.approx(lead)
    x, y = (float(v) for v in track.point_at(5.0))
    cmd = rec.update(x, y, lead, 5.0, 0.0)
    assert cmd is not None and "heading" in cmd.reason


def test_a_car_held_still_is_moved_on(track) -> None:
    rec = Recovery(track, RecoverySettings(), 0.324, 0.35)
    x, y, yaw = _pose_on(track, 3.0, 0.0, 0.2)
    assert rec.update(x, y, yaw, 3.0, 0.0, stalled_s=0.5) is None
    cmd = rec.update(x, y, yaw, 3.0, 0.0, stalled_s=1.5)
    assert cmd is not None and "still" in cmd.reason


def test_disabled_rule_never_acts(track) -> None:
    rec = Recovery(track, RecoverySettings(enabled=False), 0.324, 0.35)
    x, y, yaw = _pose_on(track, 5.0, 3.0, math.pi)
    assert rec.update(x, y, yaw, 5.0, 3.0) is None


def test_planner_hands_over_and_resumes_cold(track) -> None:
    planner = Planner(track, PlannerSettings())
    x, y, yaw = _pose_on(track, 2.0, 0.0)
    assert planner.step(x, y, yaw).status == SOLVED
    x, y, yaw = _pose_on(track, 2.2, 0.0, math.pi)  # spun round
    res = planner.step(x, y, yaw)
    assert res.status == RECOVERING and res.solver_status.startswith("recovery:")
    assert res.command.speed_mps == pytest.approx(RecoverySettings().speed_mps)
    assert res.inputs.shape == (planner.horizon, 3) and res.states.shape[1] == 4
    x, y, yaw = _pose_on(track, 2.4, 0.0)
    assert planner.step(x, y, yaw).status == SOLVED
    assert planner.recovery.episodes == 1


def test_stall_is_judged_by_the_car_not_the_commands() -> None:
    """A car rocking by a few centimetres (small forward and backward commands, pose noise)
    stands still; one that moves on does not; ticks the method did not drive do not count."""
    watch = StallWatch()
    rng = np.random.default_rng(0)
    t = 0.0
    for k in range(30):  # +-4 cm of rocking and 1.5 cm of pose noise, 1.5 s
        x = 0.04 * (-1) ** k + rng.normal(0.0, 0.015)
        t = watch.update(x, rng.normal(0.0, 0.015), 0.05)
    assert t == pytest.approx(29 * 0.05)
    assert watch.update(0.0, 0.0, 0.05, counts=False) == pytest.approx(t)  # a braking tick
    assert watch.update(STILL_RADIUS_M + 0.05, 0.0, 0.05) == 0.0  # moved on: restarts
    # driving at 2 m/s: the count restarts every few ticks, far below any stall time
    assert max(watch.update(0.1 * k, 0.0, 0.05) for k in range(100)) <= 0.15


def test_the_rule_moves_on_a_car_held_still_by_oscillating_commands(track) -> None:
    """The method's commands alternate +0.4 / -0.3 m/s (each far above a "still" speed),
    the car barely moves: after ``stall_s`` the rule takes over."""
    planner = Planner(track, PlannerSettings())
    x, y, yaw = _pose_on(track, 2.0, 0.0)
    statuses = []
    for k in range(30):  # 1.5 s at 20 Hz, the car within 3 cm of where it stands
        statuses.append(planner.step(x + 0.03 * (k % 2), y, yaw).status)
    assert statuses[0] == SOLVED
    assert RECOVERING in statuses
    first = statuses.index(RECOVERING)
    assert 1.0 <= first * 0.05 <= 1.2  # stall_s = 1 s of the car standing
    assert planner.recovery.episodes == 1


def test_hand_over_ramps_from_the_cars_speed() -> None:
    ramp = HandOver(accel_mps2=9.51)
    assert ramp.cap(8.0, 0.05) == 8.0  # not handing over: untouched
    ramp.start(1.0)
    caps = [ramp.cap(8.0, 0.05) for _ in range(5)]
    assert caps == pytest.approx([1.0 + 9.51 * 0.05 * (k + 1) for k in range(5)])
    assert ramp.active
    assert ramp.cap(2.0, 0.05) == 2.0 and not ramp.active  # within reach: the method's own
    ramp.start(1.0)
    assert ramp.cap(-5.0, 0.05) == pytest.approx(-(1.0 + 9.51 * 0.05))  # reverse, capped too


@pytest.mark.parametrize("kind", ["mpc", "tracker"])
def test_the_hand_over_never_commands_more_than_the_car_can_reach(track, kind) -> None:
    """After a recovery the method's speed commands rise from the rule's speed by at most
    a_max Ts a tick."""
    settings = PlannerSettings()
    if kind == "tracker":
        ensure_artefacts(RACELINE, track, settings)
    planner = Planner(track, settings) if kind == "mpc" else RacelinePlanner(track, settings)
    a_step = 9.51 * settings.dt_s  # the default car's a_max over one tick
    w_r = float(track.interp_width(3.0)[0])
    planner.step(*_pose_on(track, 2.0, 0.0))
    res = planner.step(*_pose_on(track, 3.0, w_r + 0.5))  # off the track: the rule drives
    assert res.status == RECOVERING
    last = res.command.speed_mps
    for k in range(12):
        res = planner.step(*_pose_on(track, 3.2 + 0.1 * k, 0.0))
        assert res.status != RECOVERING
        assert abs(res.command.speed_mps) <= last + a_step + 1e-9, k
        last = abs(res.command.speed_mps)


@pytest.mark.slow
def test_default_car_never_needs_the_rule(track) -> None:
    cfg = RacestackConfig()
    planner = Planner(track, cfg.planner, cfg.curvature)
    run = run_method("cimpcc", planner, track, cfg.simulator, LoopOptions(laps=1))
    assert run.completed_laps == 1 and run.extra["recoveries"] == 0
    assert run.run_off_track_events == 0


@pytest.mark.slow
def test_identified_car_finishes_laps_on_map416_spinning_in_the_turns(shared_tracks) -> None:
    """Model mismatch: the planner's speeds exceed this car's grip (peak 0.62 g at the rear,
    map416's 0.9 m turns at the paper's v_low need about 0.8 g), so it spins; the rule
    brings it back every time and every excursion is counted, out lap included."""
    t = load_track(str(shared_tracks / "map416"))
    real_car = SimulatorSettings(vehicle=vehicle_preset("real_car_identified"))
    cfg = RacestackConfig(simulator=real_car)
    planner = Planner(t, cfg.planner, cfg.curvature)
    run = run_method("cimpcc", planner, t, cfg.simulator, LoopOptions(laps=2))
    assert run.completed_laps == 2, run.extra
    assert run.extra["recoveries"] > 0
    assert run.run_off_track_events >= sum(lap.off_track_events for lap in run.laps)


@pytest.mark.parametrize("kind", ["mpc", "tracker"])
def test_a_teleported_car_is_found_where_it_stands(track, kind) -> None:
    """A reset or a car placed back by hand moves it farther than any tick could: the planner
    searches the whole track again and races on from there (no 'car lost' recovery)."""
    settings = PlannerSettings()
    if kind == "tracker":
        ensure_artefacts(RACELINE, track, settings)
    planner = Planner(track, settings) if kind == "mpc" else RacelinePlanner(track, settings)
    for k in range(5):
        planner.step(*_pose_on(track, 2.0 + 0.1 * k, 0.0))
    far = 0.5 * track.length_m
    res = planner.step(*_pose_on(track, far, 0.0))
    assert res.status != RECOVERING, res.solver_status
    assert res.s_m == pytest.approx(far, abs=0.05) and abs(res.e_con_m) < 0.05
    res = planner.step(*_pose_on(track, far + 0.05, 0.0))
    assert res.status == SOLVED and planner.recovery.episodes == 0
