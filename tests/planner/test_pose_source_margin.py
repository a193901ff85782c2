"""Every planner plans the raceline's line with the pose source's margin
(``services.planner.for_pose_source`` / ``for_stack``): the bench on
``--estimator truth|ekf|lidar``, the planner service and ``racestack mintime --for raceline`` on
``[localization] pose_source``; and all of them key the same lap."""

from __future__ import annotations

import argparse
import threading
from pathlib import Path

import pytest

from services.planner import for_pose_source, raceline_request
from shared.config import config_from_dict
from shared.config.methods import RACELINE

#: Margins that no default has, so the test sees them arrive.
MARGINS = {"planner": {"raceline": {"truth_margin_m": 0.004, "ekf_margin_m": 0.011,
                                    "lidar_margin_m": 0.033}}}


class StoppedError(Exception):
    """Raised by the fakes once they have seen what they were given."""


def _margin(pose: str) -> float:
    cfg = config_from_dict(MARGINS)
    return for_pose_source(cfg.planner, pose).raceline.min_time_margin_m


@pytest.mark.parametrize("estimator", ["truth", "ekf", "lidar"])
def test_the_bench_builds_its_planners_for_the_pose_they_see(
    estimator: str, monkeypatch, tmp_path: Path
) -> None:
    from services.tools.bench import run
    from services.tools.bench.closed_loop import LoopOptions

    seen = []

    def fake_ensure(method, track, settings, vehicle=None, **_kwargs):
        seen.append(settings.raceline.min_time_margin_m)
        raise StoppedError

    monkeypatch.setattr(run, "ensure_artefacts", fake_ensure)
    cfg = config_from_dict(MARGINS)
    with pytest.raises(StoppedError):
        run.run_bench(cfg, "paperlike", [RACELINE], 1, tmp_path,
                      LoopOptions(laps=1, estimator=estimator), [], 1, figures=False,
                      reference=False)
    base = cfg.planner.raceline.min_time_margin_m
    want = {"truth": base + 0.004, "ekf": base + 0.011, "lidar": base + 0.033}[estimator]
    assert seen == [pytest.approx(want)] and _margin(estimator) == pytest.approx(want)


@pytest.mark.parametrize(("pose_source", "pose"), [("external", "ekf"), ("lidar", "lidar")])
def test_the_planner_service_plans_for_its_pose_source(pose_source: str, pose: str,
                                                       monkeypatch) -> None:
    import services.planner.service as service

    seen = []

    def fake_make_planner(track, settings, curvature, vehicle=None, **_kwargs):
        seen.append(settings.raceline.min_time_margin_m)
        raise StoppedError

    monkeypatch.setattr(service, "make_planner", fake_make_planner)
    cfg = config_from_dict({**MARGINS, "localization": {"pose_source": pose_source}})
    with pytest.raises(StoppedError):
        service.run(cfg, argparse.Namespace(config=None), threading.Event())
    assert seen == [pytest.approx(_margin(pose))]


def test_racestack_mintime_makes_the_lap_the_stack_s_planner_reads(
    tmp_path: Path, monkeypatch
) -> None:
    import services.tools.mintime as mintime

    seen = []

    def fake_make(track, vehicle, settings, *_args, **_kwargs):
        seen.append(settings)
        raise StoppedError

    monkeypatch.setattr(mintime, "make_min_time_lap", fake_make)
    config = tmp_path / "lidar.toml"
    config.write_text('[localization]\npose_source = "lidar"\n[planner.raceline]\n'
                      'lidar_margin_m = 0.033\n', encoding="utf-8")
    with pytest.raises(StoppedError):
        mintime.main(["--for", RACELINE, "--config", str(config), "--track", "paperlike",
                      "--out", str(tmp_path / "out")])
    cfg = config_from_dict({"localization": {"pose_source": "lidar"},
                            "planner": {"raceline": {"lidar_margin_m": 0.033}}})
    want = raceline_request(for_pose_source(cfg.planner, "lidar"), cfg.vehicle).settings
    assert seen == [want]
    assert want.margin_m == pytest.approx(cfg.planner.raceline.min_time_margin_m + 0.033)


def test_cimpcc_line_reads_its_speed_from_filtered_poses_with_the_source_s_gain() -> None:
    """``cimpcc-line``'s speed estimate on the EKF's or the lidar's poses leans on its speed
    loop (``[planner.cimpcc_line] ekf_speed_estimate_gain`` / ``lidar_...``); on the true
    pose it is the displacement alone (the configured ``speed_estimate_gain``, 1)."""
    cfg = config_from_dict({"planner": {"cimpcc_line": {"ekf_speed_estimate_gain": 0.45,
                                                        "lidar_speed_estimate_gain": 0.25}}})
    gains = {pose: for_pose_source(cfg.planner, pose).cimpcc_line.speed_estimate_gain
             for pose in ("truth", "ekf", "lidar")}
    assert gains == {"truth": 1.0, "ekf": 0.45, "lidar": 0.25}
    # exact poses: the truth tube, the rest the configuration's own
    truth = for_pose_source(cfg.planner, "truth")
    assert truth.model_copy(update={"raceline": cfg.planner.raceline}) == cfg.planner
    no_tube = cfg.planner.model_copy(update={"raceline": cfg.planner.raceline.model_copy(
        update={"truth_margin_m": 0.0})})
    assert for_pose_source(no_tube, "truth") is no_tube
    # the raceline's margin comes along with it, and nothing else changes
    ekf = for_pose_source(cfg.planner, "ekf")
    assert ekf.raceline.min_time_margin_m == pytest.approx(
        cfg.planner.raceline.min_time_margin_m + cfg.planner.raceline.ekf_margin_m)
    assert ekf.cimpcc_line.model_copy(update={"speed_estimate_gain": 1.0}) == (
        cfg.planner.cimpcc_line)
