"""Solves with known answers, closed-loop laps, fallbacks and the solver set-ups."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from services.planner import (
    BRAKING,
    FALLBACK,
    SOLVED,
    Planner,
    SolveResult,
    discretise,
    kinematic_bicycle,
    step_numpy,
)
from services.planner.mpc.problem import build_problem
from services.planner.mpc.solver import make_solver
from services.tools.bench import ModelPlant, race
from shared.config.planner import PlannerSettings, SolverSettings
from shared.track import Track, load_track

UNCOMPILED = PlannerSettings(solver=SolverSettings(compile=False))


def stadium(straight: float = 30.0, radius: float = 5.0, ds: float = 0.05) -> Track:
    """Counter-clockwise stadium: bottom straight from (0, 0) along +x."""
    n_s = round(straight / ds)
    n_a = round(np.pi * radius / ds)
    bottom = np.column_stack([np.arange(n_s) * straight / n_s, np.zeros(n_s)])
    a = -np.pi / 2 + np.arange(n_a) * np.pi / n_a
    right = np.column_stack([straight + radius * np.cos(a), radius + radius * np.sin(a)])
    top = np.column_stack([straight - np.arange(n_s) * straight / n_s, np.full(n_s, 2 * radius)])
    left = np.column_stack([-radius * np.cos(a), radius - radius * np.sin(a)])
    xy = np.vstack([bottom, right, top, left])
    return Track("stadium", xy, np.full(len(xy), 0.6), np.full(len(xy), 0.6))


def circle(radius: float = 3.0, n: int = 600) -> Track:
    t = np.linspace(0, 2 * np.pi, n, endpoint=False)
    xy = radius * np.column_stack([np.cos(t), np.sin(t)])
    return Track("circle", xy, np.full(n, 0.6), np.full(n, 0.6))


def straight_qp_optimum(settings: PlannerSettings) -> tuple[np.ndarray, np.ndarray]:
    """Exact optimum of the CiMPCC problem on a straight (beta = 1, delta = 0) as a QP.

    With delta = 0 on a straight along x the lag error is linear in the speeds,
    ``e_lag_k = Ts * sum_{j<k} (v_p,j - v_l,j)``, e_con = 0, and the cost is quadratic.
    """
    w = settings.cimpcc
    N, dt = settings.horizon_steps, settings.dt_s
    C = np.tril(np.ones((N, N)))  # row k-1: sum over j < k
    D = np.diff(np.eye(N), axis=0)  # input rate inside the horizon (paper: not u_0 - applied)
    M = dt * np.hstack([-C, C])  # e_lag_1..N from z = [v_l; v_p]
    Pl = np.hstack([np.eye(N), np.zeros((N, N))])
    Pp = np.hstack([np.zeros((N, N)), np.eye(N)])
    H = 2 * w.q_lag * M.T @ M
    H += 2 * w.r3_velocity[0] * Pl.T @ Pl + 2 * w.r3_velocity[1] * Pp.T @ Pp
    H += 2 * w.r1_delta_u[0] * (D @ Pl).T @ (D @ Pl) + 2 * w.r1_delta_u[2] * (D @ Pp).T @ (D @ Pp)
    g = -w.gamma * dt * Pp.sum(axis=0)
    g -= 2 * w.r3_velocity[0] * w.v_up_mps[0] * Pl.sum(axis=0)
    g -= 2 * w.r3_velocity[1] * w.v_up_mps[1] * Pp.sum(axis=0)
    z = np.linalg.solve(H, -g)
    return z[:N], z[N:]


def test_first_solve_on_a_straight_is_the_qp_optimum() -> None:
    track = stadium()
    planner = Planner(track, UNCOMPILED)
    res = planner.step(10.0, 0.0, 0.0)
    assert res.status == SOLVED
    v_l, v_p = straight_qp_optimum(UNCOMPILED)
    np.testing.assert_allclose(res.inputs[:, 0], v_l, atol=2e-3)
    np.testing.assert_allclose(res.inputs[:, 2], v_p, atol=2e-3)
    np.testing.assert_allclose(res.inputs[:, 1], 0.0, atol=1e-6)
    np.testing.assert_allclose(res.beta, 1.0)


def closed_loop(planner: Planner, x0: np.ndarray, steps: int) -> tuple[list, np.ndarray]:
    """Close the planner with its own kinematic model; returns the results and last state."""
    plant = ModelPlant.kinematic(planner.track, planner.settings, x0)
    out: list = []
    race(planner, plant, None, max_ticks=steps, on_tick=out.append)
    return out, plant.x


def test_steady_command_on_straight_and_circle() -> None:
    straight_runs, _ = closed_loop(Planner(stadium(), UNCOMPILED), np.array([1.0, 0, 0, 0]), 60)
    v_straight = straight_runs[-1].command.speed_mps
    assert straight_runs[-1].command.steering_rad == pytest.approx(0.0, abs=1e-4)
    speeds = [r.command.speed_mps for r in straight_runs[-10:]]
    assert np.ptp(speeds) < 1e-3  # steady
    v_low, v_up = UNCOMPILED.cimpcc.v_low_mps[0], UNCOMPILED.cimpcc.v_up_mps[0]
    assert v_low < v_straight < v_up

    radius = 3.0
    runs, _ = closed_loop(
        Planner(circle(radius), UNCOMPILED), np.array([radius, 0, np.pi / 2, 0]), 80
    )
    last = runs[-1]
    # rear axle on a circle of radius R: tan(delta) = L / R; beta = 1 (constant curvature)
    assert last.command.steering_rad == pytest.approx(np.arctan(0.324 / radius), abs=3e-3)
    assert last.command.speed_mps == pytest.approx(v_straight, abs=0.05)
    assert abs(last.e_con_m) < 0.02
    assert all(r.status == SOLVED for r in runs)


def lap(planner: Planner, track: Track, max_steps: int = 800) -> tuple[float, float]:
    """Race one lap from the start line against the kinematic model: (lap time, max |e_con|)."""

    def check(res: SolveResult) -> None:
        assert res.status == SOLVED, res.solver_status
        assert np.isfinite([res.command.speed_mps, res.command.steering_rad]).all()

    plant = ModelPlant.kinematic(track, planner.settings)
    got = race(planner, plant, 1, max_ticks=max_steps, on_tick=check)
    L = track.length_m
    assert got.laps == 1, f"no lap in {max_steps} steps ({plant.progress_m:.1f} of {L:.1f} m)"
    return plant.lap_times_s[0], got.max_abs_e_con_m


CAR_HALF_WIDTH_M = 0.155


@pytest.mark.slow
@pytest.mark.parametrize("method", ["cimpcc", "mpcc"])
def test_one_lap_on_the_default_track_stays_inside(method: str) -> None:
    track = load_track("builtin:paperlike")
    planner = Planner(track, PlannerSettings(method=method))
    assert planner.solver.compiled
    t, max_e = lap(planner, track)
    assert max_e < 0.6 - CAR_HALF_WIDTH_M
    assert 5.0 < t < 25.0


@pytest.mark.slow
def test_one_lap_on_map416_with_beta_per_stage(shared_tracks: Path) -> None:
    track = load_track(shared_tracks / "map416")
    planner = Planner(track, PlannerSettings(beta_mode="per_stage"))
    t, max_e = lap(planner, track)
    assert max_e < 0.6 - CAR_HALF_WIDTH_M
    assert t < 15.0


def test_failed_solves_fall_back_then_brake() -> None:
    track = stadium()
    planner = Planner(track, UNCOMPILED)
    first = planner.step(10.0, 0.0, 0.0)
    assert first.status == SOLVED
    fb = planner.step(float("nan"), 0.0, 0.0)
    assert fb.status == FALLBACK and fb.consecutive_failures == 1
    assert fb.command.speed_mps == pytest.approx(first.inputs[1, 0])  # the shifted plan
    assert planner.step(10.1, float("inf"), 0.0).status == FALLBACK
    brake = planner.step(float("nan"), float("nan"), float("nan"))
    assert brake.status == BRAKING and brake.command.speed_mps == 0.0
    assert np.isfinite(brake.command.steering_rad)
    again = planner.step(10.2, 0.0, 0.0)
    assert again.status == SOLVED and again.consecutive_failures == 0


def test_a_solver_that_cannot_converge_brakes_without_nan() -> None:
    settings = PlannerSettings(solver=SolverSettings(compile=False, max_iter=1))
    planner = Planner(stadium(), settings)
    for _ in range(4):
        res = planner.step(10.0, 0.3, 0.2)
        assert res.status in (FALLBACK, BRAKING)
        assert np.isfinite([res.command.speed_mps, res.command.steering_rad]).all()
    assert res.status == BRAKING and res.command.speed_mps == 0.0


def test_commands_stay_finite_and_inside_bounds_from_any_pose() -> None:
    track = load_track("paperlike")
    planner = Planner(track, UNCOMPILED)
    rng = np.random.default_rng(3)
    b = UNCOMPILED.bounds
    for _ in range(30):
        i = rng.integers(track.n_points)
        pose = track.xy[i] + rng.normal(0, 0.8, 2)  # often far outside the track
        res = planner.step(pose[0], pose[1], rng.uniform(-np.pi, np.pi))
        v, d = res.command.speed_mps, res.command.steering_rad
        assert np.isfinite([v, d]).all()
        assert b.v_l_mps[0] <= v <= b.v_l_mps[1]
        assert b.delta_rad[0] <= d <= b.delta_rad[1]


def test_compiled_problem_is_cached_and_works_without_a_compiler(tmp_path: Path) -> None:
    track = circle()
    settings = PlannerSettings(solver=SolverSettings(cache_dir=str(tmp_path)))
    problem = build_problem(track, settings)
    first = make_solver(problem, settings.solver)
    second = make_solver(problem, settings.solver)
    assert first.compiled and not first.cache_hit
    assert second.compiled and second.cache_hit and second.library == first.library
    no_cc = SolverSettings(cache_dir=str(tmp_path / "other"), compiler="no-such-compiler-xyz")
    fallback = make_solver(problem, no_cc)
    assert not fallback.compiled
    planner = Planner(
        track, settings.model_copy(update={"solver": no_cc}), problem=problem, solver=fallback
    )
    assert planner.step(3.0, 0.0, np.pi / 2).status == SOLVED


def test_ipopt_backend_agrees_with_fatrop() -> None:
    track = stadium()
    fat = Planner(track, UNCOMPILED).step(10.0, 0.05, 0.02)
    ipo_settings = PlannerSettings(solver=SolverSettings(compile=False, backend="ipopt"))
    ipo = Planner(track, ipo_settings).step(10.0, 0.05, 0.02)
    assert ipo.status == SOLVED
    np.testing.assert_allclose(ipo.inputs, fat.inputs, atol=5e-3)


def test_mpcc_and_cimpcc_share_one_problem() -> None:
    track = stadium()
    ci = Planner(track, UNCOMPILED)
    mp = Planner(track, UNCOMPILED, method="mpcc", problem=ci.problem, solver=ci.solver)
    a = ci.step(10.0, 0.0, 0.0)
    b = mp.step(10.0, 0.0, 0.0)
    assert a.method == "cimpcc" and b.method == "mpcc"
    # MPCC pulls toward u_ref = (3.3, 0, 3.0): slower than CiMPCC's v_up on a straight
    assert b.inputs[:, 0].mean() < a.inputs[:, 0].mean()


def test_prepare_ahead_changes_nothing_and_the_command_comes_first() -> None:
    """``prepare()`` between ticks (as the service does) gives the very same plans as
    ``step`` alone, for both beta modes; ``on_command`` gets the result's command, once,
    before ``step`` returns, also on the fallback and braking paths."""
    track = stadium()
    for mode in ("current", "per_stage"):
        settings = PlannerSettings(solver=SolverSettings(compile=False), beta_mode=mode)
        alone = Planner(track, settings)
        ahead = Planner(track, settings, problem=alone.problem, solver=alone.solver)
        F = discretise(kinematic_bicycle(settings.wheelbase_m), settings.dt_s)
        x = np.array([0.5, 0.1, 0.05, 0.0])
        for k in range(40):
            got: list = []
            pose = (float("nan"), 0.0, 0.0) if k in (12, 13) else tuple(x[:3])
            a = alone.step(*pose)
            b = ahead.step(*pose, on_command=got.append)
            ahead.prepare()
            ahead.prepare()  # idempotent
            assert got == [b.command]
            assert a.status == b.status
            assert a.command == b.command
            np.testing.assert_array_equal(a.states, b.states)
            np.testing.assert_array_equal(a.beta, b.beta)
            if a.status == SOLVED:
                x = step_numpy(F, x, np.array([a.command.speed_mps, a.command.steering_rad, 0.0]))
        assert a.status == SOLVED and x[0] > 5.0  # recovered after the two bad poses


def test_prepare_after_reset_and_before_any_solve_is_harmless() -> None:
    planner = Planner(stadium(), UNCOMPILED)
    planner.prepare()  # nothing to shift yet
    assert planner.step(10.0, 0.0, 0.0).status == SOLVED
    planner.prepare()
    planner.reset()
    res = planner.step(12.0, 0.0, 0.0)  # a cold start again, not the stale prepared plan
    assert res.status == SOLVED and res.states[0, 0] == pytest.approx(12.0)


def test_off_the_track_the_speed_command_is_capped() -> None:
    """The safety rule outside the optimisation: outside the boundaries |speed| <= the cap
    (and the result says so); inside, the solver's speed is passed through."""
    track = stadium()
    settings = PlannerSettings(solver=SolverSettings(compile=False), off_track_speed_mps=0.7)
    planner = Planner(track, settings)
    inside = [planner.step(5.0 + 0.15 * k, 0.0, 0.0) for k in range(20)][-1]
    assert not inside.speed_limited and inside.command.speed_mps > 0.7
    for y in (-0.8, 0.8):  # right of, then left of the bottom straight (w = 0.6 m)
        res = planner.step(8.0, y, 0.0)  # warm: the plan still asks for racing speed
        assert res.e_con_m == pytest.approx(-y, abs=1e-9)
        assert res.inputs[0, 0] > 0.7 and res.speed_limited
        assert res.command.speed_mps == pytest.approx(0.7)
