"""The minimum-time lap: hand checks on circles, the simulator's equations, errors, the cache."""

from __future__ import annotations

import math

import casadi as ca
import numpy as np
import pytest

import services.planner.mintime.store as store
from services.planner.mintime.model import corner_offset, point_mass_speed, spatial_model
from services.planner.mintime.ocp import MinTimeError, MinTimeLap, MinTimeSettings, solve_min_time
from services.planner.mintime.track import reference_line, windowed_min
from services.simulator.dynamics import SingleTrackModel
from shared.config.vehicle import DynamicVehicleParams
from shared.track import Track
from shared.vehicle import CASADI_OPS, GRAVITY_MPS2, make_dynamic_derivatives

CAR = DynamicVehicleParams()
MU_G = CAR.mu * GRAVITY_MPS2


def circle_track(radius_m: float, half_width_m: float, spacing_m: float = 0.06) -> Track:
    """A counter-clockwise circle of constant width (left turns: kappa = +1/R)."""
    n = int(2 * math.pi * radius_m / spacing_m)
    th = np.arange(n) * 2 * math.pi / n
    xy = radius_m * np.column_stack([np.cos(th), np.sin(th)])
    return Track("circle", xy, np.full(n, half_width_m), np.full(n, half_width_m))


@pytest.fixture(scope="module")
def capped_lap() -> MinTimeLap:
    """R = 3 m: the tyres would allow ~5 m/s, so the 4.18 m/s cap binds all the way."""
    return solve_min_time(circle_track(3.0, 0.3), CAR, MinTimeSettings(v_max_mps=4.18, ds_m=0.2))


@pytest.fixture(scope="module")
def friction_lap() -> MinTimeLap:
    """R = 1.5 m, no binding cap: the friction ellipse limits the speed."""
    return solve_min_time(circle_track(1.5, 0.3), CAR, MinTimeSettings(v_max_mps=10.0, ds_m=0.2))


def steady_cornering_speed(p: DynamicVehicleParams, radius_m: float) -> float:
    """Hand check, independent of the OCP: the fastest steady turn of radius `radius_m` [m].

    Steady state of the simulator's equations on a circle: ``v' = beta' = r' = 0`` with
    ``r = v / R``; both axles inside their friction ellipses; maximise v over (v, beta,
    delta, a).
    """
    v, beta, delta, a = (ca.SX.sym(n) for n in ("v", "beta", "delta", "a"))
    d = make_dynamic_derivatives(p, CASADI_OPS, saturate=False)(v, beta, v / radius_m, delta, a)
    use = [(ax.fx_n**2 + ax.fy_n**2) / (p.mu * ax.fz_n) ** 2 for ax in (d.front, d.rear)]
    nlp = {"x": ca.vertcat(v, beta, delta, a), "f": -v,
           "g": ca.vertcat(d.dv, d.dbeta, d.dr, *use)}
    solver = ca.nlpsol("steady", "ipopt", nlp, {"ipopt.print_level": 0, "print_time": False,
                                                 "ipopt.sb": "yes"})
    sol = solver(x0=[3.0, 0.0, 0.1, 0.0], lbx=[0.5, -0.5, p.steering_min_rad, -9.0],
                 ubx=[20.0, 0.5, p.steering_max_rad, 9.0], lbg=[0, 0, 0, -1, -1],
                 ubg=[0, 0, 0, 1, 1])
    assert solver.stats()["success"]
    return float(sol["x"][0])


def test_capped_circle_lap_is_the_inner_circle_at_the_cap(capped_lap: MinTimeLap) -> None:
    lap = capped_lap
    radius = np.hypot(lap.x_m, lap.y_m)
    assert lap.success
    assert np.all(np.abs(lap.v_mps - 4.18) < 1e-3)
    # hand check: one lap of the CoG's circle at the cap
    assert lap.lap_time_s == pytest.approx(2 * math.pi * radius.mean() / 4.18, rel=1e-3)
    # pressed against the inner (left) boundary, the footprint 2 cm inside it
    assert 3.0 - 0.3 + 0.10 < radius.mean() < 3.0 - 0.3 + 0.155 + 0.02 + 0.01
    assert lap.min_clearance_m == pytest.approx(0.02, abs=2e-3)


