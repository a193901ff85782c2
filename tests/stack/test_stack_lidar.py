"""``racestack up`` localised by the bridge's own lidar particle filter (issue 13): three laps
on map416 with ``[localization] pose_source = "lidar"`` (the simulator's scans at 40 Hz, no
``vehicle/pose`` used) and no off-track event. Skips without ../shared."""

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


def test_racestack_up_races_three_laps_on_the_lidar_filter(
    tmp_path: Path, shared_tracks: Path
) -> None:
    cfg = tmp_path / "lidar.toml"
    cfg.write_text(
        f'[bus]\nlisten = ["tcp/127.0.0.1:{free_loopback_port()}"]\n'
        f'[track]\nsource = "{shared_tracks / "map416"}"\n'
        '[localization]\npose_source = "lidar"\n'
        "[simulator.lidar]\nrate_hz = 40.0\n",
        encoding="utf-8",
    )
    env = {**os.environ, "XDG_CONFIG_HOME": str(tmp_path / "xdg")}
    proc = subprocess.Popen(
        [sys.executable, "-m", "services.tools.cli", "up", "--laps", "3", "--config", str(cfg),
         "--run-dir", str(tmp_path / "run")],
        cwd=ROOT, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
    )
    try:
        out, _ = proc.communicate(timeout=300)
    finally:
        stop_process(proc, grace_s=20.0)
    assert proc.returncode == 0, out
    laps = re.findall(r"lap (\d+): (\d+\.\d+) s, .* off-track (\d+)", out)
    assert len(laps) >= 3, out
    assert all(int(off) == 0 for _, _, off in laps[:3]), out
    assert "completed laps         3/3" in out, out
