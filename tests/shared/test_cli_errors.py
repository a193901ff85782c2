"""Issue #16: every bad start of a command is ONE clear line on stderr, exit code 2, nothing
started, no folder left behind, no traceback.

The argument errors run ``services.tools.cli.main`` in this process; the cases that open a Zenoh
session (a busy hub port, a hub nobody can reach) run the real command as a subprocess
(slow-marked) so that everything it prints is seen. A busy port is a plain TCP socket
bound here: no stack has to run.
"""

from __future__ import annotations

import argparse
import io
import os
import signal
import socket
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from pathlib import Path

import pytest

from services.tools import cli
from shared.config import BusSettings
from shared.net import free_loopback_port
from shared.outdir import missing_dirs, remove_empty_dirs, writable_dir_problem
from shared.service_shell import (
    HubWatch,
    hub_endpoints,
    positive_int,
    unreachable_hub_line,
)

ROOT = Path(__file__).resolve().parents[2]
CMD_TIMEOUT_S = 180.0


def _cli(argv: list[str], capsys: pytest.CaptureFixture[str]) -> tuple[int, str, str]:
    try:
        code = cli.main(argv)
    except SystemExit as exc:  # argparse
        code = exc.code if isinstance(exc.code, int) else 1
    out, err = capsys.readouterr()
    return code, out, err


def _one_line(err: str) -> str:
    lines = [ln for ln in err.splitlines() if ln.strip()]
    assert len(lines) == 1, f"expected one line on stderr, got:\n{err}"
    assert "Traceback" not in err
    return lines[0]


def _run(args: list[str], timeout_s: float = CMD_TIMEOUT_S) -> subprocess.CompletedProcess:
    """The real command line (``python -m services.tools.cli ...``), killed after `timeout_s`."""
    env = {**os.environ, "MPLBACKEND": "Agg"}
    return subprocess.run([sys.executable, "-m", "services.tools.cli", *args], cwd=ROOT, env=env,
                          capture_output=True, text=True, timeout=timeout_s,
                          stdin=subprocess.DEVNULL)


@pytest.fixture(autouse=True)
def _keep_signal_handlers() -> Iterator[None]:
    """``racestack up`` in this process installs its Ctrl-C handler: put pytest's back."""
    saved = {sig: signal.getsignal(sig) for sig in (signal.SIGINT, signal.SIGTERM)}
    try:
        yield
    finally:
        for sig, handler in saved.items():
            signal.signal(sig, handler)


@pytest.fixture
def busy_port() -> Iterator[int]:
    """A loopback port held by a listening socket (as a router still running would)."""
    sock = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
    sock.bind(("127.0.0.1", 0))
    sock.listen(8)
    try:
        yield sock.getsockname()[1]
    finally:
        sock.close()


def _config(tmp_path: Path, listen_port: int, connect_port: int | None = None) -> Path:
    text = f'[bus]\nlisten = ["tcp/127.0.0.1:{listen_port}"]\n'
    if connect_port is not None:
        text += f'connect = ["tcp/127.0.0.1:{connect_port}"]\n'
    path = tmp_path / "racestack.toml"
    path.write_text(text)
    return path


