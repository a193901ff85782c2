"""Learning the line's steering lap by lap (``services.planner.raceline.learning``): the law
on recorded feedback, and in the car: a feed-forward that is wrong the same way every lap is
learnt away."""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest

from services.planner.raceline.learning import LearningSettings, StepLearning
from services.planner.raceline.planner import planner_timing, tracker_gains
from services.planner.raceline.tracker import ReferenceLap, Tracker
from services.simulator import Command, Simulator
from shared.config.planner import PlannerSettings
from shared.config.simulator import SimulatorSettings
from shared.config.vehicle import F1TENTH_GYM
from tests.planner.test_tracker import COMPUTE_DELAY_S, stadium


def lap_of(learning: StepLearning, feedback: float, step_m: float = 0.2) -> None:
    """One lap of ticks `step_m` apart, each with the same feedback [rad]."""
    for s in np.arange(0.0, learning.length_m, step_m):
        learning.record(float(s), feedback, step_m)


def test_a_constant_feedback_is_learnt_by_the_gain_each_lap_and_bounded() -> None:
    """A lap of 0.02 rad feedback everywhere: ``u`` = 0.5 x 0.02 after it (the smoothing
    keeps a constant), 0.75 x after the second; a large one stops at ``u_max``."""
    lr = StepLearning(20.0, LearningSettings(gain=0.5, smooth_m=0.5, max_rad=0.05))
    lap_of(lr, 0.02)
    assert lr.laps_learnt == 0  # the lap ends when the car passes the start
    lap_of(lr, 0.02)  # the first tick of this lap ended the first
    assert lr.laps_learnt == 1
    assert lr.table == pytest.approx(np.full(lr.n, 0.01))
    lr.end_lap()
    assert lr.laps_learnt == 2
    assert lr.correction(7.33) == pytest.approx(0.02)  # (0.01 + 0.5 * 0.02, the 2nd lap's)
    lap_of(lr, 1.0)
    lr.end_lap()
    assert np.all(lr.table == pytest.approx(0.05))


def test_the_correction_is_periodic_and_learnt_where_the_feedback_acted() -> None:
    """Feedback over 4-6 m only: learnt there (smoothed at its ends), nothing elsewhere;
    read at s and s + L alike."""
    lr = StepLearning(20.0, LearningSettings(gain=1.0, smooth_m=0.2, max_rad=0.5))
    for s in np.arange(0.0, 20.0, 0.1):
        lr.record(float(s), 0.03 if 4.0 <= s < 6.0 else 0.0, 0.1)
    lr.end_lap()
    assert lr.correction(5.0) == pytest.approx(0.03, abs=1e-6)
    assert lr.correction(25.0) == pytest.approx(0.03, abs=1e-6)
    assert lr.correction(-15.0) == pytest.approx(0.03, abs=1e-6)
    assert lr.correction(12.0) == pytest.approx(0.0, abs=1e-9)
    assert 0.0 < lr.correction(3.95) < 0.03  # the smoothing's edge


def test_places_not_seen_keep_what_was_learnt_and_a_new_context_clears_it() -> None:
    lr = StepLearning(10.0, LearningSettings(gain=1.0, smooth_m=0.0, max_rad=0.5))
    lr.context(("plan", 1.0))
    lap_of(lr, 0.01, 0.1)
    lr.end_lap()
    for s in np.arange(0.0, 5.0, 0.1):  # half a lap, other feedback
        lr.record(float(s), 0.02, 0.1)
    lr.end_lap()
    assert lr.correction(2.0) == pytest.approx(0.03)
    assert lr.correction(8.0) == pytest.approx(0.01)
    lr.context(("plan", 1.0))  # the same: kept
    assert lr.correction(8.0) == pytest.approx(0.01)
    lr.context(("plan", 0.98))  # a grip cut: learnt afresh
    assert lr.correction(8.0) == 0.0 and lr.laps_learnt == 0


def test_bad_settings_and_non_finite_feedback() -> None:
    with pytest.raises(ValueError):
        LearningSettings(gain=1.5)
    with pytest.raises(ValueError):
        LearningSettings(spacing_m=0.0)
    with pytest.raises(ValueError):
        StepLearning(0.0, LearningSettings())
    lr = StepLearning(10.0, LearningSettings(gain=1.0, smooth_m=0.0))
    lr.record(1.0, math.nan, 0.1)
    lr.end_lap()
    assert lr.laps_learnt == 0 and lr.correction(1.0) == 0.0


