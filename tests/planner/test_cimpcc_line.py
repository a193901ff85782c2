"""``cimpcc-line`` (issue #12): CiMPCC's problem builder contouring the minimum-time line.

The paper's methods are covered, unchanged, by ``test_planner_solve.py``; here: the line as a
reference path, the per-stage velocity references, the slip model, the compile-cache key,
a circle (steady state on the line at the profile's speed) and a lap in the bench loop.
"""

from __future__ import annotations

import json
from pathlib import Path

import casadi as ca
import numpy as np
import pytest

from services.planner.mintime.store import ensure_artefacts
from services.planner.mpc.model import (
    SPEED,
    S,
    SlipModel,
    SpeedLoop,
    U,
    discretise,
    kinematic_bicycle,
    step_numpy,
)
from services.planner.mpc.planner import (
    SOLVED,
    Planner,
    min_time_reference,
    solver_settings,
)
from services.planner.mpc.problem import NV, NXA, XA_SPEED, ParamLayout, build_problem
from services.planner.mpc.solver import cache_key, solver_options
from services.planner.reference import CENTRELINE, MIN_TIME_LINE, ReferencePath
from services.planner.registry import make_planner
from services.planner.service import plan_message
from services.tools.bench import LoopOptions, run_method
from services.tools.bench.run import main as bench_main
from shared.config import load_config
from shared.config.methods import CIMPCC_LINE
from shared.config.planner import (
    CIMPCC_WEIGHTS,
    CimpccLineSettings,
    PlannerSettings,
    SolverSettings,
)
from shared.config.vehicle import F1TENTH_GYM
from shared.track import Track
from shared.vehicle.steady_state import steady_state_steering

UNCOMPILED = PlannerSettings(method=CIMPCC_LINE, solver=SolverSettings(compile=False))
#: Centreline radius [m] of the test circle: tight enough that grip, not the 4.18 m/s cap,
#: sets the line's speed.
CIRCLE_RADIUS_M = 1.5
HALF_WIDTH_M = 0.6


def circle(radius: float = CIRCLE_RADIUS_M, n: int = 400) -> Track:
    """Counter-clockwise circle about the origin, 1.2 m wide."""
    t = np.linspace(0, 2 * np.pi, n, endpoint=False)
    xy = radius * np.column_stack([np.cos(t), np.sin(t)])
    return Track("circle", xy, np.full(n, HALF_WIDTH_M), np.full(n, HALF_WIDTH_M))


@pytest.fixture(scope="module")
def circle_line() -> tuple[Track, ReferencePath]:
    """The circle and its minimum-time line (made once per test session by the tools'
    ``ensure_artefacts``, then read from the cache by the planner's reference)."""
    track = circle()
    ensure_artefacts(CIMPCC_LINE, track, UNCOMPILED, progress=None)
    return track, min_time_reference(track, UNCOMPILED)


def test_the_line_is_a_path_with_the_real_track_limits(circle_line) -> None:
    track, ref = circle_line
    assert ref.kind == MIN_TIME_LINE and not ref.is_centreline and ref.speed is not None
    path = ref.path
    # measured along the centreline's normal, the two half-widths add up to the track's width
    np.testing.assert_allclose(path.w_left_m + path.w_right_m, 2 * HALF_WIDTH_M, atol=1e-6)
    # on a circle the fastest line is a circle near the inside boundary (left: the centre)
    r = np.hypot(*path.xy.T)
    assert np.ptp(r) < 0.01
    np.testing.assert_allclose(path.w_left_m, r - (CIRCLE_RADIUS_M - HALF_WIDTH_M), atol=1e-3)
    assert 0.1 < path.w_left_m.min() < 0.4
    # its own arc length, and every point's track progress within the lap
    assert path.length_m == pytest.approx(2 * np.pi * r.mean(), rel=1e-3)
    assert np.all((ref.track_s_m >= 0.0) & (ref.track_s_m < track.length_m))
    # a constant speed a bit under the friction circle's sqrt(0.95 mu g r) and the cap
    v = ref.speed.speed_at(np.linspace(-5.0, 20.0, 50))  # periodic in s
    assert np.ptp(v) < 1e-3
    assert 2.5 < v[0] < min(4.18, np.sqrt(0.95 * F1TENTH_GYM.mu * 9.81 * r.mean()))
    # the speed command leads the profile by what the P speed loop needs for the tyres' drag
    assert np.all(ref.speed.command_mps > ref.speed.v_mps)


