"""The raceline baseline: the minimum-time and minimum-curvature lines, the speed profile,
the tracker in the planner, clean laps in the bench's closed loop."""

from __future__ import annotations

import math

import numpy as np
import pytest

from services.planner import BRAKING, SOLVED, SolveResult
from services.planner.mintime.ocp import MinTimeLap
from services.planner.raceline.planner import (
    RacelinePlanner,
    build_raceline,
    min_curvature_offsets,
    min_time_settings,
    planning_vehicle,
    resample,
    speed_profile,
)
from services.tools.bench import ModelPlant, race
from shared.config.planner import PlannerSettings, RacelineSettings
from shared.config.vehicle import F1TENTH_GYM
from shared.track import Track, load_track

#: The minimum-curvature line (built in about a second; the minimum-time one is solved).
MIN_CURVATURE = RacelineSettings(line="min_curvature")
MIN_CURVATURE_PLANNER = PlannerSettings(raceline=MIN_CURVATURE)


def circle(radius: float = 3.0, n: int = 400, width: float = 0.6) -> Track:
    t = np.linspace(0, 2 * np.pi, n, endpoint=False)
    xy = radius * np.column_stack([np.cos(t), np.sin(t)])  # counter-clockwise
    return Track("circle", xy, np.full(n, width), np.full(n, width))


def test_on_a_circle_the_line_takes_the_outside() -> None:
    """Every concentric circle is a candidate; the widest (least curved) one wins."""
    tr = circle()
    xy, normals, w_r, w_l = resample(tr, 0.1)
    lo, hi = -(w_r - 0.2), w_l - 0.2
    alpha = min_curvature_offsets(xy, normals, lo, hi)
    # right = outside of a left turn; to within the interior-point solver's bound distance
    np.testing.assert_allclose(alpha, lo, atol=1e-3)


def test_the_line_is_straighter_than_the_centreline_and_inside_the_margin() -> None:
    tr = load_track("paperlike")
    s = MIN_CURVATURE
    rl = build_raceline(tr, s)
    assert rl.kind == "min_curvature" and rl.min_time is None
    _, _, w_r, w_l = resample(tr, s.ds_m)
    assert np.all(rl.offset_m <= w_l - s.margin_m + 1e-9)
    assert np.all(rl.offset_m >= -(w_r - s.margin_m) - 1e-9)
    k_line = np.sum(np.abs(rl.track.signed_curvature()) ** 2 * rl.track.spacing_m)
    k_centre = np.sum(np.abs(tr.signed_curvature()) ** 2 * tr.spacing_m)
    assert k_line < 0.8 * k_centre  # integral of kappa^2 along the line
    assert rl.track.length_m < tr.length_m  # corners are cut


def test_speed_profile_respects_every_limit() -> None:
    s = RacelineSettings(a_lat_mps2=4.0, a_accel_mps2=3.0, a_brake_mps2=5.0, v_max_mps=4.0)
    n = 400
    kappa = np.zeros(n)
    kappa[150:200] = 1.0  # a 1 m radius corner after a long straight
    seg = np.full(n, 0.1)
    v = speed_profile(kappa, seg, s)
    assert v.max() == pytest.approx(4.0)
    np.testing.assert_allclose(v[150:200], 2.0)  # sqrt(a_lat * R)
    dv2 = np.roll(v, -1) ** 2 - v**2
    assert np.all(dv2 <= 2 * 3.0 * 0.1 + 1e-9)  # accelerating
    assert np.all(dv2 >= -2 * 5.0 * 0.1 - 1e-9)  # braking
    flat = speed_profile(np.zeros(n), seg, s)
    np.testing.assert_allclose(flat, 4.0)  # nothing to brake for on a closed loop


def test_the_tracker_laps_the_default_track_inside_against_the_model() -> None:
    tr = load_track("paperlike")
    settings = MIN_CURVATURE_PLANNER
    planner = RacelinePlanner(tr, settings)
    w_min = float(min(tr.w_right_m.min(), tr.w_left_m.min()))

    def check(res: SolveResult) -> None:
        assert res.status == SOLVED and res.method == "raceline"
        assert abs(res.command.steering_rad) <= settings.bounds.delta_rad[1] + 1e-12
        # the rear axle stays inside; the kinematic car needs neither the understeer nor
        # the slip the tracker's feed-forward plans for the real one (17 cm off the line)
        assert abs(res.e_con_m) < w_min - 0.1
        assert res.states.shape == (settings.horizon_steps + 1, 4)

    plant = ModelPlant.kinematic(tr, settings)
    got = race(planner, plant, 1, max_ticks=600, on_tick=check)
    assert got.laps == 1 and plant.progress_m >= tr.length_m


def test_a_bad_pose_gives_a_braking_command() -> None:
    planner = RacelinePlanner(load_track("paperlike"), MIN_CURVATURE_PLANNER)
    res = planner.step(math.nan, 0.0, 0.0)
    assert res.status == BRAKING and res.command.speed_mps == 0.0
    assert np.isfinite(res.states).all() and np.isfinite(res.beta).all()


