"""An oversteering car's line keeps its rear short of its ellipse
(``MinTimeSettings.rear_ellipse_fraction``, ``requests.rear_ellipse_fraction``, ``[planner.raceline]
min_time_oversteer_balance`` and ``min_time_oversteer_rear_share``; issue #21): a car whose rear
grips less than its front spins when its line puts the rear at its ellipse, so its line leaves
the rear a share of it; every other car keeps its line and its stored key."""

from __future__ import annotations

import numpy as np
import pytest

import services.planner.mintime.store as store
from services.planner.mintime.model import spatial_model
from services.planner.mintime.ocp import MinTimeSettings, solve_min_time
from services.planner.mintime.requests import (
    line_request,
    oversteers,
    raceline_request,
    rear_ellipse_fraction,
)
from shared.config.planner import PlannerSettings, RacelineSettings
from shared.config.vehicle import F1TENTH_GYM, REAL_CAR_IDENTIFIED
from shared.vehicle.tyres import axle_peak_friction
from tests.planner.test_mintime import circle_track

#: The identified car with its rear's D cut to 0.8 of its front's: an oversteering car.
B, C, D, E = REAL_CAR_IDENTIFIED.pacejka_rear
OVERSTEER = REAL_CAR_IDENTIFIED.model_copy(
    update={"pacejka_rear": (B, C, 0.8 * REAL_CAR_IDENTIFIED.pacejka_front[2], E)})


def _balance(car) -> float:
    return axle_peak_friction(car, "rear") / axle_peak_friction(car, "front")


def test_only_a_car_whose_rear_grips_less_than_the_balance_gets_a_rear_share() -> None:
    o = RacelineSettings()
    assert _balance(REAL_CAR_IDENTIFIED) == pytest.approx(0.951, abs=1e-3)
    assert rear_ellipse_fraction(o, REAL_CAR_IDENTIFIED) is None  # 0.95 >= 0.9
    assert _balance(OVERSTEER) == pytest.approx(0.8)
    assert rear_ellipse_fraction(o, OVERSTEER) == pytest.approx(
        o.min_time_ellipse_fraction * o.min_time_oversteer_rear_share)
    assert rear_ellipse_fraction(o, F1TENTH_GYM) is None  # no Pacejka tyres
    assert rear_ellipse_fraction(o) is None  # the gym's car
    off = RacelineSettings(min_time_oversteer_balance=0.0)
    assert rear_ellipse_fraction(off, OVERSTEER) is None
    # the raceline's line (flying and out lap) asks for it
    settings = PlannerSettings()
    for out_lap in (False, True):
        req = raceline_request(settings, OVERSTEER, out_lap=out_lap).settings
        assert req.rear_ellipse_fraction == rear_ellipse_fraction(o, OVERSTEER)
        assert raceline_request(settings, REAL_CAR_IDENTIFIED,
                                out_lap=out_lap).settings.rear_ellipse_fraction is None


def test_cimpcc_lines_line_gives_an_oversteering_cars_rear_the_same_share() -> None:
    """``cimpcc-line`` contours a minimum-time line too: an oversteering car's rear keeps
    the raceline's share of that line's own ellipse (the varied family's tuning cells: 3 ->
    15 of 18 clean, 135 -> 0 spins; README). Every other car's line is as before."""
    settings = PlannerSettings()
    o, line = settings.raceline, settings.cimpcc_line
    assert oversteers(o, OVERSTEER) and not oversteers(o, REAL_CAR_IDENTIFIED)
    assert not oversteers(o, F1TENTH_GYM) and not oversteers(o)
    assert not oversteers(RacelineSettings(min_time_oversteer_balance=0.0), OVERSTEER)
    assert line_request(settings, OVERSTEER).settings.rear_ellipse_fraction == pytest.approx(
        line.ellipse_fraction * o.min_time_oversteer_rear_share)
    for car in (REAL_CAR_IDENTIFIED, F1TENTH_GYM, None):
        assert line_request(settings, car).settings.rear_ellipse_fraction is None


def test_the_other_cars_keep_their_keys_and_bad_shares_are_rejected() -> None:
    track = circle_track(3.0, 0.3)
    plain = MinTimeSettings(ds_m=0.2, slip_fraction=0.8, ellipse_fraction=0.95)
    rear = MinTimeSettings(ds_m=0.2, slip_fraction=0.8, ellipse_fraction=0.95,
                           rear_ellipse_fraction=0.855)
    # a lap stored before the setting existed: the same key as the setting left unset
    legacy = {k: v for k, v in plain.__dict__.items() if k != "rear_ellipse_fraction"}
    assert store.cache_key(track, OVERSTEER, MinTimeSettings(**legacy)) == store.cache_key(
        track, OVERSTEER, plain)
    assert store.cache_key(track, OVERSTEER, rear) != store.cache_key(track, OVERSTEER, plain)
    # no effect on tyres without a peak: nor on their key
    assert store.cache_key(track, F1TENTH_GYM, rear) == store.cache_key(
        track, F1TENTH_GYM, plain)
    assert spatial_model(F1TENTH_GYM, 0.8, 0.95, rear_ellipse_fraction=0.855
                         ).axle_use_max(rear=True) == 1.0
    for bad in (0.0, 1.5, float("nan")):
        with pytest.raises(ValueError, match="rear_ellipse_fraction"):
            MinTimeSettings(rear_ellipse_fraction=bad)
    with pytest.raises(ValueError):
        RacelineSettings(min_time_oversteer_rear_share=0.0)


def test_an_oversteering_cars_rear_keeps_its_own_share_of_the_ellipse() -> None:
    """R = 1.5 m circle: without a share of its own the rear is the limit, at 0.95^2 of its
    ellipse (the front far below its own); with it, the rear stays within 0.855^2, at a
    little time."""
    track = circle_track(1.5, 0.3)
    base = {"v_max_mps": 10.0, "ds_m": 0.2, "slip_fraction": 0.8, "ellipse_fraction": 0.95}
    free = solve_min_time(track, OVERSTEER, MinTimeSettings(**base))
    kept = solve_min_time(track, OVERSTEER,
                          MinTimeSettings(**base, rear_ellipse_fraction=0.855))
    assert free.success and kept.success
    model = spatial_model(OVERSTEER, 0.8, 0.95)

    def uses(lap) -> np.ndarray:
        return np.array([np.asarray(model.tyres(x, u)).ravel()[:2]
                         for x, u in zip(lap.states, lap.inputs, strict=True)])

    u_free, u_kept = uses(free), uses(kept)
    assert u_free[:, 1].max() == pytest.approx(0.95**2, abs=2e-3)  # the rear is the limit
    assert u_kept[:, 1].max() <= 0.855**2 + 1e-4
    assert u_free[:, 0].max() < 0.8 * 0.95**2  # the front has grip to spare
    assert free.lap_time_s < kept.lap_time_s < 1.1 * free.lap_time_s