def test_cimpcc_keeps_the_papers_references_at_every_stage() -> None:
    layout = ParamLayout(10)
    assert layout.sizes["v_up"] == layout.sizes["v_low"] == NV * 10
    p = layout.pack(np.zeros(7), 0.5, CIMPCC_WEIGHTS, 0.0, (1.0, 2.0))
    v_up = p[layout.slices["v_up"]].reshape(10, NV)
    v_low = p[layout.slices["v_low"]].reshape(10, NV)
    np.testing.assert_array_equal(v_up, np.tile(CIMPCC_WEIGHTS.v_up_mps, (10, 1)))
    np.testing.assert_array_equal(v_low, np.tile(CIMPCC_WEIGHTS.v_low_mps, (10, 1)))
    block = ca.DM(np.arange(2 * NV * 10))
    assert [float(v) for v in ca.vertsplit(ParamLayout.stage_pair(block, 3))] == [6.0, 7.0]


def test_the_compile_cache_tells_the_line_from_the_centreline(circle_line) -> None:
    track, ref = circle_line
    centre = build_problem(track, UNCOMPILED)
    line = build_problem(ref, UNCOMPILED, SlipModel.for_vehicle(F1TENTH_GYM))
    line_kinematic = build_problem(ref, UNCOMPILED)
    assert centre.reference.kind == CENTRELINE and line.reference is ref
    assert f"path={MIN_TIME_LINE}" in line.signature and "slip=" in line.signature
    keys = {cache_key(p, UNCOMPILED.solver) for p in (centre, line, line_kinematic)}
    assert len(keys) == 3
    # the same problem twice gives the same key (a second start loads the compiled object)
    again = build_problem(ref, UNCOMPILED, SlipModel.for_vehicle(F1TENTH_GYM))
    assert cache_key(again, UNCOMPILED.solver) == cache_key(line, UNCOMPILED.solver)


def test_the_slip_model_turns_on_a_wider_circle_and_is_the_paper_without_slip() -> None:
    slip = SlipModel.for_vehicle(F1TENTH_GYM)
    assert slip.wheelbase_m == pytest.approx(F1TENTH_GYM.wheelbase_m)
    assert slip.understeer_s2pm > 0.0 and slip.rear_slip_s2pm > 0.0  # the gym car understeers
    x, u = np.array([1.0, 2.0, 0.3, 5.0]), np.array([2.0, 0.1, 1.8])
    paper = np.asarray(kinematic_bicycle(0.324)(x, u)).ravel()
    same = np.asarray(kinematic_bicycle(9.0, SlipModel(0.324))(x, u)).ravel()
    np.testing.assert_array_equal(paper, same)
    # steady state: radius (L + K_us v^2) / tan(delta), the course turned outwards by alpha_r
    v, delta, dt = 3.0, 0.25, 0.01
    F = discretise(kinematic_bicycle(0.0, slip), dt, "rk4")
    z = np.zeros(4)
    pts = []
    for _ in range(400):
        z = step_numpy(F, z, np.array([v, delta, v]))
        pts.append(z[: S.PHI])
    pts = np.asarray(pts)
    radius = (slip.wheelbase_m + slip.understeer_s2pm * v**2) / np.tan(delta)
    # least-squares circle through the points (x^2 + y^2 + D x + E y + F = 0)
    A = np.column_stack([pts, np.ones(len(pts))])
    d, e, f = np.linalg.lstsq(A, -(pts**2).sum(axis=1), rcond=None)[0]
    assert np.sqrt(d * d / 4 + e * e / 4 - f) == pytest.approx(radius, rel=1e-6)
    xdot = np.asarray(kinematic_bicycle(0.0, slip)(np.zeros(4), [v, delta, v])).ravel()
    course = np.arctan2(xdot[S.Y], xdot[S.X])
    assert course == pytest.approx(-slip.rear_slip_s2pm * v**2 / radius, rel=1e-9)


