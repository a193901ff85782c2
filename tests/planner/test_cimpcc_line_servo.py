"""``cimpcc-line`` on a car with a slow servo and peaky tyres (issue #21): the servo a state
of the horizon model, the speed command within the cap, the traction budget.

The laps these make are measured by ``python -m benchmarks.robustness --methods cimpcc-line``
(README), not here.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from services.planner.mintime.model import friction_circle_mps2
from services.planner.mintime.store import ensure_artefacts
from services.planner.mpc.model import (
    SERVO,
    SPEED,
    S,
    Servo,
    SlipModel,
    SpeedLoop,
    U,
    discretise,
    kinematic_bicycle,
    step_numpy,
)
from services.planner.mpc.planner import (
    COMMAND_CAP_FADE_MPS,
    COMMAND_CAP_OVER_MPS,
    Planner,
    min_time_reference,
    model_servo,
)
from services.planner.mpc.problem import NXA, XA_SERVO, XA_SPEED, build_problem
from services.planner.reference import ReferencePath
from shared.config.methods import CIMPCC_LINE, method_setup
from shared.config.planner import CimpccLineSettings, PlannerSettings, SolverSettings
from shared.config.vehicle import F1TENTH_GYM, REAL_CAR_IDENTIFIED
from shared.track import Track

UNCOMPILED = PlannerSettings(method=CIMPCC_LINE, solver=SolverSettings(compile=False))
HALF_WIDTH_M = 0.6


def circle(radius: float = 1.5, n: int = 400) -> Track:
    """Counter-clockwise circle about the origin, 1.2 m wide."""
    t = np.linspace(0, 2 * np.pi, n, endpoint=False)
    xy = radius * np.column_stack([np.cos(t), np.sin(t)])
    return Track("circle", xy, np.full(n, HALF_WIDTH_M), np.full(n, HALF_WIDTH_M))


@pytest.fixture(scope="module")
def circle_line() -> tuple[Track, ReferencePath]:
    """The circle and the gym car's minimum-time line on it (cached by the tools)."""
    track = circle()
    ensure_artefacts(CIMPCC_LINE, track, UNCOMPILED, progress=None)
    return track, min_time_reference(track, UNCOMPILED)


def test_the_servo_follows_its_target_with_its_time_constant_and_rate_limit() -> None:
    servo = Servo.for_vehicle(REAL_CAR_IDENTIFIED)
    assert servo.time_constant_s == pytest.approx(0.158) and servo.rate_max_radps == 3.2
    # small steps: first order, e^-1 of the step left after tau
    after = servo.advance(0.0, 0.01, servo.time_constant_s, substeps=100)
    assert after == pytest.approx(0.01 * (1 - math.exp(-1.0)), rel=0.01)
    # a large step is rate limited: no faster than r_max
    assert servo.advance(0.0, 0.8, 0.05) <= 3.2 * 0.05 + 1e-9
    assert float(servo.rate(0.8, 0.0)) == pytest.approx(3.2, rel=0.1)


def test_with_a_servo_the_car_turns_with_the_wheels_not_with_the_target() -> None:
    slip = SlipModel.for_vehicle(REAL_CAR_IDENTIFIED, near_limit=True)
    loop = SpeedLoop.for_vehicle(REAL_CAR_IDENTIFIED)
    servo = Servo.for_vehicle(REAL_CAR_IDENTIFIED)
    f = kinematic_bicycle(0.0, slip, loop, servo)
    x = np.array([0.0, 0.0, 0.0, 0.0, 2.0, 0.0])  # wheels straight
    xdot = np.asarray(f(x, [2.0, 0.3, 2.0])).ravel()  # target 0.3 rad
    assert xdot.shape == (6,)
    assert xdot[S.PHI] == pytest.approx(0.0)  # not turning yet
    assert xdot[SERVO] == pytest.approx(float(servo.rate(0.3, 0.0)))
    # with the wheels at the target it turns as the model without the servo does
    x[SERVO] = 0.3
    without = np.asarray(kinematic_bicycle(0.0, slip, loop)(x[: SERVO], [2.0, 0.3, 2.0]))
    np.testing.assert_allclose(np.asarray(f(x, [2.0, 0.3, 2.0])).ravel()[:SERVO],
                               without.ravel())
    # one step: the wheels move towards the target
    F = discretise(f, 0.05, "rk2")
    x[SERVO] = 0.0
    nxt = step_numpy(F, x, np.array([2.0, 0.3, 2.0]))
    assert 0.0 < nxt[SERVO] < 0.3 and nxt[SPEED] == pytest.approx(2.0, abs=0.05)
    with pytest.raises(ValueError, match="speed loop"):
        kinematic_bicycle(0.0, slip, None, servo)


