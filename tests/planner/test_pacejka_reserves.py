"""The identified car's reserves (issue #21): a minimum-time lap whose tyres stay short of their
peak and their ellipse, whose steering a slow servo can follow, and the tracker and cimpcc-line
command that invert that servo's lag. The gym car's laps and commands stay as they were."""

from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np
import pytest

from services.planner.mintime.model import DELTA, servo_reach, spatial_model
from services.planner.mintime.ocp import MinTimeLap, MinTimeSettings, solve_min_time
from services.planner.mintime.requests import line_request, raceline_request
from services.planner.mintime.store import cache_key
from services.planner.mpc.model import SlipModel, U
from services.planner.mpc.planner import Planner
from services.planner.raceline.planner import (
    JOIN_SPEED_MPS,
    SERVO_ALLOWANCE_S,
    RacelinePlanner,
    planner_timing,
)
from services.planner.raceline.tracker import ReferenceLap, Tracker, TrackerGains, TrackerTiming
from services.planner.recovery import handover_accel_mps2, ramps_from_rest
from shared.config.planner import PlannerSettings, RacelineSettings
from shared.config.vehicle import F1TENTH_GYM, REAL_CAR_IDENTIFIED
from shared.track import Track, load_track
from shared.vehicle.tyres import pacejka_peak_slip_rad, pacejka_slip_for_share

CAR = REAL_CAR_IDENTIFIED
RESERVES = MinTimeSettings(10.0, ds_m=0.2, slip_fraction=0.7, ellipse_fraction=0.9)


def circle_track(radius_m: float, half_width_m: float, spacing_m: float = 0.06) -> Track:
    """A counter-clockwise circle of constant width."""
    n = int(2 * math.pi * radius_m / spacing_m)
    th = np.arange(n) * 2 * math.pi / n
    xy = radius_m * np.column_stack([np.cos(th), np.sin(th)])
    return Track("circle", xy, np.full(n, half_width_m), np.full(n, half_width_m))


@pytest.fixture(scope="module")
def laps() -> tuple[MinTimeLap, MinTimeLap]:
    """The identified car on a 1.5 m circle: at its limit, and with the reserves."""
    track = circle_track(1.5, 0.3)
    return (
        solve_min_time(track, CAR, MinTimeSettings(10.0, ds_m=0.2)),
        solve_min_time(track, CAR, RESERVES),
    )


def test_only_a_slow_servo_has_a_reach() -> None:
    """The gym's 0.01 s servo meets its rate limit almost anywhere; the identified 0.158 s one
    cannot swing the wheels at 3.2 rad/s near an end stop."""
    assert servo_reach(F1TENTH_GYM) is None
    assert servo_reach(CAR) == pytest.approx(0.158)


def test_the_reserves_hold_at_every_node(laps: tuple[MinTimeLap, MinTimeLap]) -> None:
    """Slip within 0.7 of the peak, force within 0.9 of the ellipse, the servo's target
    within the steering limits; the reserves cost a little time, not more than 10 %."""
    limit, reserved = laps
    model = spatial_model(CAR)
    peak = (pacejka_peak_slip_rad(CAR, "front"), pacejka_peak_slip_rad(CAR, "rear"))
    for x, u in zip(reserved.states, reserved.inputs, strict=True):
        use_f, use_r, alpha_f, alpha_r = (float(v) for v in np.asarray(model.tyres(x, u)).ravel())
        assert abs(alpha_f) <= 0.7 * peak[0] + 1e-6
        assert abs(alpha_r) <= 0.7 * peak[1] + 1e-6
        assert max(use_f, use_r) <= 0.81 + 1e-6
        target = x[DELTA] + 0.158 * u[0]
        assert CAR.steering_min_rad - 1e-6 <= target <= CAR.steering_max_rad + 1e-6
    assert limit.lap_time_s < reserved.lap_time_s < 1.1 * limit.lap_time_s


def test_the_reserves_leave_other_tyres_and_their_cache_keys_alone() -> None:
    """Linear-saturated tyres keep their force past the peak: the reserves change nothing,
    not even the cache key (the gym car's stored laps stay valid); Pacejka laps differ."""
    track = circle_track(1.5, 0.3)
    plain = MinTimeSettings(10.0, ds_m=0.2)
    assert cache_key(track, F1TENTH_GYM, RESERVES) == cache_key(track, F1TENTH_GYM, plain)
    assert cache_key(track, CAR, RESERVES) != cache_key(track, CAR, plain)
    assert spatial_model(F1TENTH_GYM, 0.7, 0.9).ellipse_use_max == 1.0
    with pytest.raises(ValueError, match="slip_fraction"):
        MinTimeSettings(slip_fraction=0.0)
    with pytest.raises(ValueError, match="ellipse_fraction"):
        MinTimeSettings(ellipse_fraction=1.5)