def test_velocity_references_follow_the_profile_at_each_predicted_stage(circle_line) -> None:
    track, ref = circle_line
    planner = Planner(track, UNCOMPILED, reference=ref)
    assert planner.method == CIMPCC_LINE and planner.path is ref.path
    start = ref.path.xy[0]
    res = planner.step(float(start[0]), float(start[1]), float(ref.path.heading_rad[0]))
    assert res.status == SOLVED
    np.testing.assert_array_equal(res.beta, 1.0)
    n = planner.problem.horizon
    drag = np.zeros(n) if planner.problem.has_speed else None
    p = planner._parameters(
        np.zeros(planner.problem.nxa), res.beta, np.column_stack([[1.0] * n, [2.0] * n]), drag
    )
    layout = planner.problem.layout
    np.testing.assert_array_equal(p[layout.slices["v_up"]], p[layout.slices["v_low"]])
    np.testing.assert_array_equal(p[layout.slices["v_up"]][:4], [1.0, 2.0, 1.0, 2.0])
    # the result's progress is the track's (the bench's and telemetry's bookkeeping), the
    # plan's states are on the line
    s_track, e_track = track.project(start)
    assert res.s_m == pytest.approx(float(s_track), abs=1e-6)
    assert res.e_con_m == pytest.approx(float(e_track), abs=1e-6)
    assert res.states[0, S.PROGRESS] < 0.5 or res.states[0, S.PROGRESS] > ref.path.length_m - 0.5
    # it makes a valid planner/plan record
    plan = plan_message(res, 1.0, 0.9)
    assert plan.method == CIMPCC_LINE and type(plan).decode(plan.encode()) == plan


@pytest.mark.slow
def test_on_a_circle_it_settles_on_the_line_at_the_profile_speed(circle_line) -> None:
    """In the bench loop (the simulated car, its delays, a standing start on the centreline)
    the car ends up on the line, at the minimum-time profile's steady-state speed."""
    track, ref = circle_line
    cfg = load_config(None)
    planner = Planner(track, cfg.planner, method=CIMPCC_LINE, reference=ref)
    poses: list[tuple[float, float]] = []
    step = planner.step

    def recording_step(x: float, y: float, yaw: float, on_command=None):
        poses.append((x, y))
        return step(x, y, yaw, on_command)

    planner.step = recording_step  # type: ignore[method-assign]
    run = run_method(CIMPCC_LINE, planner, track, cfg.simulator, LoopOptions(laps=3))
    assert run.completed_laps == 3 and run.run_off_track_events == 0
    last = slice(-40, None)  # the last 2 s
    rear = np.hypot(*np.asarray(poses[last]).T)
    line_r = float(np.hypot(*ref.path.xy.T).mean())
    assert np.max(np.abs(rear - line_r)) < 0.02
    v_line = float(ref.speed.v_mps.mean())
    speed = np.asarray(run.trace.speed_mps[last])
    assert np.max(np.abs(speed - v_line)) < 0.03 * v_line
    command = np.asarray(run.trace.cmd_speed_mps[last])
    assert np.all(command > v_line)  # it leads the speed by what the speed loop needs
    assert run.laps[-1].lap_time_s == pytest.approx(ref.speed.lap_time_s, rel=0.02)


@pytest.mark.slow
@pytest.mark.parametrize("where", ["paperlike", "map416"])
def test_it_builds_and_races_a_clean_lap_in_the_bench(
    where: str, tmp_path: Path, request: pytest.FixtureRequest
) -> None:
    """``racestack bench --methods cimpcc-line`` on the default track and on the paper's
    (skipped without ../shared): a clean lap, well under the paper method's (13.27 s on
    paperlike, 10.88 s on map416 in this simulator)."""
    spec = "paperlike" if where == "paperlike" else str(request.getfixturevalue("shared_tracks")
                                                         / "map416")
    out = tmp_path / "out"
    code = bench_main(["--track", spec, "--laps", "1", "--methods", CIMPCC_LINE, "--out",
                       str(out), "--no-figures", "--no-reference"])
    assert code == 0
    m = json.loads((out / "results.json").read_text())["methods"][CIMPCC_LINE]
    assert m["completed_laps"] == 1 and m["off_track_events_all"] == 0
    cimpcc_lap_s = {"paperlike": 13.27, "map416": 10.88}[where]
    assert m["lap_time_s"]["mean"] < 0.8 * cimpcc_lap_s


def test_cimpcc_line_refuses_a_path_without_a_speed_profile() -> None:
    with pytest.raises(ValueError, match="speed profile"):
        Planner(circle(), UNCOMPILED, reference=build_problem(circle(), UNCOMPILED).reference)


