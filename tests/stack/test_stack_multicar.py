"""``racestack up --cars 2 --laps 1`` as a user runs it (issue #24): one simulator for both
cars, a bridge, planner and telemetry per car, both cars complete their lap, one lap table
with a column per car and the incidents are printed, and every process the launcher started
is gone after (stopped by PID with a timeout)."""

from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

from services.tools.launcher.supervisor import stop_process
from shared.net import free_loopback_port

pytestmark = pytest.mark.slow
ROOT = Path(__file__).resolve().parents[2]


def gone(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return True
    return False


def test_two_cars_race_a_lap_each_over_zenoh_as_processes(tmp_path: Path) -> None:
    cfg = tmp_path / "up.toml"
    cfg.write_text(f'[bus]\nlisten = ["tcp/127.0.0.1:{free_loopback_port()}"]\n')
    run_dir = tmp_path / "run"
    env = {**os.environ, "XDG_CONFIG_HOME": str(tmp_path / "xdg"),
           "XDG_DATA_HOME": str(tmp_path / "xdg")}
    proc = subprocess.Popen(
        [sys.executable, "-m", "services.tools.cli", "up", "--cars", "2", "--laps", "1",
         "--config", str(cfg), "--run-dir", str(run_dir)],
        cwd=ROOT, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
    )
    try:
        out, _ = proc.communicate(timeout=420)
    finally:
        stop_process(proc, grace_s=20.0)
    assert proc.returncode == 0, out
    text = (run_dir / "logs" / "launcher.log").read_text()
    pids = {m[0]: int(m[1]) for m in re.findall(r"started ([\w.]+) \(pid (\d+)\)", text)}
    assert set(pids) == {"simulator", "localization_bridge", "planner", "telemetry",
                         "localization_bridge.car1", "planner.car1", "telemetry.car1"}, out
    assert all(gone(pid) for pid in pids.values()), out
    assert "all services alive: racing 2 cars" in out
    assert re.search(r"^car0 lap 1: \d+\.\d+ s", out, re.M), out
    assert re.search(r"^car1 lap 1: \d+\.\d+ s", out, re.M), out
    # one table, a column per car (the second at 0.85 of its speed commands)
    assert "car0 (cimpcc)" in out and "car1 (cimpcc x0.85)" in out, out
    assert "completed laps" in out and re.search(r"^incidents: \d+ contact", out, re.M), out
    # each car's own configuration and recording
    assert 'car = "car1"' in (run_dir / "config.car1.toml").read_text()
    assert (run_dir / "car0").is_dir() and (run_dir / "car1").is_dir()
    # the bridges tracked opponents from their scans and said what it cost
    bridge = (run_dir / "logs" / "localization_bridge.car1.log").read_text()
    assert re.search(r"opponents: [1-9]\d* scans, \d+ detections", bridge), bridge[-2000:]
