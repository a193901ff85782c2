"""``benchmarks.stack_tests_hog``: a round that leaves a process of its tests running fails
and the process is stopped by its PID (an orphaned service at real-time priority disturbed
the next test run, issue 25); a clean round passes. The benchmark runs as its own process
(it makes itself the child subreaper, which the test process should not become)."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

from benchmarks.stack_tests_hog import _start_time, descendants

ROOT = Path(__file__).resolve().parents[2]

LEAKY = '''
import subprocess, sys
from pathlib import Path

def test_leaves_a_process_behind():
    child = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(300)"],
                             start_new_session=True)
    Path(r"{pidfile}").write_text(str(child.pid))
'''

CLEAN = '''
import subprocess, sys

def test_stops_what_it_starts():
    child = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(300)"])
    child.kill()
    child.wait(timeout=10)
'''


def _bench(test_file: Path, out: Path) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "benchmarks.stack_tests_hog", "--rounds", "1", "--no-hog",
         "--out", str(out), "--files", str(test_file)],
        cwd=ROOT, capture_output=True, text=True, timeout=180)


def test_a_round_that_leaves_a_process_running_fails_and_stops_it(tmp_path: Path) -> None:
    pidfile = tmp_path / "pid"
    leaky = tmp_path / "test_leaky.py"
    leaky.write_text(LEAKY.format(pidfile=pidfile), encoding="utf-8")
    done = _bench(leaky, tmp_path / "out")
    pid = int(pidfile.read_text())
    try:
        assert done.returncode == 1, done.stdout + done.stderr
        assert "round 1: FAIL" in done.stdout and "1 processes left running" in done.stdout
        assert _start_time(pid) is None  # stopped by its PID, and reaped
        assert "1 passed" in (tmp_path / "out" / "round-1.txt").read_text()
    finally:
        if _start_time(pid) is not None:
            os.kill(pid, 9)


def test_a_clean_round_passes(tmp_path: Path) -> None:
    clean = tmp_path / "test_clean.py"
    clean.write_text(CLEAN, encoding="utf-8")
    done = _bench(clean, tmp_path / "out")
    assert done.returncode == 0, done.stdout + done.stderr
    assert "round 1: PASS" in done.stdout and "1/1 rounds passed" in done.stdout


def test_descendants_name_children_and_theirs() -> None:
    code = ("import subprocess, sys, time; c = subprocess.Popen([sys.executable, '-c', "
            "'import time; time.sleep(60)']); print(c.pid, flush=True); time.sleep(60)")
    parent = subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE, text=True)
    grandchild = None
    try:
        grandchild = int(parent.stdout.readline())
        found = descendants(os.getpid())
        assert parent.pid in found and grandchild in found
        assert found[grandchild] == _start_time(grandchild)
    finally:
        if grandchild is not None:
            os.kill(grandchild, 9)
        parent.kill()
        parent.wait(timeout=10)