def test_make_planner_builds_the_method(circle_line) -> None:
    track, _ = circle_line
    planner = make_planner(track, UNCOMPILED, vehicle=F1TENTH_GYM)
    assert isinstance(planner, Planner) and planner.method == CIMPCC_LINE
    assert planner.reference.kind == MIN_TIME_LINE
    x0 = planner.path.xy[5]
    res = planner.step(float(x0[0]), float(x0[1]), float(planner.path.heading_rad[5]))
    assert res.status == SOLVED and np.isfinite(res.command.speed_mps)
    assert res.inputs.shape == (UNCOMPILED.cimpcc_line.horizon_steps, len(U))


# ---------------------------------------------------------------- the speed-loop model
def test_the_speed_loop_speeds_up_and_brakes_with_the_cars_gains() -> None:
    loop = SpeedLoop.for_vehicle(F1TENTH_GYM)
    k_a, k_b = F1TENTH_GYM.speed_gain_accel_per_s, F1TENTH_GYM.speed_gain_brake_per_s
    # (within a few % of the gains: the smooth switch between them and the smooth clip)
    assert float(loop.accel(3.5, 3.0)) == pytest.approx(k_a * 0.5, rel=0.03)
    assert float(loop.accel(2.8, 3.0)) == pytest.approx(-k_b * 0.2, rel=0.03)
    # far from the target it is held at the drive's limit
    assert abs(float(loop.accel(10.0, 0.0))) == pytest.approx(loop.accel_max_mps2, rel=0.01)
    assert abs(float(loop.accel(0.0, 10.0))) == pytest.approx(loop.accel_max_mps2, rel=0.01)
    # held for long it settles just under the command (the smooth switch: by about
    # (k_b - k_a) e_s / (k_a + k_b) = 0.03 m/s); the mean over a step lies between the ends
    v_end, v_mean = loop.advance(2.0, 3.0, 2.0, substeps=200)
    assert 2.95 < v_end < 3.0
    v_end, v_mean = loop.advance(2.0, 3.0, 0.05)
    assert 2.0 < v_mean < v_end < 3.0


def test_with_a_speed_loop_the_car_moves_at_its_speed_not_at_the_command() -> None:
    loop = SpeedLoop.for_vehicle(F1TENTH_GYM)
    slip = SlipModel.for_vehicle(F1TENTH_GYM, near_limit=True)
    f = kinematic_bicycle(0.0, slip, loop)
    x = np.array([0.0, 0.0, 0.3, 1.0, 2.5])  # [X, Y, phi, s, v]
    u = np.array([4.0, 0.0, 2.5])  # command 4 m/s, straight
    xdot = np.asarray(f(x, u)).ravel()
    assert xdot.shape == (5,)
    np.testing.assert_allclose(xdot[:2], 2.5 * np.array([np.cos(0.3), np.sin(0.3)]))
    assert xdot[SPEED] == pytest.approx(float(loop.accel(4.0, 2.5)))


def test_the_near_limit_slip_turns_like_the_cars_steady_state() -> None:
    """At 9 m/s^2 and 4 m/s the small-angle slip model predicts 13 % more curvature than the
    car's steady state (load transfer and drag, ``tracker.steady_state_steering``) for the
    same steering; the near-limit fit errs less and on the safe side (it turns 8 % less);
    at low lateral acceleration both agree."""
    small = SlipModel.for_vehicle(F1TENTH_GYM)
    fit = SlipModel.for_vehicle(F1TENTH_GYM, near_limit=True)
    assert fit.understeer_growth_s6pm3 > 0.0 > fit.rear_slip_growth_s6pm3
    assert small.understeer_growth_s6pm3 == 0.0 == small.rear_slip_growth_s6pm3
    v = 4.0

    def curvature_error(model: SlipModel, a_y: float) -> float:
        """model's curvature / the steady state's - 1 at the steady state's steering."""
        kappa = a_y / v**2
        delta, _, _ = steady_state_steering(
            np.array([kappa]), np.array([v]), np.zeros(1), F1TENTH_GYM
        )
        f = kinematic_bicycle(0.0, model, SpeedLoop(1.0, 1.0, 1.0))
        xdot = np.asarray(f([0.0, 0.0, 0.0, 0.0, v], [v, float(delta[0]), v])).ravel()
        return float(xdot[S.PHI] / v / kappa - 1.0)

    assert abs(curvature_error(small, 1.0)) < 0.02 and abs(curvature_error(fit, 1.0)) < 0.02
    assert curvature_error(small, 9.0) > 0.1
    assert -0.1 < curvature_error(fit, 9.0) < 0.0