# --------------------------------------------------------------------------- bad counts
@pytest.mark.parametrize(
    ("argv", "names"),
    [
        (["up", "--laps", "0"], "--laps"),
        (["up", "--laps", "-1"], "--laps"),
        (["up", "--laps", "three"], "--laps"),
        (["demo", "--laps", "0"], "--laps"),
        (["laps", "--laps", "-3"], "--laps"),
        (["up", "--serve", "70000"], "--serve"),
        (["up", "--serve", "0"], "--serve"),
        (["bench", "--laps", "0"], "--laps"),
        (["bench", "--sweep-laps", "0"], "--sweep-laps"),
        (["bench", "--compute-delay-ms", "-1"], "--compute-delay-ms"),
        (["tune", "--method", "cimpcc", "--out", "t", "--trials", "0"], "--trials"),
        (["tune", "--method", "cimpcc", "--out", "t", "--laps", "-1"], "--laps"),
        (["mintime", "--ds", "-1", "--out", "m"], "--ds"),
    ],
)
def test_cli_bad_count_is_one_line_exit_2_nothing_started(
    argv: list[str], names: str, capsys: pytest.CaptureFixture[str], tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    monkeypatch.chdir(tmp_path)  # a default run folder would appear here
    code, out, err = _cli(argv, capsys)
    line = _one_line(err)
    assert code == 2 and names in line and "error" in line
    assert "racestack up:" not in out  # nothing started
    assert list(tmp_path.iterdir()) == []  # no run folder


def test_cli_positive_int_names_what_is_wrong() -> None:
    assert positive_int("3") == 3
    for bad in ("0", "-2", "x", "1.5"):
        with pytest.raises(argparse.ArgumentTypeError, match=r"whole number|at least 1"):
            positive_int(bad)


# --------------------------------------------------------------------------- folders
def test_outdir_removes_only_what_it_made(tmp_path: Path) -> None:
    target = tmp_path / "a" / "b" / "c"
    made = missing_dirs(target)
    assert made == [target, target.parent, target.parent.parent]
    assert writable_dir_problem(target) is None and target.is_dir()
    remove_empty_dirs(made)
    assert not (tmp_path / "a").exists() and tmp_path.is_dir()
    (tmp_path / "f").write_text("x")
    assert "is a file" in (writable_dir_problem(tmp_path / "f") or "")
    assert "not writable" in (writable_dir_problem(tmp_path / "f" / "sub") or "")


def test_cli_up_unusable_run_dir(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    (tmp_path / "file").write_text("x")
    cfg = _config(tmp_path, free_loopback_port())
    code, out, err = _cli(["up", "--config", str(cfg), "--run-dir",
                           str(tmp_path / "file" / "run")], capsys)
    line = _one_line(err)
    assert code == 2 and "--run-dir" in line and str(tmp_path / "file" / "run") in line
    assert "racestack up:" not in out


def test_cli_report_unusable_out_before_any_table(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    (tmp_path / "file").write_text("x")
    rrd = tmp_path / "run.rrd"
    rrd.write_bytes(b"not read: the folder is checked first")
    code, out, err = _cli(["report", str(rrd), "--out", str(tmp_path / "file" / "r")], capsys)
    line = _one_line(err)
    assert code == 2 and "--out" in line and out == ""


def test_cli_report_not_a_recording(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    rrd = tmp_path / "garbage.rrd"
    rrd.write_bytes(b"garbage")
    out_dir = tmp_path / "out"
    code, out, err = _cli(["report", str(rrd), "--out", str(out_dir)], capsys)
    line = _one_line(err)
    assert code == 2 and "not a readable telemetry recording" in line and out == ""
    assert not out_dir.exists()  # made for the check, removed again
    code, _, err = _cli(["report", str(tmp_path / "missing.rrd")], capsys)
    assert code == 2 and "no such file" in _one_line(err)


def test_cli_run_telemetry_unusable_out(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    (tmp_path / "file").write_text("x")
    cfg = _config(tmp_path, free_loopback_port())
    code, _, err = _cli(["run", "telemetry", "--config", str(cfg), "--out",
                         str(tmp_path / "file" / "rec")], capsys)
    line = _one_line(err)
    assert code == 2 and "--out" in line and "telemetry" in line


# --------------------------------------------------------------------------- the hub
def test_hub_watch_says_once_that_the_hub_is_unreachable() -> None:
    port = free_loopback_port()
    settings = BusSettings(listen=[f"tcp/127.0.0.1:{port}"])
    endpoints = hub_endpoints(settings, "planner")
    assert endpoints == [f"tcp/127.0.0.1:{port}"]
    stream = io.StringIO()
    watch = HubWatch("planner", endpoints, wait_s=0.05, stream=stream).start()
    deadline = time.monotonic() + 20.0
    while not watch.said and time.monotonic() < deadline:
        time.sleep(0.02)
    time.sleep(0.3)  # a second probe has failed too by now: still one line
    watch.stop()
    text = stream.getvalue()
    assert text == unreachable_hub_line("planner", endpoints) + "\n"
    assert f"tcp/127.0.0.1:{port}" in text and "racestack run router" in text


def test_hub_watch_is_silent_when_the_hub_listens(busy_port: int) -> None:
    stream = io.StringIO()
    watch = HubWatch("planner", [f"tcp/127.0.0.1:{busy_port}"], wait_s=0.01,
                     stream=stream).start()
    time.sleep(0.5)
    watch.stop()
    assert stream.getvalue() == "" and not watch.said


@pytest.mark.slow
def test_cli_up_busy_hub_port(tmp_path: Path, busy_port: int) -> None:
    cfg = _config(tmp_path, busy_port)
    run_dir = tmp_path / "runs" / "r1"
    got = _run(["up", "--config", str(cfg), "--run-dir", str(run_dir)])
    line = _one_line(got.stderr)
    assert got.returncode == 2, got.stderr
    assert f"tcp/127.0.0.1:{busy_port}" in line and "already in use" in line
    assert not (tmp_path / "runs").exists()  # no empty run folder left
    assert "waiting for" not in got.stdout  # nothing started


@pytest.mark.slow
def test_cli_run_router_busy_port(tmp_path: Path, busy_port: int) -> None:
    got = _run(["run", "router", "--config", str(_config(tmp_path, busy_port))])
    line = _one_line(got.stderr)
    assert got.returncode == 2 and "already in use" in line and "router" in line


@pytest.mark.slow
def test_cli_up_services_could_not_reach_the_hub(tmp_path: Path) -> None:
    cfg = _config(tmp_path, free_loopback_port(), connect_port=free_loopback_port())
    run_dir = tmp_path / "run"
    got = _run(["up", "--config", str(cfg), "--run-dir", str(run_dir)])
    line = _one_line(got.stderr)
    assert got.returncode == 2 and "connect" in line
    assert not run_dir.exists()


@pytest.mark.slow
def test_cli_run_service_without_hub_says_so_once_and_keeps_waiting(tmp_path: Path) -> None:
    """``racestack run SERVICE`` with no hub: one line within a few seconds (after the
    service has started), then it keeps waiting; Ctrl-C ends it."""
    port = free_loopback_port()
    cfg = _config(tmp_path, port)
    proc = subprocess.Popen(
        [sys.executable, "-m", "services.tools.cli", "run", "localization_bridge", "--config",
         str(cfg)], cwd=ROOT, stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE, text=True,
    )
    lines: list[str] = []
    assert proc.stderr is not None
    reader = threading.Thread(target=lambda: lines.extend(proc.stderr), daemon=True)
    reader.start()  # every stderr line, as it comes
    try:
        deadline = time.monotonic() + CMD_TIMEOUT_S
        said: list[str] = []
        while time.monotonic() < deadline and not said:
            said = [ln for ln in list(lines) if "cannot reach the hub" in ln]
            assert proc.poll() is None, "the service should keep waiting"
            time.sleep(0.1)
        assert len(said) == 1 and f"tcp/127.0.0.1:{port}" in said[0]
        time.sleep(2.5)  # more probes fail: no second line
        assert sum("cannot reach the hub" in ln for ln in list(lines)) == 1
        assert proc.poll() is None
    finally:
        proc.send_signal(signal.SIGINT)  # as Ctrl-C
        try:
            proc.wait(timeout=30)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait(timeout=10)
    assert proc.returncode in (0, 130)