def test_a_margin_wider_than_the_track_is_an_error() -> None:
    with pytest.raises(ValueError, match="margin"):
        build_raceline(load_track("paperlike"), MIN_CURVATURE.model_copy(update={"margin_m": 0.7}))


def test_the_planner_service_can_run_the_baseline() -> None:
    """``[planner] method = "raceline"`` builds the baseline, and its results make valid
    ``planner/plan`` records (what the service publishes)."""
    from services.planner.mpc.planner import Planner
    from services.planner.registry import make_planner
    from services.planner.service import plan_message

    tr = load_track("paperlike")
    planner = make_planner(tr, PlannerSettings(method="raceline", raceline=MIN_CURVATURE))
    assert isinstance(planner, RacelinePlanner)
    got: list = []
    res = planner.step(*tr.xy[3], float(tr.heading_rad[3]), on_command=got.append)
    planner.prepare()
    assert got == [res.command]
    plan = plan_message(res, 1.0, 0.9)
    assert plan.method == "raceline" and plan.status == SOLVED
    assert type(plan).decode(plan.encode()) == plan
    bad = planner.step(math.inf, 0.0, 0.0)
    assert plan_message(bad, 1.0, 0.9).status == BRAKING
    assert isinstance(make_planner(tr, PlannerSettings(method="mpcc")), Planner)


@pytest.mark.slow
def test_a_line_on_a_full_size_f1tenth_track(shared_tracks) -> None:
    """The coarse (0.35 m) F1TENTH centrelines: the line stays regular and inside."""
    tr = load_track(shared_tracks / "f1tenth" / "Oschersleben")
    s = MIN_CURVATURE
    rl = build_raceline(tr, s)
    xy, _, w_r, w_l = resample(tr, s.ds_m)
    assert np.all(rl.offset_m <= w_l - s.margin_m + 1e-9)
    assert np.all(rl.offset_m >= -(w_r - s.margin_m) - 1e-9)
    centre = Track("centre", xy, w_r, w_l)  # the same spacing as the line

    def energy(t: Track) -> float:
        return float(np.sum(t.signed_curvature() ** 2) * t.spacing_m)

    assert energy(rl.track) < 0.5 * energy(centre)
    assert 2.0 < rl.speed_mps.min() and rl.lap_time_s < tr.length_m / 2.0


def test_no_room_for_a_raceline_is_a_track_error_in_the_bench(tmp_path, capsys) -> None:
    from services.tools.bench.run import main

    cfg = tmp_path / "c.toml"
    cfg.write_text('[planner.raceline]\nline = "min_curvature"\nmargin_m = 0.7\n')
    code = main(
        [
            "--config",
            str(cfg),
            "--track",
            "paperlike",
            "--laps",
            "1",
            "--methods",
            "raceline",
            "--out",
            str(tmp_path / "out"),
            "--no-figures",
            "--no-reference",
        ]
    )
    assert code == 2
    assert "no room" in capsys.readouterr().err


# --------------------------------------------------------------------------- min-time line
def circle_lap(track: Track, radius: float, v: float, delta: float) -> MinTimeLap:
    """A stand-in for the minimum-time lap on a circle `track` of `radius` [m]: the line
    0.2 m outside the centreline at constant speed `v` [m/s] and steering `delta` [rad]."""
    r_line = radius + 0.2
    n = track.n_points
    ang = np.arange(n) * 2 * math.pi / n
    xy = r_line * np.column_stack([np.cos(ang), np.sin(ang)])
    chord = 2 * r_line * math.sin(math.pi / n)
    s = np.arange(n) * chord
    beta = np.full(n, -0.02)
    course = ang + math.pi / 2
    states = np.column_stack(
        [np.full(n, -0.2), -beta, np.full(n, v), beta, np.full(n, v / r_line), np.full(n, delta)]
    )
    inputs = np.column_stack([np.zeros(n), np.full(n, 1.0)])
    return MinTimeLap(
        lap_time_s=n * chord / v,
        status="Solve_Succeeded",
        success=True,
        iterations=1,
        solve_time_s=0.0,
        ds_m=track.length_m / n,
        v_max_mps=4.18,
        margin_m=0.02,
        tyre_model="linear_saturated",
        track_name=track.name,
        track_length_m=track.length_m,
        reference_length_m=track.length_m,
        s_ref_m=np.arange(n) * track.length_m / n,
        t_s=s / v,
        s_m=s,
        x_m=xy[:, 0],
        y_m=xy[:, 1],
        psi_rad=np.mod(course, 2 * math.pi),
        yaw_rad=course - beta,
        kappa_radpm=np.full(n, 1 / r_line),
        v_mps=np.full(n, v),
        ax_mps2=np.zeros(n),
        n_m=np.full(n, -0.2),
        states=states,
        inputs=inputs,
        min_clearance_m=0.05,
        point_mass_lap_time_s=n * chord / v,
    )