def test_only_a_slow_servo_is_a_state_and_the_switch_turns_it_off() -> None:
    setup = method_setup(UNCOMPILED, CIMPCC_LINE)
    assert setup.servo_state
    assert model_servo(setup, F1TENTH_GYM) is None  # the gym's 0.01 s servo
    assert model_servo(setup, REAL_CAR_IDENTIFIED) == Servo.for_vehicle(REAL_CAR_IDENTIFIED)
    off = UNCOMPILED.model_copy(
        update={"cimpcc_line": CimpccLineSettings(servo_state=False, cap_command=False)}
    )
    setup_off = method_setup(off, CIMPCC_LINE)
    assert model_servo(setup_off, REAL_CAR_IDENTIFIED) is None
    light_line = CimpccLineSettings(model="kinematic_slip")
    light = UNCOMPILED.model_copy(update={"cimpcc_line": light_line})
    assert model_servo(method_setup(light, CIMPCC_LINE), REAL_CAR_IDENTIFIED) is None


def test_the_servo_problem_has_the_wheels_angle_last(circle_line) -> None:
    _, ref = circle_line
    car = REAL_CAR_IDENTIFIED
    slip, loop = SlipModel.for_vehicle(car, near_limit=True), SpeedLoop.for_vehicle(car)
    pr = build_problem(ref, UNCOMPILED, slip, loop, 4.18, servo=Servo.for_vehicle(car))
    assert pr.has_servo and pr.has_speed and pr.nxa == NXA + 2
    assert pr.model_index[-2:] == (XA_SPEED, XA_SERVO)
    assert "servo=" in pr.signature and pr.layout.sizes["x0"] == NXA + 2
    for k in range(pr.horizon):
        assert pr.ubw[pr.state_index(k + 1)][XA_SPEED] == pytest.approx(4.18)
    plain = build_problem(ref, UNCOMPILED, slip, loop, 4.18)
    assert not plain.has_servo and plain.signature != pr.signature
    with pytest.raises(ValueError, match="speed loop"):
        build_problem(ref, UNCOMPILED, slip, None, servo=Servo.for_vehicle(car))


def test_the_speed_command_keeps_the_car_at_the_cap(circle_line) -> None:
    """The command is capped at the cap plus the speed loop's lead for the line's drag, so
    the car's own speed (the loop never passes its command) keeps the cap."""
    track, ref = circle_line
    planner = Planner(track, UNCOMPILED, reference=ref)
    k_a = F1TENTH_GYM.speed_gain_accel_per_s
    e = math.exp(-k_a * UNCOMPILED.dt_s)
    # below the cap: the command that brings the car just to the cap in one period
    reach = (4.18 - 3.0 * e) / (1.0 - e)
    assert planner._command_limit(None, 3.0) == pytest.approx(reach)
    drag = np.array([1.0, 0.0])
    assert planner._command_limit(drag, 3.0) == pytest.approx(reach + 1.0 / k_a)
    assert planner._command_limit(np.array([-1.0]), 3.0) == pytest.approx(reach)
    v_end, _ = SpeedLoop.for_vehicle(F1TENTH_GYM).advance(3.0, reach, UNCOMPILED.dt_s)
    assert v_end <= 4.18 + 1e-6  # the loop (smoothly clipped at a_max) gets no further
    # near the cap the command is the cap plus the drag's lead, which fades out to above it
    top = 4.18 + COMMAND_CAP_OVER_MPS
    full = top - COMMAND_CAP_FADE_MPS
    assert full < 4.18
    assert planner._command_limit(drag, full) == pytest.approx(
        (4.18 - full * e) / (1.0 - e) + 1.0 / k_a
    )
    half = top - COMMAND_CAP_FADE_MPS / 2
    assert planner._command_limit(drag, half) == pytest.approx(
        max(4.18, (4.18 - half * e) / (1.0 - e)) + 0.5 / k_a
    )
    assert planner._command_limit(drag, top) == pytest.approx(4.18)
    assert planner._command_limit(drag, 4.3) == pytest.approx(4.18)
    off = UNCOMPILED.model_copy(update={"cimpcc_line": CimpccLineSettings(cap_command=False)})
    assert Planner(track, off, reference=ref)._command_cap is None
    # a lap's commands stay within it
    for k in range(8):
        phi = 0.05 * k
        res = planner.step(1.3 * math.cos(phi), 1.3 * math.sin(phi), phi + math.pi / 2)
        v = float(planner._v_est)
        assert res.command.speed_mps <= max(4.18, (4.18 - v * e) / (1 - e)) + 2.5 / k_a


