"""Scan-to-publish latency of the lidar_driver service: the fake Hokuyo's last byte of a
scan -> the ``Scan`` arriving at a Zenoh subscriber.

This process hosts the hub (a router ``Bus`` on a free loopback port, scouting off) and a
``FakeHokuyo`` (a pty, or a loopback TCP port), and starts the real service
(``python -m services.lidar_driver``) with ``[lidar_driver] port`` at the fake. Each golden
scan carries its number in its first range, so every received ``Scan`` is matched to the
time the fake finished writing it (``time.monotonic`` after the write of its last byte) and
to the subscriber callback's ``time.monotonic`` (same machine, same clock). The first
``--warmup`` scans are skipped. Run from the project root::

    .venv/bin/python -m benchmarks.lidar_latency --scans 600

Printed per transport: matched / sent, median, p90, p99, max [ms]. The scan itself is 1081
beams (UTM-30LX, 40 Hz; 3.3 kB of SCIP data).
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import numpy as np

from shared.bus import Bus
from shared.config import load_config
from shared.hokuyo.fake_io import FakeHokuyo
from shared.messages import Scan
from shared.net import free_loopback_port

ROOT = Path(__file__).resolve().parents[1]
#: Distinct golden scans (numbers are told apart modulo this).
GOLDEN = 4096


def golden() -> list[np.ndarray]:
    rng = np.random.default_rng(11)
    base = rng.integers(20, 29000, 1081)
    out = []
    for k in range(GOLDEN):
        s = base.copy()
        s[0] = 1000 + k
        out.append(s)
    return out


def measure(transport: str, scans: int, warmup: int) -> dict[str, float]:
    """Run the service against the fake for ``warmup + scans`` scans; latency figures [ms]."""
    fake = FakeHokuyo(golden(), transport=transport)  # type: ignore[arg-type]
    tmp = Path(tempfile.mkdtemp("lidar-bench"))
    port = free_loopback_port()
    toml = tmp / "racestack.toml"
    toml.write_text(
        f'[bus]\ncar = "lidarbench"\nlisten = ["tcp/127.0.0.1:{port}"]\n\n'
        f'[lidar_driver]\nport = "{fake.address}"\nsilence_timeout_s = 2.0\n',
        encoding="utf-8",
    )
    hub = Bus(load_config(toml).bus, "bench", listen_default=True, mode="router")
    received: list[tuple[int, float]] = []
    lock = threading.Lock()

    def on_scan(msg: Scan) -> None:
        t = time.monotonic()
        with lock:
            received.append((round(float(msg.ranges_m[0]) * 1000) - 1000, t))

    hub.subscribe(hub.keys.scan, Scan, on_scan)
    env = {**os.environ, "PYTHONPATH": str(ROOT), "PYTHONUNBUFFERED": "1"}
    log = open(tmp / "lidar.log", "wb")
    proc = subprocess.Popen(
        [sys.executable, "-m", "services.lidar_driver", "--config", str(toml)],
        cwd=str(ROOT), env=env, stdout=log, stderr=subprocess.STDOUT,
    )
    try:
        if not hub.wait_alive(["lidar_driver"], 30.0):
            raise RuntimeError("the lidar_driver did not start")
        deadline = time.monotonic() + 60.0 + (scans + warmup) / 40.0 * 3
        while time.monotonic() < deadline:
            with lock:
                if len(received) >= warmup + scans:
                    break
            time.sleep(0.05)
    finally:
        if proc.poll() is None:
            proc.send_signal(2)
            try:
                proc.wait(timeout=10.0)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait(timeout=5.0)
        sub_count = len(received)
        hub.close()
        fake.close()
        log.close()
    sent = {n % GOLDEN: t for n, t in fake.sent}
    with lock:
        pairs = received[warmup : warmup + scans]
    lat = np.array([(t - sent[k]) * 1e3 for k, t in pairs if k in sent])
    if lat.size == 0:
        raise RuntimeError(f"no scan matched ({sub_count} received); see {tmp}/lidar.log")
    return {
        "matched": float(lat.size),
        "sent": float(len(fake.sent)),
        "median_ms": float(np.median(lat)),
        "p90_ms": float(np.percentile(lat, 90)),
        "p99_ms": float(np.percentile(lat, 99)),
        "max_ms": float(lat.max()),
    }


def main(argv: list[str] | None = None) -> int:
    """Measure and print the figures per transport."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scans", type=int, default=600, help="scans measured per transport")
    ap.add_argument("--warmup", type=int, default=40, help="first scans not measured")
    ap.add_argument("--transport", choices=["pty", "tcp", "both"], default="both")
    args = ap.parse_args(argv)
    transports = ["pty", "tcp"] if args.transport == "both" else [args.transport]
    print(f"lidar scan-to-publish latency, 1081 beams at 40 Hz, {args.scans} scans each")
    print(f"{'transport':<10}{'matched':>9}{'median':>9}{'p90':>9}{'p99':>9}{'max':>9}  [ms]")
    for tr in transports:
        r = measure(tr, args.scans, args.warmup)
        print(
            f"{tr:<10}{int(r['matched']):>9}{r['median_ms']:>9.2f}{r['p90_ms']:>9.2f}"
            f"{r['p99_ms']:>9.2f}{r['max_ms']:>9.2f}"
        )
    return 0


if __name__ == "__main__":
    sys.exit(main())