def test_friction_limited_circle_matches_steady_state_cornering(friction_lap: MinTimeLap) -> None:
    lap = friction_lap
    radius = float(np.hypot(lap.x_m, lap.y_m).mean())
    v_hand = steady_cornering_speed(CAR, radius)
    assert lap.v_mps.max() < 10.0 - 1.0  # the cap does not bind
    assert lap.v_mps.mean() == pytest.approx(v_hand, rel=5e-3)
    assert lap.lap_time_s == pytest.approx(2 * math.pi * radius / v_hand, rel=5e-3)
    # the steady speed is near sqrt(mu g R), never above it (load transfer while driving
    # against the front tyre's drag costs the limiting front axle a few per cent)
    assert 0.9 * math.sqrt(MU_G * radius) < v_hand < math.sqrt(MU_G * radius)


@pytest.mark.parametrize("tyres", ["linear_saturated", "pacejka"])
def test_solution_obeys_the_simulators_own_equations(
    tyres: str, friction_lap: MinTimeLap
) -> None:
    """At every node the simulator's rhs (saturated tyres, its input limits) gives the
    OCP's derivatives: the optimum is inside every limit the simulator applies (for
    Pacejka tyres: below the peak slip, where the simulator's capped curve is the same)."""
    car, lap = CAR, friction_lap
    if tyres == "pacejka":
        car = DynamicVehicleParams(preset="real_car_identified")
        lap = solve_min_time(circle_track(1.5, 0.3), car, MinTimeSettings(10.0, ds_m=0.2))
        peak = spatial_model(car).peak_slip_rad
        assert peak is not None
    model = SingleTrackModel(car)
    f = make_dynamic_derivatives(car, CASADI_OPS, saturate=False)
    for (_n, _xi, v, beta, r, delta), (sv, a) in zip(lap.states, lap.inputs, strict=True):
        sim = model.rhs((0.0, 0.0, delta, v, 0.0, r, beta), sv, a)
        ocp = f(v, beta, r, delta, a)
        assert sim[3] == pytest.approx(float(ocp.dv), abs=1e-5)
        assert sim[5] == pytest.approx(float(ocp.dr), abs=1e-4)
        assert sim[6] == pytest.approx(float(ocp.dbeta), abs=1e-5)
        assert sim[2] == pytest.approx(sv)
        if tyres == "pacejka":
            assert abs(float(ocp.front.alpha_rad)) <= peak[0] + 1e-6
            assert abs(float(ocp.rear.alpha_rad)) <= peak[1] + 1e-6


def test_gym_linear_tyres_corner_at_the_cap() -> None:
    """The gym's linear tyres bound nothing: on a circle the 4.18 m/s cap binds where the
    friction-limited car reaches only ~3.6 m/s."""
    gym = DynamicVehicleParams(tyre_model="linear")
    lap = solve_min_time(circle_track(1.5, 0.3), gym, MinTimeSettings(4.18, ds_m=0.2))
    assert np.allclose(lap.v_mps, 4.18, atol=1e-3)
    radius = np.hypot(lap.x_m, lap.y_m).mean()
    assert lap.lap_time_s == pytest.approx(2 * math.pi * radius / 4.18, rel=1e-3)


def test_too_narrow_track_is_a_one_line_error() -> None:
    with pytest.raises(MinTimeError) as err:
        solve_min_time(circle_track(3.0, 0.17), CAR)
    text = str(err.value)
    assert "no feasible lap" in text and "\n" not in text and "0.340 m wide" in text


@pytest.mark.slow
def test_too_tight_track_is_a_one_line_error() -> None:
    """Wide enough for the car, but tighter than it can turn: IPOPT proves infeasibility."""
    with pytest.raises(MinTimeError, match="no feasible lap found"):
        solve_min_time(circle_track(0.6, 0.3), CAR)


def test_reference_line_of_a_circle() -> None:
    track = circle_track(2.0, 0.4, spacing_m=0.1)
    ref = reference_line(track)
    assert ref.length_m == pytest.approx(2 * math.pi * 2.0, rel=1e-5)
    pts = ref.points(np.linspace(0.0, ref.length_m, 50, endpoint=False))
    assert np.allclose(pts.kappa_1pm, 0.5, atol=5e-4)  # the spline ripples by 0.02 %
    assert np.allclose(np.hypot(pts.xy[:, 0], pts.xy[:, 1]), 2.0, atol=1e-5)
    assert np.allclose(ref.effective_curvature(pts.s_m[:5], 0.29), 0.5, atol=5e-4)
    assert np.allclose(ref.effective_curvature(pts.s_m[:5], -0.29), 0.5, atol=5e-4)
    w_l, w_r = ref.widths(pts.xy)
    assert np.allclose(w_l, 0.4, atol=2e-3) and np.allclose(w_r, 0.4, atol=2e-3)
    assert np.array_equal(windowed_min(np.array([3.0, 1, 4, 1, 5, 9, 2, 6]), 1),
                          [1.0, 1, 1, 1, 1, 2, 2, 2])


