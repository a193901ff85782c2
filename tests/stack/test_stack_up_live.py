"""Issue #16 on the real stack: ``racestack up --serve PORT`` prints the viewer's connect line
on the terminal, shows lap progress and speed while it races, and Ctrl-C prints the table
of the laps finished so far, then stops every service (exit code 130)."""

from __future__ import annotations

import os
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from services.tools.launcher.supervisor import stop_process
from shared.net import free_loopback_port

pytestmark = pytest.mark.slow
ROOT = Path(__file__).resolve().parents[2]


def _gone(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return True
    return False


def test_up_serve_line_progress_and_ctrl_c_table(tmp_path: Path) -> None:
    cfg = tmp_path / "up.toml"
    cfg.write_text(f'[bus]\nlisten = ["tcp/127.0.0.1:{free_loopback_port()}"]\n')
    serve = free_loopback_port()
    env = {**os.environ, "XDG_CONFIG_HOME": str(tmp_path / "xdg"),
           "XDG_DATA_HOME": str(tmp_path / "xdg")}
    proc = subprocess.Popen(
        [sys.executable, "-m", "services.tools.cli", "up", "--laps", "3", "--serve", str(serve),
         "--config", str(cfg), "--run-dir", str(tmp_path / "run")],
        cwd=ROOT, env=env, stdin=subprocess.DEVNULL, stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT, text=True,
    )
    lines: list[str] = []
    try:
        deadline = time.monotonic() + 240
        assert proc.stdout is not None
        while time.monotonic() < deadline:
            line = proc.stdout.readline()
            if not line:
                break
            lines.append(line)
            if re.match(r"lap 1: \d", line):
                break
        proc.send_signal(signal.SIGINT)  # Ctrl-C after the first lap
        rest, _ = proc.communicate(timeout=60)
    finally:
        stop_process(proc, grace_s=20.0)
    out = "".join(lines) + rest
    assert proc.returncode == 130, out
    assert f"rerun --connect rerun+http://127.0.0.1:{serve}/proxy" in out, out
    progress = r"(?:out lap|lap \d/3): \d+\.\d of \d+\.\d m \(\d+ %\), \d+\.\d\d m/s"
    assert re.search(progress, out), out
    assert "interrupted" in out and "completed laps" in out and "1/3" in out, out
    assert out.index("completed laps") < out.index("\nstopping the stack\n")  # table first
    print(out)  # seen with -s
    log = (tmp_path / "run" / "logs" / "launcher.log").read_text()  # the console is quiet
    pids = [int(p) for p in re.findall(r"started \w+ \(pid (\d+)\)", log)]
    assert len(pids) == 4 and all(_gone(pid) for pid in pids), log