# --------------------------------------------------------------------------- in the car
def learnt_laps(gain: float, laps: int = 4) -> list[float]:
    """The simulated gym car driven round a stadium by the raceline's tracker at 20 Hz on a
    plan whose steering feed-forward is 0.03 rad to the right everywhere (a model error,
    the same every lap), with the learning wired as ``RacelinePlanner`` wires it: the rms
    lateral error [m] of each lap."""
    settings = PlannerSettings()
    car = F1TENTH_GYM
    tr = stadium(15.0, 2.5)
    v = np.full(tr.n_points, 3.0)
    plan = ReferenceLap.from_path(tr, tr.signed_curvature(), v, car)
    plan = ReferenceLap(plan.line, plan.s_m, plan.yaw_rad, plan.kappa_1pm, plan.v_mps,
                        plan.a_mps2, plan.delta_rad - 0.03, plan.t_s, plan.lap_time_s)
    tracker = Tracker.for_vehicle(plan, planner_timing(settings, car),
                                  tracker_gains(settings.raceline), car)
    o = settings.raceline
    learning = StepLearning(plan.length_m, LearningSettings(
        gain=gain, smooth_m=o.steering_learning_smooth_m, max_rad=o.steering_learning_max_rad))
    period = tracker.timing.period_s
    sim = Simulator(SimulatorSettings())
    sim.reset((1.0, 0.0, 0.0), speed_mps=3.0, steering_rad=0.0)
    tracker.reset(1.0)
    prev = Command(3.0, 0.0)
    errors: list[list[float]] = [[]]
    s_last = None
    while len(errors) <= laps:
        st = sim.state
        c = tracker.command(st.x_m, st.y_m, st.yaw_rad)
        if s_last is not None and c.s_m < s_last - 0.5 * plan.length_m:
            errors.append([])
        s_last = c.s_m
        errors[-1].append(c.e_m)
        steering = c.steering_rad + learning.correction(c.steer_s_m)
        v_d = float(plan.at("v", c.steer_s_m))
        learning.record(c.steer_s_m - v_d * o.steering_learning_lead_s, c.feedback_rad,
                        v_d * period)
        cmd = Command(c.speed_mps, min(max(steering, -0.35), 0.35))
        sim.step(prev, COMPUTE_DELAY_S)
        sim.step(cmd, period - COMPUTE_DELAY_S)
        prev = cmd
    return [float(np.sqrt(np.mean(np.square(e)))) for e in errors[1:laps]]


@pytest.mark.slow
def test_a_feed_forward_wrong_the_same_way_every_lap_is_learnt_away() -> None:
    """Without learning the car holds the 0.03 rad error off with a steady offset (the
    proportional feedback's price, 5.7 cm rms, the same every lap); learning at the gain
    0.5 halves it lap by lap, as the law's ``(1 - gamma)`` says (measured 3.1, 1.6, 0.8,
    0.4 cm: the start's part lap already taught the first)."""
    fixed = learnt_laps(0.0, laps=5)
    learnt = learnt_laps(0.5, laps=5)
    assert min(fixed) > 0.05 and max(fixed) - min(fixed) < 0.001
    assert learnt[0] < 0.7 * fixed[0]
    for before, after in itertools.pairwise(learnt):
        assert 0.4 * before < after < 0.6 * before
    assert learnt[-1] < fixed[-1] / 10.0


def _race_paperlike(gain: float, laps: int):
    from services.planner import ensure_artefacts
    from services.planner.raceline.planner import RacelinePlanner
    from services.tools.bench import LoopOptions, run_method
    from shared.config import load_config
    from shared.track import load_track

    cfg = load_config(None)
    track = load_track("paperlike")
    ensure_artefacts("raceline", track, cfg.planner, cfg.vehicle)  # the tools' job
    settings = cfg.planner.model_copy(update={"raceline": cfg.planner.raceline.model_copy(
        update={"steering_learning_gain": gain})})
    planner = RacelinePlanner(track, settings, cfg.curvature, vehicle=cfg.vehicle)
    run = run_method("raceline", planner, track, cfg.simulator, LoopOptions(laps=laps))
    return planner, run


@pytest.mark.slow
def test_the_raceline_learns_its_steering_and_laps_faster_for_it() -> None:
    """The bench's closed loop on paperlike, three flying laps with the default learning and
    without: the same first lap within a few milliseconds, then faster laps with it
    (measured 9.6034 -> 9.5736 s in the third), no off-track event, and a correction learnt
    within its bound."""
    planner, run = _race_paperlike(PlannerSettings().raceline.steering_learning_gain, 3)
    fixed, run_fixed = _race_paperlike(0.0, 3)
    assert PlannerSettings().raceline.steering_learning_gain > 0.0  # on by default
    assert run.completed_laps == run_fixed.completed_laps == 3
    assert run.run_off_track_events == 0 and planner.recovery.episodes == 0
    assert planner.learning.laps_learnt >= 3 and fixed.learning.laps_learnt == 0
    table = planner.learning.table
    assert 0.0 < np.abs(table).max() <= planner.options.steering_learning_max_rad
    learnt = [lap.lap_time_s for lap in run.laps]
    base = [lap.lap_time_s for lap in run_fixed.laps]
    assert learnt[0] == pytest.approx(base[0], abs=0.02)
    assert learnt[2] < base[2] - 0.01
