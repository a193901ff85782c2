"""The raceline baseline: minimum-curvature offsets, the speed profile, the pursuit tracker."""

from __future__ import annotations

import math

import numpy as np
import pytest

from services.planner.model import discretise, kinematic_bicycle, step_numpy
from services.planner.planner import BRAKING, SOLVED
from services.planner.raceline import (
    RacelinePlanner,
    build_raceline,
    min_curvature_offsets,
    resample,
    speed_profile,
)
from shared.config.planner import PlannerSettings, RacelineSettings
from shared.track import Track, load_track


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
    s = RacelineSettings()
    rl = build_raceline(tr, s)
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


def test_pure_pursuit_laps_the_default_track_inside_against_the_model() -> None:
    tr = load_track("paperlike")
    settings = PlannerSettings()
    planner = RacelinePlanner(tr, settings)
    F = discretise(kinematic_bicycle(settings.wheelbase_m), settings.dt_s)
    x = np.array([*tr.xy[0], tr.heading_rad[0], 0.0])
    progress, s_last, L = 0.0, 0.0, tr.length_m
    w_min = float(min(tr.w_right_m.min(), tr.w_left_m.min()))
    for _ in range(600):
        res = planner.step(*x[:3])
        assert res.status == SOLVED and res.method == "raceline"
        assert abs(res.command.steering_rad) <= settings.bounds.delta_rad[1] + 1e-12
        assert abs(res.e_con_m) < w_min - 0.15  # the car's half-width stays inside
        assert res.states.shape == (settings.horizon_steps + 1, 4)
        progress += (res.s_m - s_last + L / 2) % L - L / 2
        s_last = res.s_m
        if progress >= L:
            break
        x = step_numpy(F, x, np.array([res.command.speed_mps, res.command.steering_rad, 0.0]))
    assert progress >= L


def test_a_bad_pose_gives_a_braking_command() -> None:
    planner = RacelinePlanner(load_track("paperlike"), PlannerSettings())
    res = planner.step(math.nan, 0.0, 0.0)
    assert res.status == BRAKING and res.command.speed_mps == 0.0
    assert np.isfinite(res.states).all() and np.isfinite(res.beta).all()


def test_a_margin_wider_than_the_track_is_an_error() -> None:
    with pytest.raises(ValueError, match="margin"):
        build_raceline(load_track("paperlike"), RacelineSettings(margin_m=0.7))


def test_the_planner_service_can_run_the_baseline() -> None:
    """``[planner] method = "raceline"`` builds the baseline, and its results make valid
    ``planner/plan`` records (what the service publishes)."""
    from services.planner.methods import make_planner
    from services.planner.planner import Planner
    from services.planner.service import plan_message

    tr = load_track("paperlike")
    planner = make_planner(tr, PlannerSettings(method="raceline"))
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
    s = RacelineSettings()
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
    from services.bench.run import main

    cfg = tmp_path / "c.toml"
    cfg.write_text("[planner.raceline]\nmargin_m = 0.7\n")
    code = main(["--config", str(cfg), "--track", "paperlike", "--laps", "1",
                 "--methods", "raceline", "--out", str(tmp_path / "out"), "--no-figures"])
    assert code == 2
    assert "no room" in capsys.readouterr().err