@pytest.mark.parametrize("kappa", [0.0, 0.8, -1.1])
def test_corner_offset_is_exact_on_a_circular_reference(kappa: float) -> None:
    rng = np.random.default_rng(1)
    n, xi, k = ca.SX.sym("n"), ca.SX.sym("xi"), ca.SX.sym("k")
    cx, cy = 0.29, -0.155
    f = ca.Function("off", [n, xi, k], [corner_offset(n, xi, k, cx, cy)])
    for _ in range(20):
        n0, xi0 = rng.uniform(-0.4, 0.4), rng.uniform(-0.5, 0.5)
        # reference point at the origin heading +x; centre of curvature at (0, 1/kappa)
        px = cx * math.cos(xi0) - cy * math.sin(xi0)
        py = n0 + cx * math.sin(xi0) + cy * math.cos(xi0)
        if kappa == 0.0:
            exact = py
        else:
            r = 1.0 / kappa
            exact = r - math.copysign(math.hypot(px, py - r), r)
        assert float(f(n0, xi0, kappa)) == pytest.approx(exact, abs=1e-12)


def test_point_mass_speed_on_a_circle() -> None:
    kappa = np.full(100, 0.5)
    v = point_mass_speed(kappa, 0.1, 20.0, MU_G, 9.51, 9.51)
    assert np.allclose(v, math.sqrt(MU_G / 0.5))
    assert np.allclose(point_mass_speed(kappa, 0.1, 3.0, MU_G, 9.51, 9.51), 3.0)


def test_settings_reject_bad_numbers() -> None:
    for kwargs in ({"v_max_mps": 0.0}, {"ds_m": -0.1}, {"margin_m": math.nan},
                   {"v_max_mps": math.inf}, {"ds_m": "0.1"}):
        with pytest.raises(ValueError):
            MinTimeSettings(**kwargs)


def test_linear_tyres_have_no_friction_constraints() -> None:
    gym = DynamicVehicleParams(tyre_model="linear")
    assert not spatial_model(gym).friction_limited
    assert spatial_model(CAR).friction_limited
    pac = DynamicVehicleParams(preset="real_car_identified")
    peak = spatial_model(pac).peak_slip_rad
    assert peak is not None and all(0.0 < a < 0.5 for a in peak)


def test_cache_hits_and_misses(tmp_path, monkeypatch, capped_lap: MinTimeLap) -> None:
    calls: list[MinTimeSettings] = []

    def fake_solve(track, vehicle, settings):
        calls.append(settings)
        return capped_lap

    monkeypatch.setattr(store, "solve_min_time", fake_solve)
    track = circle_track(3.0, 0.3)
    cfg = MinTimeSettings(v_max_mps=4.18, ds_m=0.2)
    first = store.make_min_time_lap(track, CAR, cfg, cache_dir=tmp_path)
    again = store.make_min_time_lap(track, CAR, cfg, cache_dir=tmp_path)
    assert len(calls) == 1 and not first.cache_hit and again.cache_hit
    assert again.lap_time_s == capped_lap.lap_time_s
    assert np.array_equal(again.states, capped_lap.states)
    assert again.status == capped_lap.status and again.tyre_model == capped_lap.tyre_model
    # anything the lap depends on changes the key
    store.make_min_time_lap(track, CAR, MinTimeSettings(v_max_mps=4.18, ds_m=0.2, margin_m=0.03),
                       cache_dir=tmp_path)
    store.make_min_time_lap(track, CAR.model_copy(update={"mu": 1.0}), cfg, cache_dir=tmp_path)
    store.make_min_time_lap(circle_track(3.0, 0.31), CAR, cfg, cache_dir=tmp_path)
    assert len(calls) == 4
    # a damaged entry is a miss, then replaced
    key = store.cache_key(track, CAR, cfg)
    store.cache_file(key, tmp_path).write_bytes(b"not a cache file")
    assert not store.make_min_time_lap(track, CAR, cfg, cache_dir=tmp_path).cache_hit
    assert store.make_min_time_lap(track, CAR, cfg, cache_dir=tmp_path).cache_hit
    assert len(calls) == 5
    # use_cache=False always solves
    store.make_min_time_lap(track, CAR, cfg, cache_dir=tmp_path, use_cache=False)
    assert len(calls) == 6


def test_default_cache_folder_follows_racestack_cache(tmp_path, monkeypatch) -> None:
    monkeypatch.setenv("RACESTACK_CACHE", str(tmp_path))
    assert store.cache_file("abc") == tmp_path / "mintime" / "abc.npz"