def test_the_planners_lines_carry_the_configured_reserves() -> None:
    """cimpcc-line's line and the raceline's ask for the configured reserves; the limit does
    not (it is the car's own)."""
    settings = PlannerSettings()
    line = line_request(settings, CAR).settings
    race = raceline_request(settings, CAR).settings
    assert (line.slip_fraction, line.ellipse_fraction) == (
        settings.cimpcc_line.slip_fraction, settings.cimpcc_line.ellipse_fraction)
    assert (race.slip_fraction, race.ellipse_fraction) == (
        settings.raceline.min_time_slip_fraction, settings.raceline.min_time_ellipse_fraction)


def ramp_plan(rate_radps: float) -> ReferenceLap:
    """A 10 m circle at 2 m/s whose planned steering grows `rate_radps` per second (from the
    start of the lap)."""
    line = circle_track(10.0, 1.0, 0.05)
    n = line.n_points
    tangent = line.tangent_unit()
    yaw = np.unwrap(np.arctan2(tangent[:, 1], tangent[:, 0]))
    t = np.asarray(line.s_m) / 2.0
    return ReferenceLap(line, np.asarray(line.s_m), yaw, np.full(n, 0.1), np.full(n, 2.0),
                        np.zeros(n), rate_radps * t, t, line.length_m / 2.0)


def test_the_tracker_leads_a_slow_servo_by_its_time_constant() -> None:
    """On the plan, the command is the planned steering after the pure delays plus tau times
    its rate: the servo's first-order lag then brings the wheels onto the plan."""
    plan = ramp_plan(0.4)
    gains = TrackerGains()
    lagged = Tracker(plan, TrackerTiming(0.05, 0.01, 0.03, 0.158), gains, 4.755, 19.02)
    plain = Tracker(plan, TrackerTiming(0.05, 0.01, 0.03), gains, 4.755, 19.02)
    s = 5.0
    x, y = plan.line.point_at(s)
    yaw = float(plan.at("yaw", s))
    a = lagged.command(float(x), float(y), yaw, s_hint_m=s)
    b = plain.command(float(x), float(y), yaw, s_hint_m=s)
    assert a.steering_rad - b.steering_rad == pytest.approx(0.158 * 0.4, rel=1e-3)
    with pytest.raises(ValueError):
        TrackerTiming(0.05, 0.01, 0.03, -0.1)


def test_planner_timing_inverts_only_a_slow_servo() -> None:
    """The gym car keeps its configured delays; the identified car's tracker starts its window
    the gym servo's share earlier and inverts its own servo's lag."""
    settings = PlannerSettings()
    gym = planner_timing(settings, F1TENTH_GYM)
    assert gym == planner_timing(settings)
    assert gym.servo_time_constant_s == 0.0
    ident = planner_timing(settings, CAR)
    assert ident.servo_time_constant_s == pytest.approx(0.158)
    assert ident.steering_delay_s == pytest.approx(
        settings.raceline.steering_delay_s - SERVO_ALLOWANCE_S)


def test_cimpcc_line_leads_a_slow_servo_from_its_plan() -> None:
    """The command's steering is the plan's first, led by tau times the plan's rate, within the
    bounds; without a slow servo (the gym car, the paper's methods) it is the plan's own."""
    horizon, dt = 10, 0.05
    w = np.zeros(64)
    u1 = slice(10, 13)
    w[u1][U.DELTA] = 0.1
    fake = SimpleNamespace(
        _servo_tau=0.158, settings=SimpleNamespace(dt_s=dt),
        problem=SimpleNamespace(horizon=horizon, input_index=lambda k: u1),
        _u_lo=np.array([0.0, -0.4, 0.0]), _u_hi=np.array([5.0, 0.4, 5.0]),
    )
    u0 = np.array([3.0, 0.05, 3.0])
    lead = Planner._servo_lead(fake, u0, w)
    assert lead == pytest.approx(0.05 + 0.158 * 0.05 / dt)
    w[u1][U.DELTA] = 0.4
    assert Planner._servo_lead(fake, u0, w) == pytest.approx(0.4)  # the bound
    fake._servo_tau = None
    assert Planner._servo_lead(fake, u0, w) == pytest.approx(0.05)


def test_the_inverse_magic_formula_gives_the_share_back() -> None:
    """The slip for a share of the peak, fed to the curve, gives that share; 1: the peak."""
    b, c, _d, e = CAR.pacejka_front
    share = np.array([0.1, 0.5, 0.9, 1.0])
    alpha = pacejka_slip_for_share(CAR, "front", share)
    x = b * alpha
    np.testing.assert_allclose(np.sin(c * np.arctan(x - e * (x - np.arctan(x)))), share,
                               atol=1e-9)
    assert alpha[-1] == pytest.approx(pacejka_peak_slip_rad(CAR, "front"))