def test_the_speed_loop_problem_has_the_speed_state_and_a_drag_per_stage(circle_line) -> None:
    _, ref = circle_line
    loop = SpeedLoop.for_vehicle(F1TENTH_GYM)
    slip = SlipModel.for_vehicle(F1TENTH_GYM, near_limit=True)
    speed = build_problem(ref, UNCOMPILED, slip, loop)
    plain = build_problem(ref, UNCOMPILED, slip)
    assert speed.has_speed and speed.nxa == NXA + 1 and speed.model_index[-1] == XA_SPEED
    assert not plain.has_speed and plain.nxa == NXA and "drag" not in plain.layout.slices
    assert speed.layout.sizes["drag"] == speed.horizon and speed.layout.sizes["x0"] == NXA + 1
    assert cache_key(speed, UNCOMPILED.solver) != cache_key(plain, UNCOMPILED.solver)
    xs = np.arange((speed.horizon + 1) * speed.nxa, dtype=float).reshape(-1, speed.nxa)
    us = np.ones((speed.horizon, 4))
    back_xs, back_us = speed.unpack(speed.pack(xs, us))
    np.testing.assert_array_equal(back_xs, xs)
    np.testing.assert_array_equal(back_us, us)
    # the line's drag: on the circle's constant speed, all of the lap's acceleration input
    prof = ref.speed
    assert prof.drag_mps2 is not None and np.all(prof.drag_mps2 >= 0.0)
    assert float(np.mean(prof.drag_at(np.linspace(0.0, 5.0, 20)))) > 0.1


def test_the_speed_estimate_follows_the_poses(circle_line) -> None:
    """The pose carries no speed: the planner estimates it from the displacement over the
    period plus the speed loop's change over its second half."""
    track, ref = circle_line
    settings = UNCOMPILED.model_copy(
        update={"cimpcc_line": CimpccLineSettings(model="kinematic_slip_speed")}
    )
    planner = Planner(track, settings, reference=ref)
    assert planner.problem.has_speed
    dt = settings.dt_s
    planner._u_applied = np.array([3.0, 0.0, 3.0])
    estimates = [planner._estimate_speed(3.0 * dt * k, 0.0, 0.0) for k in range(8)]
    assert estimates[0] < 3.0  # no previous pose: the loop's prediction from standstill
    # then the displacement (the period's mean) corrected by the loop's change; it settles
    # on the steady speed within a few periods
    assert np.max(np.abs(np.asarray(estimates[1:]) - 3.0)) < 0.25
    assert estimates[-1] == pytest.approx(3.0, abs=0.01)
    planner.reset()
    planner._u_applied = np.array([4.0, 0.0, 4.0])  # speeding up: above the period's mean
    planner._estimate_speed(0.0, 0.0, 0.0)
    planner._v_est = 3.0
    assert planner._estimate_speed(3.0 * dt, 0.0, 0.0) > 3.0


def test_a_speed_estimate_gain_below_one_filters_the_pose_noise(circle_line) -> None:
    """On filtered poses (``speed_estimate_gain`` < 1: ``for_pose_source``) the estimate
    leans on the speed loop's prediction: 1.5 cm of pose noise, at a steady 4 m/s, moves
    it several times less than the displacement alone, which stays exact on true poses."""
    track, ref = circle_line
    rng = np.random.default_rng(3)
    noise = rng.normal(0.0, 0.015, 200)

    def spread(gain: float, sigma: float) -> tuple[float, float]:
        line = CimpccLineSettings(model="kinematic_slip_speed", speed_estimate_gain=gain)
        planner = Planner(track, UNCOMPILED.model_copy(update={"cimpcc_line": line}),
                          reference=ref)
        dt = planner.settings.dt_s
        planner._u_applied = np.array([4.0, 0.0, 4.0])
        planner._v_est = 4.0
        v = np.array([planner._estimate_speed(4.0 * dt * k + sigma * noise[k], 0.0, 0.0)
                      for k in range(noise.size)])[20:]
        return float(np.std(v)), float(np.mean(v))

    # on true poses steady and right, at either gain: this synthetic car holds exactly the
    # 4 m/s it is commanded, where the loop model's smooth accelerate / brake blend settles
    # about 5 mm/s lower; the filter leans towards its model by about 1 / g of that
    assert spread(1.0, 0.0) == pytest.approx((0.0, 4.0), abs=0.01)
    assert spread(0.3, 0.0) == pytest.approx((0.0, 4.0), abs=0.025)
    raw, _ = spread(1.0, 1.0)
    filtered, mean = spread(0.3, 1.0)
    assert raw > 0.3  # about sqrt(2) 1.5 cm / 50 ms
    assert filtered < raw / 2.5 and mean == pytest.approx(4.0, abs=0.05)


