"""Issue #22, first steps with ``racestack up``: hints that run as printed, a quiet console
(the log in the run folder), ``--track``/``--method``, one wording of ``--laps 0``, the out
lap before the timed laps."""

from __future__ import annotations

import argparse
import io
import logging
import os
import stat
import sys
from pathlib import Path

import pytest

import services.tools.launcher as launcher
from services.simulator.laps import LapTimer, centreline_pose
from services.simulator.service import START_OFFSET_M
from services.tools.bench import LoopOptions
from services.tools.bench import main as bench_main
from services.tools.bench.run import build_parser as bench_parser
from services.tools.cli import main as racestack
from services.tools.launcher import up
from shared.commands import racestack_command, runnable
from shared.config import RacestackConfig
from shared.config.localization import LocalizationSettings
from shared.config.methods import CIMPCC, MPCC
from shared.config.vehicle import F1TENTH_GYM
from shared.evaluation.results import OUT_LAP_START_M
from shared.track import load_track


# ---------------------------------------------------------------- 1. runnable hints
def _venv(tmp_path: Path, *scripts: str) -> Path:
    """A fake ``.venv/bin`` under `tmp_path` with `scripts` in it; returns its python."""
    bin_dir = tmp_path / ".venv" / "bin"
    bin_dir.mkdir(parents=True)
    for name in ("python", *scripts):
        path = bin_dir / name
        path.write_text("#!/bin/sh\n")
        path.chmod(path.stat().st_mode | stat.S_IXUSR)
    return bin_dir / "python"


def test_the_closing_hint_names_the_venv_scripts_when_they_are_not_on_path(
    tmp_path: Path, monkeypatch
) -> None:
    """After ``make demo`` (.venv/bin not on PATH) the hints say ``.venv/bin/rerun`` and
    ``.venv/bin/racestack``: a bare ``rerun`` would be 'command not found'."""
    python = _venv(tmp_path, "rerun", "racestack")
    monkeypatch.setattr(sys, "executable", str(python))
    monkeypatch.setenv("PATH", "/usr/bin:/bin")
    monkeypatch.chdir(tmp_path)
    hint = up.closing_hint(Path("runs/20261202-101010"))
    assert hint == (
        "recording: runs/20261202-101010/telemetry.*.rrd (open: .venv/bin/rerun "
        "runs/20261202-101010/telemetry.*.rrd; figures: .venv/bin/racestack report "
        "runs/20261202-101010)"
    )


def test_a_script_on_path_is_named_bare_and_one_outside_the_folder_by_its_full_path(
    tmp_path: Path, monkeypatch
) -> None:
    python = _venv(tmp_path, "rerun")
    monkeypatch.setenv("PATH", f"{python.parent}{os.pathsep}/usr/bin")
    assert runnable("rerun", str(python)) == "rerun"  # the one on PATH is this one
    monkeypatch.setenv("PATH", "/usr/bin:/bin")
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    assert runnable("rerun", str(python), cwd=elsewhere) == str(python.parent / "rerun")
    assert runnable("nosuchscript", str(python)) == "nosuchscript"  # not beside it: bare


def test_without_a_racestack_script_the_hint_is_python_dash_m(
    tmp_path: Path, monkeypatch
) -> None:
    python = _venv(tmp_path)  # python alone (the repository run from a checkout)
    monkeypatch.setenv("PATH", "/usr/bin:/bin")
    assert racestack_command(str(python), cwd=tmp_path) == (
        ".venv/bin/python -m services.tools.cli")


def test_the_watch_live_line_names_a_runnable_rerun(tmp_path: Path, monkeypatch) -> None:
    python = _venv(tmp_path, "rerun")
    monkeypatch.setattr(sys, "executable", str(python))
    monkeypatch.setenv("PATH", "/usr/bin:/bin")
    monkeypatch.chdir(tmp_path)
    log = tmp_path / "telemetry.log"
    log.write_text("telemetry: watch live with: rerun --connect rerun+http://127.0.0.1:9/proxy\n")
    assert up._connect_line(log, 1.0) == (
        "watch live with: nice -n 10 .venv/bin/rerun --connect rerun+http://127.0.0.1:9/proxy")


