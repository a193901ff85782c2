"""The minimum-time lap's high-speed reserve (``MinTimeSettings.reserve_speed_mps``,
``[planner.raceline] min_time_reserve_*``; issue #21): above a speed each friction-limited
axle uses at most a share of its friction ellipse, and at or below it the problem, its lap
and its cache key are those of before."""

from __future__ import annotations

import math

import numpy as np
import pytest

import services.planner.mintime.store as store
from services.planner.mintime.model import spatial_model
from services.planner.mintime.ocp import MinTimeSettings, solve_min_time
from services.planner.mintime.requests import min_time_settings, raceline_request
from shared.config.planner import PlannerSettings, RacelineSettings
from shared.config.vehicle import DynamicVehicleParams
from tests.planner.test_mintime import circle_track, steady_cornering_speed

CAR = DynamicVehicleParams()


def test_the_bound_falls_smoothly_from_the_whole_ellipse_to_the_reserves_share() -> None:
    m = spatial_model(CAR, reserve=(6.0, 2.0, 0.9))
    assert m.reserve == (6.0, 2.0, 0.9)
    assert float(m.use_bound(5.0)) == 1.0 and float(m.use_bound(6.0)) == 1.0
    assert float(m.use_bound(7.0)) == pytest.approx(1.0 - 0.5 * (1.0 - 0.81))
    assert float(m.use_bound(8.0)) == pytest.approx(0.81)
    assert float(m.use_bound(12.0)) == pytest.approx(0.81)
    v = np.linspace(5.5, 8.5, 31)
    b = np.array([float(m.use_bound(x)) for x in v])
    assert np.all(np.diff(b) <= 1e-12)  # monotone
    assert spatial_model(CAR).use_bound(9.0) == 1.0  # no reserve: the ellipse
    gym = DynamicVehicleParams(tyre_model="linear")  # no friction limit: nothing to reserve
    assert spatial_model(gym, reserve=(6.0, 2.0, 0.9)).reserve is None


def test_a_reserved_circle_corners_on_that_share_of_the_grip() -> None:
    """R = 1.5 m (about 3.9 m/s at the limit), the reserve full from 2.5 m/s: the lap is
    the steady turn of a car with 0.9 of the friction, within the OCP's 0.5 %."""
    track = circle_track(1.5, 0.3)
    cfg = MinTimeSettings(v_max_mps=10.0, ds_m=0.2, reserve_speed_mps=2.0,
                          reserve_width_mps=0.5, reserve_fraction=0.9)
    lap = solve_min_time(track, CAR, cfg)
    radius = float(np.hypot(lap.x_m, lap.y_m).mean())
    v_hand = steady_cornering_speed(CAR.model_copy(update={"mu": 0.9 * CAR.mu}), radius)
    assert lap.success
    assert lap.v_mps.mean() == pytest.approx(v_hand, rel=5e-3)
    assert v_hand < 0.96 * steady_cornering_speed(CAR, radius)


def test_an_inactive_reserve_keeps_the_problem_and_the_key() -> None:
    track = circle_track(3.0, 0.3)
    plain = MinTimeSettings(v_max_mps=4.18, ds_m=0.2)
    at_cap = MinTimeSettings(v_max_mps=4.18, ds_m=0.2, reserve_speed_mps=4.18)
    above = MinTimeSettings(v_max_mps=4.18, ds_m=0.2, reserve_speed_mps=6.0,
                            reserve_fraction=0.5)
    assert not at_cap.reserve_active and not above.reserve_active
    key = store.cache_key(track, CAR, plain)
    assert store.cache_key(track, CAR, at_cap) == key == store.cache_key(track, CAR, above)
    fast = MinTimeSettings(v_max_mps=10.0, ds_m=0.2)
    fast_reserved = MinTimeSettings(v_max_mps=10.0, ds_m=0.2, reserve_speed_mps=4.18)
    assert fast_reserved.reserve_active
    assert store.cache_key(track, CAR, fast_reserved) != store.cache_key(track, CAR, fast)
    gym = DynamicVehicleParams(tyre_model="linear")  # no friction: the reserve is no change
    assert store.cache_key(track, gym, fast_reserved) == store.cache_key(track, gym, fast)