def test_the_default_line_is_the_min_time_lap_planned_within_the_car_s_lock() -> None:
    """``line = "min_time"``: the loader is asked for the car with its own steering range
    (``steering_range = "car"``) and ``[planner.raceline]``'s top speed, grid and margin;
    the line, its speeds and its steering become the raceline and the tracker's plan."""
    tr = circle(3.0, n=300, width=0.6)
    calls: list = []

    def loader(track, vehicle, settings):
        calls.append((track, vehicle, settings))
        return circle_lap(track, 3.0, 3.5, 0.15)

    # the line's own speeds from the first step (no cautious out lap, and no wider line
    # for that full-speed out lap)
    settings = PlannerSettings(method="raceline", raceline=RacelineSettings(
        start_speed_scale=1.0, out_lap_margin_m=0.0))
    planner = RacelinePlanner(tr, settings, min_time_loader=loader)
    ((track, car, mt),) = calls
    assert track is tr
    f = settings.raceline.min_time_steering_fraction  # the tracker's reserve of the lock
    assert (car.steering_min_rad, car.steering_max_rad) == pytest.approx(
        (f * F1TENTH_GYM.steering_min_rad, f * F1TENTH_GYM.steering_max_rad))
    assert planner._delta_lim == (F1TENTH_GYM.steering_min_rad, F1TENTH_GYM.steering_max_rad)
    assert mt == min_time_settings(settings.raceline)
    assert (mt.v_max_mps, mt.ds_m, mt.margin_m) == (4.18, 0.1, 0.02)
    rl = planner.raceline
    assert rl.kind == "min_time" and rl.min_time is not None
    np.testing.assert_allclose(rl.offset_m, -0.2, atol=2e-3)  # outside = right of a left turn
    np.testing.assert_allclose(rl.track.w_right_m, 0.4, atol=2e-3)
    np.testing.assert_allclose(rl.speed_mps, 3.5)
    assert rl.lap_time_s == pytest.approx(rl.min_time.lap_time_s)
    # on the line (rear axle l_r behind the CoG) the command is the lap's own
    lr = F1TENTH_GYM.lr_m
    s = 2.0
    cx, cy = rl.track.point_at(s)
    yaw = rl.reference.at("yaw", s)
    res = planner.step(cx - lr * math.cos(yaw), cy - lr * math.sin(yaw), yaw)
    assert res.status == SOLVED
    assert res.command.steering_rad == pytest.approx(0.15, abs=0.01)
    assert res.command.speed_mps == pytest.approx(
        3.5 + 1.0 / F1TENTH_GYM.speed_gain_accel_per_s, abs=0.01
    )


def test_the_planning_car_has_the_planner_s_steering_range() -> None:
    car = planning_vehicle(F1TENTH_GYM, (-0.35, 0.3))
    assert (car.steering_min_rad, car.steering_max_rad) == (-0.35, 0.3)
    assert car.mu == F1TENTH_GYM.mu and car.lr_m == F1TENTH_GYM.lr_m
    assert planning_vehicle(F1TENTH_GYM, (-1.0, 1.0)) is F1TENTH_GYM
    assert planning_vehicle(F1TENTH_GYM, None) is F1TENTH_GYM
    with pytest.raises(ValueError):
        planning_vehicle(F1TENTH_GYM, (0.1, 0.3))


def _race(track: Track, laps: int):
    from services.planner import ensure_artefacts
    from services.tools.bench import LoopOptions, run_method
    from shared.config import load_config

    cfg = load_config(None)
    ensure_artefacts("raceline", track, cfg.planner, cfg.vehicle)  # the tools' job
    planner = RacelinePlanner(track, cfg.planner, cfg.curvature, vehicle=cfg.vehicle)
    run = run_method("raceline", planner, track, cfg.simulator, LoopOptions(laps=laps))
    return planner, run


@pytest.mark.slow
@pytest.mark.parametrize("name", ["map416", "paperlike"])
def test_the_min_time_line_races_clean_laps_near_its_own_time(name: str, request) -> None:
    """The bench's closed loop (20 Hz, 2 ms compute delay, the simulator's delays): two
    flying laps, no off-track event, within 3 % of the planned lap (measured: +1.0 % on
    map416, +0.7 % on paperlike)."""
    track = load_track(
        request.getfixturevalue("shared_tracks") / "map416" if name == "map416" else "paperlike"
    )
    planner, run = _race(track, 2)
    plan = planner.raceline.lap_time_s
    assert run.completed_laps == 2 and not run.extra.get("aborted")
    assert run.run_off_track_events == 0 and planner.recovery.episodes == 0
    for lap in run.laps:
        assert plan * 0.999 < lap.lap_time_s < plan * 1.03