# ---------------------------------------------------------------- 2. a quiet console
def test_the_console_of_up_shows_only_warnings_in_one_short_line() -> None:
    out = io.StringIO()
    launcher.console_logging(False, stream=out)
    try:
        logging.getLogger("services.tools.launcher.supervisor").info("started planner (pid 1)")
        logging.getLogger("shared.bus").warning("the hub is slow")
        assert out.getvalue() == "racestack up: warning: the hub is slow\n"
        verbose = io.StringIO()
        launcher.console_logging(True, stream=verbose)
        logging.getLogger("x.y").debug("detail")
        line = verbose.getvalue()
        assert line.endswith(" DEBUG x.y: detail\n") and line[:4].isdigit()  # a timestamp
    finally:
        logging.getLogger().handlers.clear()


def test_the_run_log_keeps_the_info_lines_with_their_timestamps(tmp_path: Path) -> None:
    launcher.console_logging(False, stream=io.StringIO())
    handler = up.run_log(tmp_path / "logs" / "launcher.log")
    try:
        logging.getLogger("services.tools.launcher.supervisor").info("started planner (pid 1)")
    finally:
        logging.getLogger().removeHandler(handler)
        handler.close()
        logging.getLogger().handlers.clear()
    text = (tmp_path / "logs" / "launcher.log").read_text()
    assert text.rstrip().endswith(
        "INFO services.tools.launcher.supervisor: started planner (pid 1)")
    assert text[:4].isdigit()


def test_racestack_up_sets_the_quiet_console_and_passes_the_overrides(
    monkeypatch, capsys
) -> None:
    seen = {}

    def fake_run_up(cfg, opts, stop_requested=None) -> int:
        logging.getLogger("services.tools.launcher.supervisor").info("started x (pid 1)")
        logging.getLogger("services.tools.launcher").warning("a warning")
        seen.update(cfg=cfg, opts=opts)
        return 0

    monkeypatch.setattr(launcher, "run_up", fake_run_up)
    try:
        assert racestack(["up", "--track", "gentle", "--method", MPCC, "--laps", "1"]) == 0
    finally:
        logging.getLogger().handlers.clear()
    err = capsys.readouterr().err
    assert err == "racestack up: warning: a warning\n"
    cfg, opts = seen["cfg"], seen["opts"]
    assert cfg.track.source == "gentle" and cfg.planner.method == MPCC
    assert opts.config_data == {"track": {"source": "gentle"}, "planner": {"method": MPCC}}
    assert opts.verbose is False and opts.laps == 1


# ---------------------------------------------------------------- 5. --track, --method
def test_up_config_keeps_the_file_and_replaces_the_two_values(tmp_path: Path) -> None:
    config = tmp_path / "my.toml"
    config.write_text('[track]\nsource = "paperlike"\n[planner]\nmethod = "cimpcc"\n'
                      "dt_s = 0.05\n[simulator]\nintegration_step_s = 0.001\n")
    cfg, data = launcher.up_config(str(config), track="gentle", method=MPCC)
    assert cfg.track.source == "gentle" and cfg.planner.method == MPCC
    assert data["planner"]["dt_s"] == 0.05 and data["simulator"] == {"integration_step_s": 0.001}
    same, none = launcher.up_config(str(config))
    assert none is None and same.planner.method == CIMPCC


def test_up_with_an_unknown_method_or_track_is_one_line_and_nothing_starts(
    tmp_path: Path, monkeypatch, capsys
) -> None:
    opened = []
    monkeypatch.setattr(up.Launcher, "open_bus", lambda *a, **k: opened.append(1))
    with pytest.raises(SystemExit) as info:
        racestack(["up", "--method", "pid"])
    err = capsys.readouterr().err
    assert info.value.code == 2 and err.count("\n") == 1 and "--method" in err
    run_dir = tmp_path / "run"
    try:
        code = racestack(["up", "--track", "nosuchtrack", "--run-dir", str(run_dir)])
    finally:
        logging.getLogger().handlers.clear()
    err = capsys.readouterr().err
    assert code == 2 and err.count("\n") == 1 and "nosuchtrack" in err
    assert opened == [] and not run_dir.exists()


class _FakeBus:
    """Stands in for the launcher's bus (no Zenoh session): listens on one endpoint."""

    settings = type("S", (), {"listen": ["tcp/127.0.0.1:1"]})()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        return None


