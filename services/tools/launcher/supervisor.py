"""Start, watch and stop the stack's service processes (used by ``racestack up``).

Each service runs as its own process (``python -m services.<name> --config FILE``), started with
``subprocess`` (never a fork of a process holding a Zenoh session). The supervisor stops only the
processes it started, by their PID: SIGINT first (services close their Zenoh sessions), then
SIGTERM, then SIGKILL after timeouts.
"""

from __future__ import annotations

import logging
import os
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path

log = logging.getLogger(__name__)


@dataclass
class Child:
    """One started service process."""

    name: str
    argv: list[str]
    process: subprocess.Popen
    log_path: Path | None = None
    started_at: float = field(default_factory=time.monotonic)

    @property
    def pid(self) -> int:
        """Process id."""
        return self.process.pid

    def exit_code(self) -> int | None:
        """The exit code, or None while it runs."""
        return self.process.poll()


def stop_process(proc: subprocess.Popen, grace_s: float = 10.0) -> int | None:
    """Stop one process we started, by its PID: SIGINT, wait `grace_s`; then SIGKILL.

    Returns its exit code, or None when it had to be killed.
    """
    if proc.poll() is None:
        proc.send_signal(signal.SIGINT)
        try:
            return proc.wait(timeout=grace_s)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait(timeout=5.0)
            return None
    return proc.returncode


def service_argv(name: str, config_path: str | None, extra: Sequence[str] = ()) -> list[str]:
    """The command line that starts service `name` with the current interpreter."""
    argv = [sys.executable, "-m", f"services.{name}"]
    if config_path:
        argv += ["--config", str(config_path)]
    return argv + list(extra)


class Supervisor:
    """A group of service processes started and stopped together."""

    def __init__(self, log_dir: Path | None = None, env: dict[str, str] | None = None) -> None:
        """Args: log_dir: where each child's stdout/stderr go (None: inherit); env: extra env."""
        self.children: list[Child] = []
        self._log_dir = log_dir
        self._env = {**os.environ, **(env or {})}
        self._lock = threading.Lock()

    def start(self, name: str, argv: list[str]) -> Child:
        """Start one child process."""
        out = None
        log_path = None
        if self._log_dir is not None:
            self._log_dir.mkdir(parents=True, exist_ok=True)
            log_path = self._log_dir / f"{name}.log"
            out = log_path.open("ab")
        proc = subprocess.Popen(
            argv,
            stdout=out if out else None,
            stderr=subprocess.STDOUT if out else None,
            stdin=subprocess.DEVNULL,
            env=self._env,
            start_new_session=True,  # Ctrl-C in the terminal reaches only the supervisor
        )
        if out:
            out.close()
        child = Child(name, argv, proc, log_path)
        with self._lock:
            self.children.append(child)
        log.info("started %s (pid %d)", name, proc.pid)
        return child

    def forget(self, child: Child) -> None:
        """Stop watching a child that has exited (e.g. one deliberately stopped)."""
        if child.exit_code() is None:
            raise ValueError(f"{child.name} (pid {child.pid}) is still running")
        with self._lock:
            self.children = [c for c in self.children if c is not child]

    def dead(self) -> list[Child]:
        """Children that have exited."""
        return [c for c in self.children if c.exit_code() is not None]

    def wait_until(
        self, condition: Callable[[], bool], timeout_s: float, poll_s: float = 0.05
    ) -> bool:
        """Wait for `condition` while every child lives; False on timeout or a dead child."""
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            if self.dead():
                return False
            if condition():
                return True
            time.sleep(poll_s)
        return False

    def stop_all(self, grace_s: float = 5.0) -> dict[str, int | None]:
        """Stop every child: SIGINT, then SIGTERM, then SIGKILL; returns exit codes by name."""
        with self._lock:
            children = list(self.children)
        for sig, wait_s in ((signal.SIGINT, grace_s), (signal.SIGTERM, 2.0), (signal.SIGKILL, 2.0)):
            alive = [c for c in children if c.exit_code() is None]
            if not alive:
                break
            for c in alive:
                try:
                    c.process.send_signal(sig)
                except ProcessLookupError:
                    pass
            deadline = time.monotonic() + wait_s
            for c in alive:
                try:
                    c.process.wait(timeout=max(0.0, deadline - time.monotonic()))
                except subprocess.TimeoutExpired:
                    if sig == signal.SIGKILL:
                        log.error("%s (pid %d) did not die", c.name, c.pid)
                    else:
                        log.warning("%s (pid %d) ignored %s", c.name, c.pid, sig.name)
        return {c.name: c.exit_code() for c in children}

    def __enter__(self) -> Supervisor:
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop_all()
