"""``racestack up`` as a user runs it: the whole stack, a lap, the table, a recording.

Issue 4 (one command) and issue 5 (the recording of a real run read back). The launcher is
started as a real process on a free loopback port; every PID it reports must be gone after.
"""

from __future__ import annotations

import os
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pyarrow as pa
import pytest
import rerun as rr

from services.telemetry import find_segments
from services.tools.launcher.supervisor import stop_process
from services.tools.report import lap_events, read_recording
from shared.net import free_loopback_port

pytestmark = pytest.mark.slow
ROOT = Path(__file__).resolve().parents[2]


def write_config(tmp: Path) -> Path:
    cfg = tmp / "up.toml"
    cfg.write_text(f'[bus]\nlisten = ["tcp/127.0.0.1:{free_loopback_port()}"]\n')
    return cfg


def launcher(args: list[str], tmp: Path) -> subprocess.Popen[str]:
    env = {**os.environ, "XDG_CONFIG_HOME": str(tmp / "xdg"), "XDG_DATA_HOME": str(tmp / "xdg")}
    return subprocess.Popen(
        [sys.executable, "-m", "services.tools.cli", "up", *args],
        cwd=ROOT,
        env=env,
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
    )


def started_pids(run_dir: Path) -> dict[str, int]:
    """The services the launcher started, by PID, from its log (RUN/logs/launcher.log: the
    console shows only warnings)."""
    text = (run_dir / "logs" / "launcher.log").read_text()
    return {m[0]: int(m[1]) for m in re.findall(r"started (\w+) \(pid (\d+)\)", text)}


def gone(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return True
    return False


def monotone_in_file(path: Path, entity: str) -> int:
    """Rows of `entity` in file order; asserts the message time never goes back.

    Stamps of the real stack are wall-clock, so the recorder uses its wall_time timeline
    (sim_time for simulation-time stamps)."""
    store = rr.chunk.RrdReader(str(path)).stream().collect()
    last, rows = -np.inf, 0
    for chunk in store.stream():
        if chunk.entity_path.lstrip("/") != entity:
            continue
        rb = chunk.to_record_batch()
        timeline = next((n for n in ("wall_time", "sim_time") if n in rb.schema.names), None)
        if timeline is None:
            continue  # a static chunk
        t = rb.column(timeline).cast(pa.int64()).to_numpy(zero_copy_only=False) / 1e9
        assert np.all(np.diff(t) >= 0) and t[0] >= last, entity
        last, rows = t[-1], rows + len(t)
    return rows


def test_racestack_up_races_a_lap_records_it_and_stops_everything(tmp_path: Path) -> None:
    run_dir = tmp_path / "run"
    proc = launcher(
        ["--laps", "1", "--config", str(write_config(tmp_path)), "--run-dir", str(run_dir)],
        tmp_path,
    )
    try:
        out, _ = proc.communicate(timeout=180)
    finally:
        stop_process(proc, grace_s=20.0)
    assert proc.returncode == 0, out
    pids = started_pids(run_dir)
    assert set(pids) == {"simulator", "localization_bridge", "planner", "telemetry"}, out
    assert all(gone(pid) for pid in pids.values()), out
    assert "all services alive: racing" in out
    assert re.search(r"lap 1: \d+\.\d+ s, .* off-track 0", out), out
    # the out lap first (issue 22): untimed, then lap 1 is a flying lap
    assert out.index("out lap done: timing 1 lap") < out.index("lap 1: "), out
    assert " INFO " not in out  # the log lines are in the run's log, not on the console
    assert "Lap time [s]" in out and "completed laps         1/1" in out
    # the CPU of each process over the race, beside the table (issue 25)
    assert "CPU over the race (" in out, out
    for name in (*pids, "launcher (with the hub)", "all"):
        assert re.search(rf"^  {re.escape(name)} +\d+\.\d\d s +\d+\.\d %", out, re.M), out

    # the recording of the real run (issue 5)
    data = read_recording(run_dir)
    assert data.complete  # the telemetry service closed its file on the launcher's SIGINT
    centre = np.asarray(data.static["world/track/centerline"]["LineStrips2D:strips"][0])
    assert centre.shape[0] > 1000 and centre.shape[1] == 2  # the 42 m paperlike track
    assert "world/track/left" in data.static and "world/track/right" in data.static
    laps = [e for e in lap_events(data) if e["kind"] == "lap"]
    assert len(laps) == 1 and 5.0 < laps[0]["lap_time_s"] < 20.0  # a flying lap
    assert laps[0]["off_track_events"] == 0
    t_speed, speed = data.series["speed/measured"]
    assert speed.max() > 3.0 and speed.min() >= -0.1 and speed.max() < 6.0
    _, solve = data.series["solver/solve_time_ms"]
    assert 0.0 < np.median(solve) < 20.0 and solve.size > 100
    # one lap in real time: the series span about the lap and start where the race did
    assert t_speed[-1] - t_speed[0] > laps[0]["lap_time_s"] * 0.9
    rrd = find_segments(run_dir)[0]  # the first segment (one a minute): the whole lap
    assert monotone_in_file(rrd, "world/car") > 100
    assert monotone_in_file(rrd, "world/plan/horizon") > 100
    assert (run_dir / "logs" / "planner.log").exists()


def test_ctrl_c_stops_every_service(tmp_path: Path) -> None:
    proc = launcher(
        [
            "--laps",
            "50",
            "--config",
            str(write_config(tmp_path)),
            "--run-dir",
            str(tmp_path / "run"),
        ],
        tmp_path,
    )
    lines: list[str] = []
    try:
        deadline = time.monotonic() + 150
        assert proc.stdout is not None
        while time.monotonic() < deadline:
            line = proc.stdout.readline()
            if not line:
                break
            lines.append(line)
            if "all services alive: racing" in line:
                break
        assert any("all services alive" in line for line in lines), "".join(lines)
        time.sleep(2.0)
        proc.send_signal(signal.SIGINT)
        rest, _ = proc.communicate(timeout=30)
    finally:
        stop_process(proc, grace_s=20.0)
    out = "".join(lines) + rest
    assert proc.returncode == 130, out
    pids = started_pids(tmp_path / "run")
    assert len(pids) == 4
    assert all(gone(pid) for pid in pids.values()), out