def test_the_services_read_the_config_with_the_overrides(tmp_path: Path, monkeypatch) -> None:
    """With --track/--method ``up`` writes RUN/config.toml and starts the services with it."""
    written = {}

    def no_race(cfg, opts, bus, track, run_dir, stop_requested) -> int:
        written["path"] = opts.config_path
        return 0

    monkeypatch.setattr(up.Launcher, "open_bus", lambda *a, **k: _FakeBus())
    monkeypatch.setattr(up, "_unreachable_hub", lambda cfg, services: [])
    monkeypatch.setattr(up, "_race", no_race)
    cfg, data = launcher.up_config(None, track="gentle", method=MPCC)
    opts = up.UpOptions(config_path=None, run_dir=tmp_path / "run", config_data=data,
                        services=("simulator",))
    assert up.run_up(cfg, opts) == 0
    assert written["path"] == str(tmp_path / "run" / "config.toml")
    from shared.config import load_config

    back = load_config(written["path"])
    assert back.track.source == "gentle" and back.planner.method == MPCC


# ---------------------------------------------------------------- 7. --laps 0, one wording
WORDING = "argument --laps: must be a whole number >= 1, got 0"


@pytest.mark.parametrize("command", ["up", "demo", "bench", "laps"])
def test_laps_zero_is_worded_alike_by_every_command(command: str, capsys) -> None:
    with pytest.raises(SystemExit) as info:
        racestack([command, "--laps", "0"])
    err = capsys.readouterr().err
    assert info.value.code == 2
    assert err == f"racestack {command}: error: {WORDING} (see racestack {command} --help)\n"


def test_laps_zero_passed_on_in_code_is_worded_alike_too(tmp_path: Path, capsys) -> None:
    assert up.run_up(RacestackConfig(), up.UpOptions(config_path=None, laps=0,
                                                     run_dir=tmp_path / "r")) == 2
    assert capsys.readouterr().err == f"racestack up: error: {WORDING}\n"
    args = bench_parser(argparse.ArgumentParser()).parse_args(["--no-figures"])
    args.laps = 0
    assert bench_main(args=args) == 2
    assert capsys.readouterr().err == f"racestack bench: error: {WORDING}\n"


# ---------------------------------------------------------------- 8. the out lap
def test_up_starts_where_the_bench_does_so_lap_1_is_a_flying_lap() -> None:
    assert START_OFFSET_M == OUT_LAP_START_M == LoopOptions().start_offset_m > 0.0
    track = load_track("paperlike")
    timer = LapTimer(track)
    x, y, yaw = centreline_pose(track, START_OFFSET_M)
    timer.update(0.0, x, y, yaw, 0.0)
    assert not timer.timing  # past the line: no START until the car comes round
    events = []
    for k, s in enumerate(range(1, round(track.length_m) + 2)):  # drive round at 1 m per tick
        x, y, yaw = centreline_pose(track, START_OFFSET_M + s)
        events += timer.update(0.1 * (k + 1), x, y, yaw, 10.0)
    assert [e.kind for e in events] == ["start"]  # the out lap ended: timing starts


def test_the_lidar_filter_starts_where_the_simulated_car_does() -> None:
    rear_axle = START_OFFSET_M - F1TENTH_GYM.lr_m
    assert LocalizationSettings().start_s_m == pytest.approx(rear_axle, abs=0.01)


def test_the_progress_line_of_the_out_lap() -> None:
    assert up.lap_progress_line(0, 3, 12.34, 32.77, 3.214) == (
        "out lap: 12.3 of 32.8 m (38 %), 3.21 m/s")
    assert up.lap_progress_line(1, 3, 1.0, 32.77, 3.0).startswith("lap 1/3: ")


def test_up_takes_the_hub_s_priority_only_when_asked_and_hosting_the_hub(
        tmp_path: Path, monkeypatch) -> None:
    """``racestack up`` (``hub_priority``) schedules the launcher as ``[processes.router]``
    before the bus opens; called in a test's own process (the default) it changes nothing."""
    order: list[str] = []

    def opened(*a, **k):
        order.append("bus")
        return _FakeBus()

    def applied(settings):
        order.append(settings)
        return type("R", (), {"warnings": [], "notes": []})()

    monkeypatch.setattr(up.Launcher, "open_bus", opened)
    monkeypatch.setattr(up, "_unreachable_hub", lambda cfg, services: [])
    monkeypatch.setattr(up, "_race", lambda *a: 0)
    monkeypatch.setattr(up, "apply_priority", applied)
    cfg = RacestackConfig()
    for asked, expected in ((False, ["bus"]), (True, [cfg.processes.router, "bus"])):
        order.clear()
        opts = up.UpOptions(config_path=None, run_dir=tmp_path / f"run{asked}",
                            services=("simulator",), hub_priority=asked)
        assert up.run_up(cfg, opts) == 0
        assert order == expected
