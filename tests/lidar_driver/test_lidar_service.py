"""The lidar_driver as a REAL process against the fake Hokuyo on a pty and on TCP, over Zenoh.

The test process hosts the hub (a router ``Bus`` on a free loopback port) and the fake; the
service runs as ``python -m services.lidar_driver --config <tmp toml>``. The process is
stopped by PID with a timeout (SIGINT, then SIGKILL) in a ``finally``; every wait has one.
"""

from __future__ import annotations

import faulthandler
import math
import os
import signal
import subprocess
import sys
import time
from collections.abc import Callable, Iterator
from pathlib import Path

import numpy as np
import pytest

from shared.bus import Bus
from shared.config import load_config
from shared.hokuyo.fake_io import FakeHokuyo, pty_available
from shared.messages import LogEvent, Scan
from shared.net import free_loopback_port

ROOT = Path(__file__).resolve().parents[2]
SERVICE = "lidar_driver"
START_TIMEOUT_S = 20.0
WAIT_S = 5.0

pytestmark = pytest.mark.slow


@pytest.fixture(autouse=True)
def _deadline() -> Iterator[None]:
    faulthandler.dump_traceback_later(90.0, exit=True, file=sys.stderr)
    try:
        yield
    finally:
        faulthandler.cancel_dump_traceback_later()


def golden(n: int = 8) -> list[np.ndarray]:
    rng = np.random.default_rng(3)
    out = [rng.integers(20, 29000, 1081) for _ in range(n)]
    for k, s in enumerate(out):
        s[0] = 1000 + k  # which golden scan
        s[1:3] = [0, 7]  # error codes -> +inf
    return out


def until(cond: Callable[[], bool], timeout_s: float = WAIT_S) -> bool:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if cond():
            return True
        time.sleep(0.01)
    return cond()


class Rig:
    """Hub, fake Hokuyo and the service process."""

    def __init__(self, tmp: Path, transport: str) -> None:
        self.scans_golden = golden()
        self.fake = FakeHokuyo(self.scans_golden, transport=transport)  # type: ignore[arg-type]
        port = free_loopback_port()
        self.toml = tmp / "racestack.toml"
        self.toml.write_text(
            f'[bus]\ncar = "lidartest"\nlisten = ["tcp/127.0.0.1:{port}"]\n\n'
            f'[lidar_driver]\nport = "{self.fake.address}"\nevent_interval_s = 0.1\n'
            "reconnect_period_s = 0.2\nsilence_timeout_s = 0.3\nreply_timeout_s = 0.3\n",
            encoding="utf-8",
        )
        self.hub = Bus(load_config(self.toml).bus, "test", listen_default=True, mode="router")
        self.scans = self.hub.subscribe(self.hub.keys.scan, Scan, queue_size=4096)
        self.logs = self.hub.subscribe(self.hub.keys.events_log, LogEvent, queue_size=1024)
        self.events: list[LogEvent] = []
        self.log_path = tmp / "lidar.log"
        env = {**os.environ, "PYTHONPATH": str(ROOT), "PYTHONUNBUFFERED": "1"}
        with open(self.log_path, "wb") as out:
            self.proc = subprocess.Popen(
                [sys.executable, "-m", "services.lidar_driver", "--config", str(self.toml)],
                cwd=str(ROOT), env=env, stdout=out, stderr=subprocess.STDOUT,
            )

    def output(self) -> str:
        return self.log_path.read_text(errors="replace")

    def wait_event(self, pred: Callable[[str], bool], timeout_s: float = WAIT_S) -> bool:
        def seen() -> bool:
            self.events += [e for e in self.logs.drain() if e.source == SERVICE]
            return any(pred(e.text) for e in self.events)

        return until(seen, timeout_s)

    def close(self) -> None:
        try:
            if self.proc.poll() is None:
                self.proc.send_signal(signal.SIGINT)
                try:
                    self.proc.wait(timeout=10.0)
                except subprocess.TimeoutExpired:
                    self.proc.kill()
                    self.proc.wait(timeout=5.0)
        finally:
            self.hub.close()
            self.fake.close()


@pytest.mark.parametrize("transport", ["pty", "tcp"])
def test_golden_scans_faults_unplug_and_silence(tmp_path: Path, transport: str) -> None:
    if transport == "pty" and not pty_available():
        pytest.skip("needs pseudo-terminals (os.openpty)")
    rig = Rig(tmp_path, transport)
    try:
        assert rig.hub.wait_alive([SERVICE], START_TIMEOUT_S), rig.output()
        got: list[Scan] = []

        def twenty() -> bool:
            got.extend(rig.scans.drain())
            return len(got) >= 20

        assert until(twenty, 10.0), rig.output()
        # published unchanged: metres, +inf for error codes, angles from PP (UTM-30LX)
        for sc in got:
            k = round(float(sc.ranges_m[0]) * 1000) - 1000
            expect = (rig.scans_golden[k] / 1000.0).astype(np.float32)
            expect[1:3] = np.inf
            assert np.array_equal(sc.ranges_m, expect)
            assert sc.angle_min_rad == pytest.approx(-math.radians(135.0))
            assert sc.angle_increment_rad == pytest.approx(math.radians(0.25))
            assert abs(sc.stamp_s - time.time()) < 5.0
        # garbage, bad checksums, truncated scans: counted, reported, survived
        rig.fake.set(garbage=b"\x00\xffnoise\n\n", corrupt=2, truncate=1)
        assert rig.wait_event(lambda t: "bad checksums" in t and "truncated" in t), rig.output()
        rig.scans.drain()
        assert until(lambda: len(rig.scans.drain()) > 0), rig.output()
        # unplug / replug: reported, reconnected, scans again
        rig.fake.unplug()
        assert rig.wait_event(lambda t: "lost the lidar" in t or "no scan" in t), rig.output()
        time.sleep(0.5)
        rig.fake.replug()
        assert rig.wait_event(lambda t: "back: handshake" in t), rig.output()
        rig.scans.drain()
        assert until(lambda: len(rig.scans.drain()) > 0), rig.output()
        # a silent sensor: reported, link reopened, scans again when it speaks
        rig.fake.set(silent=True)
        assert rig.wait_event(lambda t: "no scan for" in t), rig.output()
        rig.fake.set(silent=False)
        rig.scans.drain()
        assert until(lambda: len(rig.scans.drain()) > 0), rig.output()
        assert rig.proc.poll() is None
    finally:
        rig.close()
    assert rig.proc.returncode == 0, rig.output()