def test_the_planner_estimates_the_wheels_and_steers_the_servos_target(circle_line) -> None:
    track, ref = circle_line
    planner = Planner(track, UNCOMPILED, reference=ref, vehicle=REAL_CAR_IDENTIFIED)
    assert planner.problem.has_servo and planner._servo_tau is None  # no lead: it plans it
    res = None
    for k in range(6):  # on the line's circle, counter-clockwise
        phi = 0.02 * k
        r = 1.3
        res = planner.step(r * math.cos(phi), r * math.sin(phi), phi + math.pi / 2)
    assert res is not None and math.isfinite(res.command.steering_rad)
    # the wheels' estimate follows the targets that were sent
    assert 0.0 < planner._delta_est <= REAL_CAR_IDENTIFIED.steering_max_rad
    gym = Planner(track, UNCOMPILED, reference=ref)
    assert not gym.problem.has_servo


def test_the_gym_s_tyres_have_their_own_traction_budget(circle_line) -> None:
    """``traction_fraction_gym`` (0.9) for the gym's tyres, ``traction_fraction`` (0.8) for
    Pacejka ones; None turns either off (issue #21: the gym car drove wide out of
    hairpins at full lock)."""
    track, ref = circle_line
    gym = Planner(track, UNCOMPILED, reference=ref)
    assert gym._traction_mps2 == pytest.approx(0.9 * friction_circle_mps2(F1TENTH_GYM))
    off = UNCOMPILED.model_copy(update={"cimpcc_line": UNCOMPILED.cimpcc_line.model_copy(
        update={"traction_fraction_gym": None})})
    assert Planner(track, off, reference=ref)._traction_mps2 is None
    car = REAL_CAR_IDENTIFIED  # the Pacejka car keeps its own share
    assert Planner(track, off, reference=ref, vehicle=car)._traction_mps2 == pytest.approx(
        0.8 * friction_circle_mps2(car))


def test_the_traction_budget_caps_the_drive_in_a_bend_not_on_a_straight(circle_line) -> None:
    track, ref = circle_line
    car = REAL_CAR_IDENTIFIED
    planner = Planner(track, UNCOMPILED, reference=ref, vehicle=car)
    budget = 0.8 * friction_circle_mps2(car)
    assert planner._traction_mps2 == pytest.approx(budget)
    pr = planner.problem
    w = np.zeros(pr.nlp["x"].shape[0])
    k_a = car.speed_gain_accel_per_s
    v = 3.0
    # straight: the whole budget to the drive
    assert planner._traction_cap(9.0, v, w) == pytest.approx(v + budget / k_a)
    # braking is never capped
    assert planner._traction_cap(1.0, v, w) == 1.0
    # a bend at a_y = 0.8 of the budget: 0.6 of it left
    w[pr.state_index(1).start + 2] = 0.8 * budget / v * UNCOMPILED.dt_s  # heading change
    assert planner._traction_cap(9.0, v, w) == pytest.approx(v + 0.6 * budget / k_a)
    # beyond the budget: a tenth of it
    w[pr.state_index(1).start + 2] *= 2.0
    assert planner._traction_cap(9.0, v, w) == pytest.approx(v + 0.1 * budget / k_a)
    assert U.V_L == 0  # the command it caps