def test_the_slip_model_knows_the_pacejka_cars_understeer_near_its_limit() -> None:
    """cimpcc-line's near-limit slip model fits the magic formula's steady state: within 3 %
    of its understeer gradient at 0.9 of the limit; the gym car's fit is unchanged."""
    model = SlipModel.for_vehicle(CAR, near_limit=True)
    assert model.understeer_growth_s6pm3 > 0.0
    g = 9.81
    a_y = 0.9 * 0.618 * g
    true_k = (pacejka_slip_for_share(CAR, "front", a_y / (0.65 * g))
              - pacejka_slip_for_share(CAR, "rear", a_y / (0.618 * g))) / a_y
    fitted = model.understeer_s2pm + model.understeer_growth_s6pm3 * a_y**2
    assert fitted == pytest.approx(true_k, rel=0.03)
    assert SlipModel.for_vehicle(CAR) == SlipModel(
        model.wheelbase_m, model.understeer_s2pm, model.rear_slip_s2pm)


def test_peaky_tyres_ramp_gently_and_join_the_line_slowly() -> None:
    """The identified car's hand-over leaves 30 % of its friction circle for steering and the
    raceline joins its line at JOIN_SPEED_MPS from a standing start; the gym car's start is
    as it was (its full a_max, no join)."""
    assert handover_accel_mps2(F1TENTH_GYM) == F1TENTH_GYM.accel_max_mps2
    assert handover_accel_mps2(CAR) == pytest.approx(0.7 * 0.618 * 9.81)
    assert ramps_from_rest(CAR) and not ramps_from_rest(F1TENTH_GYM)
    track = load_track("paperlike")
    planner = RacelinePlanner(track, PlannerSettings(raceline=RacelineSettings(
        line="min_curvature")), vehicle=CAR)
    line = planner.raceline.reference.line
    x, y = line.point_at(1.0)
    h = float(line.heading_at(1.0))
    off = 0.3  # the rear axle 0.3 m left of the line, aligned with it
    res = planner.step(float(x) - off * math.sin(h) - CAR.lr_m * math.cos(h),
                       float(y) + off * math.cos(h) - CAR.lr_m * math.sin(h), h)
    assert res.command.speed_mps <= JOIN_SPEED_MPS
    gym = RacelinePlanner(track, PlannerSettings(raceline=RacelineSettings(
        line="min_curvature")), vehicle=F1TENTH_GYM)
    assert not gym._joining and not gym._handover.active


def test_with_a_slow_servo_the_feedback_leads_the_error_by_its_lag() -> None:
    """The second command of a slow-servo tracker feeds back the look-ahead error predicted
    tau ahead from its change over one period; without a slow servo, the error itself."""
    plan = ramp_plan(0.0)
    timing = TrackerTiming(0.05, 0.01, 0.03, 0.158)
    lagged = Tracker(plan, timing, TrackerGains(), 4.755, 19.02)
    s = 5.0
    x, y = plan.line.point_at(s)
    h = float(plan.line.heading_at(s))
    yaw = float(plan.at("yaw", s))
    first = lagged.command(float(x), float(y), yaw, s_hint_m=s)
    right = (float(x) + 0.01 * math.sin(h), float(y) - 0.01 * math.cos(h))
    second = lagged.command(*right, yaw, s_hint_m=s)
    k_e = TrackerGains().k_lateral_radpm
    e = second.e_m - first.e_m
    assert e == pytest.approx(0.01, abs=1e-3)
    assert second.steering_rad - first.steering_rad == pytest.approx(
        k_e * e * (1.0 + 0.158 / 0.05), rel=0.05)
    lagged.reset()
    again = lagged.command(*right, yaw, s_hint_m=s)  # forgotten: no rate yet
    assert again.steering_rad - first.steering_rad == pytest.approx(k_e * e, rel=0.05)