def test_the_raceline_passes_its_reserve_and_keeps_the_cap_lines_key() -> None:
    o = RacelineSettings(min_time_reserve_speed_mps=5.0, min_time_reserve_fraction=0.85,
                         min_time_reserve_width_mps=1.5, v_max_mps=10.0)
    s = min_time_settings(o)
    assert (s.reserve_speed_mps, s.reserve_fraction, s.reserve_width_mps) == (5.0, 0.85, 1.5)
    assert s.reserve_active
    # the default settings at the paper's 4.18 m/s cap: the key of a lap without a reserve
    track = circle_track(3.0, 0.3)
    car, settings = raceline_request(PlannerSettings())
    plain = MinTimeSettings(v_max_mps=settings.v_max_mps, ds_m=settings.ds_m,
                            margin_m=settings.margin_m)
    assert store.cache_key(track, car, settings) == store.cache_key(track, car, plain)


def test_bad_reserves_are_rejected() -> None:
    for kwargs in ({"reserve_speed_mps": 0.0}, {"reserve_fraction": 0.0},
                   {"reserve_width_mps": 0.0}, {"reserve_speed_mps": math.nan}):
        with pytest.raises(ValueError):
            MinTimeSettings(**kwargs)


def test_the_reserves_margin_keeps_the_footprint_further_inside_at_speed() -> None:
    """``reserve_margin_m``: R = 3 m, the tyres allow about 5.4 m/s, the reserve full from
    2.5 m/s: the footprint keeps the margin plus 5 cm from the inner wall (not just the
    margin, as the plain lap does)."""
    track = circle_track(3.0, 0.3)
    cfg = MinTimeSettings(v_max_mps=10.0, ds_m=0.2, reserve_speed_mps=2.0,
                          reserve_width_mps=0.5, reserve_fraction=1.0, reserve_margin_m=0.05)
    lap = solve_min_time(track, CAR, cfg)
    assert lap.success and lap.v_mps.min() > 2.5
    assert lap.min_clearance_m == pytest.approx(0.02 + 0.05, abs=3e-3)


def test_the_reserves_steering_cost_is_in_the_objective_above_its_speed_only() -> None:
    """``reserve_steering_weight_s`` k: the objective gains ``k h sum S(v) (sv /
    sv_max)^2`` at the same decision vector; with every speed below ``reserve_speed_mps``
    nothing."""
    import casadi as ca

    from services.planner.mintime.nlp import make_grid, transcribe
    from services.planner.mintime.track import reference_line

    track = circle_track(3.0, 0.3)
    grid = make_grid(reference_line(track), CAR, 0.5)
    m = spatial_model(CAR)
    plain = transcribe(m, CAR, grid, 10.0, 1.0, 0.02)
    costly = transcribe(m, CAR, grid, 10.0, 1.0, 0.02, (2.0, 0.5, 0.1, 0.0))
    n_z = plain.nlp["x"].shape[0]
    rng = np.random.default_rng(0)
    z = rng.uniform(0.2, 0.8, n_z)  # scaled: speeds 2-8 m/s, some steering rate everywhere
    f_plain = ca.Function("f", [plain.nlp["x"]], [plain.nlp["f"]])
    f_costly = ca.Function("f", [costly.nlp["x"]], [costly.nlp["f"]])
    assert float(f_costly(z)) > float(f_plain(z))
    slow = transcribe(m, CAR, grid, 10.0, 1.0, 0.02, (20.0, 0.5, 0.1, 0.0))
    f_slow = ca.Function("f", [slow.nlp["x"]], [slow.nlp["f"]])
    assert float(f_slow(z)) == pytest.approx(float(f_plain(z)), rel=1e-12)


def test_the_default_reserve_acts_at_ten_metres_per_second_only() -> None:
    """``[planner.raceline]``'s default reserve acts on lines capped above the paper's
    4.18 m/s: capped there, the raceline's line is the line of before (its cache key); at
    --v-max 10 it is on, at every speed of the line, with the whole ellipse for the front,
    0.8 of it for the rear, the yaw bound, the steering cost and the margin."""
    o = RacelineSettings()
    assert o.min_time_reserve_speed_mps == 4.18
    assert not min_time_settings(o).reserve_active
    fast = min_time_settings(o.model_copy(update={"v_max_mps": 10.0}))
    assert fast.reserve_active and fast.reserve_start_mps == 0.0
    assert (fast.reserve_fraction, fast.reserve_rear_fraction, fast.reserve_yaw_pole_per_s,
            fast.reserve_steering_weight_s, fast.reserve_margin_m) == (1.0, 0.8, 2.0, 0.1, 0.1)