# ---------------------------------------------------------------- solving it fast
def test_cimpcc_line_has_its_own_solver_tolerances_and_the_paper_methods_keep_theirs() -> None:
    """``[planner.cimpcc_line.solver]`` reaches cimpcc-line's solver only: cimpcc and mpcc
    (the reproduction) solve with ``[planner.solver]`` as before."""
    settings = PlannerSettings()
    own = settings.cimpcc_line.solver
    line = solver_settings(settings, CIMPCC_LINE)
    assert (line.tol, line.mu_init, line.bound_push) == (own.tol, own.mu_init, own.bound_push)
    assert line.max_iter == settings.solver.max_iter and line.backend == settings.solver.backend
    for method in ("cimpcc", "mpcc"):
        assert solver_settings(settings, method) == settings.solver
    assert settings.solver.bound_push is None  # the back-end's default push


def test_the_bound_push_reaches_either_back_end_and_none_leaves_the_default(circle_line) -> None:
    _, ref = circle_line
    problem = build_problem(ref, UNCOMPILED)
    for backend, key in (("fatrop", "fatrop"), ("ipopt", "ipopt")):
        pushed = SolverSettings(backend=backend, bound_push=1e-6)
        opts = solver_options(problem, pushed)[key]
        assert opts["bound_push"] == opts["bound_frac"] == 1e-6
        plain = solver_options(problem, SolverSettings(backend=backend))[key]
        assert "bound_push" not in plain and "bound_frac" not in plain


@pytest.mark.parametrize("model", ["kinematic_slip", "kinematic_slip_speed"])
def test_the_lifted_problem_is_the_same_problem(circle_line, model: str) -> None:
    """``lifted``: the track limits (and the speed pull) on each stage's own state instead of
    on the prediction from the stage before. Once the gaps are closed it is the same problem:
    the same plan from the same poses, in a smaller Hessian."""
    track, ref = circle_line
    plans = {}
    for lifted in (False, True):
        line = CimpccLineSettings(model=model, lifted=lifted)
        settings = UNCOMPILED.model_copy(update={"cimpcc_line": line})
        planner = Planner(track, settings, reference=ref)
        assert planner.problem.signature.endswith("|lifted") == lifted
        x0 = planner.path.xy[5] + np.array([0.0, 0.03])  # a little off the line
        yaw = float(planner.path.heading_rad[5])
        results = [planner.step(float(x0[0]), float(x0[1]), yaw) for _ in range(3)]
        assert all(r.status == SOLVED for r in results)
        plans[lifted] = results[-1]
    a, b = plans[False], plans[True]
    assert a.command.speed_mps == pytest.approx(b.command.speed_mps, abs=0.02)
    assert a.command.steering_rad == pytest.approx(b.command.steering_rad, abs=0.005)
    np.testing.assert_allclose(a.states[:, :2], b.states[:, :2], atol=0.01)


def test_the_lifted_problem_keeps_one_copy_of_the_models_derivatives(circle_line) -> None:
    _, ref = circle_line
    slip = SlipModel.for_vehicle(F1TENTH_GYM)
    sizes = {}
    for lifted in (False, True):
        problem = build_problem(ref, UNCOMPILED, slip, lifted=lifted)
        nlp = problem.nlp
        lam = ca.SX.sym("lam", nlp["g"].shape[0])
        hess = ca.hessian(nlp["f"] + ca.dot(lam, nlp["g"]), nlp["x"])[0]
        sizes[lifted] = ca.Function("h", [nlp["x"], nlp["p"], lam], [hess]).n_instructions()
        # the same constraints, counted the same way; stage 0's slack is unused when lifted
        assert problem.lbg.size == build_problem(ref, UNCOMPILED, slip).lbg.size
        slack0 = problem.input_index(0).start + 3
        assert problem.ubw[slack0] == (0.0 if lifted else np.inf)
    assert sizes[True] < 0.8 * sizes[False]