def test_joining_the_line_slowly_steers_for_the_speed_it_joins_at() -> None:
    """Held at JOIN_SPEED_MPS below its line's speed, the raceline steers the line at that
    speed (``_slow_steering``), not the line's own steering for its own speed: with that the
    identified car ran off the inside of map416's first bends in its out lap."""
    track = load_track("paperlike")
    planner = RacelinePlanner(track, PlannerSettings(raceline=RacelineSettings(
        line="min_curvature")), vehicle=CAR)
    ref = planner.raceline.reference
    s = float(ref.s_m[int(np.argmax(ref.v_mps))])  # the fastest point: far above the join
    assert float(ref.at("v", s)) > JOIN_SPEED_MPS + 0.5
    line = ref.line
    x, y = line.point_at(s)
    h = float(line.heading_at(s))
    off = 0.2  # the rear axle 0.2 m left of the line: joining
    pose = (float(x) - off * math.sin(h) - CAR.lr_m * math.cos(h),
            float(y) + off * math.cos(h) - CAR.lr_m * math.sin(h), h)
    asked = []

    def slow(cx, cy, yaw, s_m, speed_mps, line_rad, slope=0.0):
        asked.append((speed_mps, line_rad))
        return 0.0123

    planner._slow_steering = slow
    planner._s_line = s
    planner._join_pending = False  # the line directly, no blended join (``raceline.join``)
    res = planner.step(*pose)
    assert planner._joining and res.command.speed_mps <= JOIN_SPEED_MPS
    assert asked == [(res.command.speed_mps, pytest.approx(asked[0][1]))]
    assert res.command.steering_rad == pytest.approx(0.0123)


def test_a_grip_adapted_car_steers_for_the_speed_it_is_held_at() -> None:
    """The grip adaptation (``speed_scale`` < 1) holds the car below its line's speed; it
    steers the line at that speed (``_slow_steering``), not the line's own steering for the
    line's speed: with that, a car whose adaptation fired turned in too far (gen-1 and gen-7
    with the identified car: 12 and 15 off-track events, issue #21)."""
    track = load_track("paperlike")
    planner = RacelinePlanner(track, PlannerSettings(raceline=RacelineSettings(
        line="min_curvature", start_speed_scale=1.0)),  # the line's own speeds at once
        vehicle=F1TENTH_GYM)
    ref = planner.raceline.reference
    s = float(ref.s_m[int(np.argmax(ref.v_mps))])
    x, y = ref.line.point_at(s)
    h = float(ref.line.heading_at(s))
    lr = F1TENTH_GYM.lr_m
    pose = (float(x) - lr * math.cos(h), float(y) - lr * math.sin(h), h)  # on the line
    asked = []

    def slow(cx, cy, yaw, s_m, speed_mps, line_rad, slope=0.0):
        asked.append(speed_mps)
        return 0.0123

    planner._slow_steering = slow
    planner._s_line = s
    planner._join_pending = False
    res = planner.step(*pose)  # at the line's own speed: its own steering
    assert not asked and res.command.steering_rad != pytest.approx(0.0123)
    planner.speed_scale = 0.8
    res = planner.step(*pose)
    # the speed asked of it: its plan at the scale, without the speed loop's lead
    # (``_steering_speed``), below the command that carries the lead
    assert len(asked) == 1 and asked[0] == pytest.approx(0.8 * float(ref.at("v", s)), rel=0.02)
    assert asked[0] < res.command.speed_mps
    assert res.command.steering_rad == pytest.approx(0.0123)
    assert res.command.speed_mps < 0.85 * float(ref.at("v", s)) + 0.5


def test_a_slow_servo_joins_its_line_at_a_gentler_slope(monkeypatch) -> None:
    """Joining at JOIN_SPEED_MPS, a car with a slow servo moves across at
    ``SLOW_SERVO_JOIN_SHARE`` of the lateral speed of the line's top speed: a longer blend
    for the same gap (its servo lags the blend's turn back onto the line)."""
    import services.planner.raceline.planner as rp

    assert 0.0 < rp.SLOW_SERVO_JOIN_SHARE < 1.0
    track = load_track("paperlike")
    lengths = {}
    for share in (1.0, rp.SLOW_SERVO_JOIN_SHARE):
        monkeypatch.setattr(rp, "SLOW_SERVO_JOIN_SHARE", share)
        planner = RacelinePlanner(track, PlannerSettings(raceline=RacelineSettings(
            line="min_curvature")), vehicle=CAR)
        assert planner._slow_servo
        ref = planner.raceline.reference
        s = float(ref.s_m[int(np.argmax(ref.v_mps))])  # the fastest point: a straight
        line = ref.line
        x, y = line.point_at(s)
        h = float(line.heading_at(s))
        off = 0.3  # the rear axle 0.3 m left of the line, at rest: a slow join
        planner.step(float(x) - off * math.sin(h) - CAR.lr_m * math.cos(h),
                     float(y) + off * math.cos(h) - CAR.lr_m * math.sin(h), h)
        assert planner._joining and planner._join is not None
        lengths[share] = planner._join.length_m
    assert lengths[rp.SLOW_SERVO_JOIN_SHARE] == pytest.approx(
        lengths[1.0] / rp.SLOW_SERVO_JOIN_SHARE, rel=0.05)
