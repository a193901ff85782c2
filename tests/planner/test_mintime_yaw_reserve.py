"""The high-speed reserve's yaw bound, rear share and start speed
(``MinTimeSettings.reserve_yaw_pole_per_s``, ``reserve_rear_fraction``, ``reserve_from_mps``;
``[planner.raceline] min_time_reserve_*``; issue #21): a line that brakes into a bend from
speed keeps the car's yaw from diverging faster than the bound, its rear inside its own share
of the ellipse, and a line capped at the paper's 4.18 m/s stays the line (and key) of before."""

from __future__ import annotations

import numpy as np
import pytest

import services.planner.mintime.store as store
from services.planner.mintime.ocp import MinTimeSettings, solve_min_time
from services.planner.mintime.requests import min_time_settings
from shared.config.planner import RacelineSettings
from shared.config.vehicle import DynamicVehicleParams
from shared.vehicle.yaw_stability import yaw_pole_per_s
from tests.planner.test_mintime import circle_track
from tests.planner.test_overtake import stadium

CAR = DynamicVehicleParams()


def _fast(**kwargs) -> MinTimeSettings:
    return MinTimeSettings(v_max_mps=10.0, ds_m=0.25, reserve_speed_mps=4.18,
                           reserve_from_mps=1.0, reserve_width_mps=1.0, **kwargs)


@pytest.fixture(scope="module")
def braking_laps():
    """A stadium with 14 m straights into R = 1.5 m bends: the lap brakes from 8-9 m/s."""
    track = stadium(straight_m=14.0, radius_m=1.5, half_width_m=0.5, spacing_m=0.1)
    free = solve_min_time(track, CAR, _fast(reserve_fraction=1.0))
    bounded = solve_min_time(track, CAR, _fast(reserve_fraction=1.0, reserve_yaw_pole_per_s=1.0))
    return free, bounded


def _poles(lap) -> np.ndarray:
    return np.array([yaw_pole_per_s(CAR, v, a) for v, a in zip(lap.v_mps, lap.inputs[:, 1],
                                                              strict=True)])


def test_the_bound_keeps_the_yaw_from_diverging_faster_than_it_braking_into_a_bend(
        braking_laps) -> None:
    free, bounded = braking_laps
    assert free.success and bounded.success
    assert free.v_mps.max() > 7.5  # fast enough for braking to matter
    assert _poles(free).max() > 4.0  # the free lap brakes the car unstable
    assert _poles(bounded).max() <= 1.0 + 1e-3
    assert bounded.lap_time_s > free.lap_time_s  # it costs time ...
    assert bounded.lap_time_s < 1.1 * free.lap_time_s  # ... a little


def test_the_rear_keeps_its_own_share_of_the_ellipse() -> None:
    """R = 1.5 m circle, the reserve from 1 m/s: the rear within 0.8 of its ellipse's
    radius (use <= 0.64), the front free to use more."""
    from services.planner.mintime.model import spatial_model

    cfg = _fast(reserve_fraction=1.0, reserve_rear_fraction=0.8)
    lap = solve_min_time(circle_track(1.5, 0.3), CAR, cfg)
    m = spatial_model(CAR, reserve=(1.0, 1.0, 1.0), rear_reserve_fraction=0.8)
    use = np.array([np.asarray(m.tyres(x, u)).ravel()[:2]
                    for x, u in zip(lap.states, lap.inputs, strict=True)])
    assert lap.success
    assert use[:, 1].max() <= 0.64 + 1e-4
    assert use[:, 0].max() > 0.7
    both = solve_min_time(circle_track(1.5, 0.3), CAR, _fast(reserve_fraction=0.8))
    assert lap.lap_time_s < both.lap_time_s  # the front's share is time


def test_capped_lines_keep_their_key_and_new_reserves_enter_the_key_only_when_active() -> None:
    track = circle_track(3.0, 0.3)
    plain = MinTimeSettings(v_max_mps=4.18, ds_m=0.2)
    capped = MinTimeSettings(v_max_mps=4.18, ds_m=0.2, reserve_speed_mps=4.18,
                             reserve_yaw_pole_per_s=2.0, reserve_rear_fraction=0.8,
                             reserve_from_mps=1.0)
    assert store.cache_key(track, CAR, capped) == store.cache_key(track, CAR, plain)
    base = _fast()
    for change in ({"reserve_yaw_pole_per_s": 2.0}, {"reserve_rear_fraction": 0.8},
                   {"reserve_from_mps": 2.0}):
        other = MinTimeSettings(**{**base.__dict__, **change})
        assert store.cache_key(track, CAR, other) != store.cache_key(track, CAR, base)
    # a key stored before these settings existed: the same as all three left unset
    legacy = MinTimeSettings(v_max_mps=10.0, ds_m=0.25, reserve_speed_mps=4.18,
                             reserve_width_mps=1.0)
    assert legacy.reserve_start_mps == 4.18
    assert _fast().reserve_start_mps == 1.0


def test_the_raceline_settings_reach_the_problem() -> None:
    o = RacelineSettings(v_max_mps=10.0, min_time_reserve_yaw_pole_per_s=3.0,
                         min_time_reserve_rear_fraction=0.7, min_time_reserve_from_mps=2.0)
    s = min_time_settings(o)
    assert (s.reserve_yaw_pole_per_s, s.reserve_rear_fraction, s.reserve_from_mps) == (
        3.0, 0.7, 2.0)


def test_bad_values_are_rejected() -> None:
    for kwargs in ({"reserve_yaw_pole_per_s": -1.0}, {"reserve_rear_fraction": 0.0},
                   {"reserve_from_mps": -0.5}, {"reserve_rear_fraction": float("nan")}):
        with pytest.raises(ValueError):
            MinTimeSettings(**kwargs)
