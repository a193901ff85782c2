"""Command-to-wire latency of the vesc_driver service: ``cmd/drive`` on Zenoh -> SET_RPM bytes.

This process hosts the hub (a router ``Bus`` on a free loopback port, scouting off) and a
``FakeVesc`` on a pty, and starts the real service (``python -m services.vesc_driver``) with
``[vesc] port`` at the fake's symlink. It publishes ``--n`` ``DriveCmd`` at ``--rate`` Hz,
each with its own speed so that its ERPM identifies it, and measures, per command, the time
from just before ``put`` to the fake VESC's read of the first SET_RPM frame carrying that
ERPM (both ``time.monotonic``, same machine). Run from the project root::

    .venv/bin/python -m benchmarks.vesc_wire_latency --n 1000

Two modes of the service are measured (``--mode both``, the default):

* ``immediate`` (``[vesc] write_on_command = true``, the default): a new command is written
  at once, besides the fixed-rate frames;
* ``fixed`` (``write_on_command = false``): commands go out only on the driver's fixed
  ``command_rate_hz`` ticks (50 Hz), so the latency includes waiting for the next tick (up
  to one period, 20 ms).

Send times: command ``i`` goes out at ``t0 + i / rate + U(0, jitter / rate)`` (``--jitter``,
default 0.9, seeded), so its phase against the driver's tick is spread over the period. With
``--jitter 0`` and ``--rate`` equal to the driver's rate, both clocks tick in lock-step and
the ``fixed`` mode shows one constant phase offset instead of the 0-20 ms spread.

Printed per mode: matched / sent, median, p90, p99, max and mean latency [ms].
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

from services.tools.launcher.supervisor import stop_process
from shared.bus import Bus
from shared.config import load_config
from shared.config.vesc import VescSettings
from shared.messages import DriveCmd
from shared.net import free_loopback_port
from shared.vesc.fake_pty import FakeVesc
from shared.vesc.protocol import CommandId

ROOT = Path(__file__).resolve().parents[1]
#: Wait for the service to come up [s].
START_TIMEOUT_S = 30.0
#: Wait for it to exit after SIGINT before killing it [s].
STOP_TIMEOUT_S = 10.0
#: Lowest and highest ERPM of the identifying command speeds.
ERPM_LO, ERPM_HI = 2000, 22000
#: ERPM of the warm-up commands (not among the measured ones).
WARMUP_ERPM = 1000
#: Wait after the last command for its frame [s].
DRAIN_S = 0.3


def erpm_sequence(n: int) -> list[int]:
    """``n`` distinct ERPM values in [ERPM_LO, ERPM_HI] (ValueError if n is too large)."""
    span = ERPM_HI - ERPM_LO
    if n > span + 1:
        raise ValueError(f"at most {span + 1} distinct commands")
    step = max(1, min(20, span // max(1, n - 1)))
    return [ERPM_LO + step * i for i in range(n)]


def _stop(proc: subprocess.Popen[bytes]) -> int | None:
    """SIGINT by PID, wait; SIGKILL if it does not exit in time."""
    return stop_process(proc, STOP_TIMEOUT_S)


def measure(
    mode: str, n: int, rate_hz: float, warmup: int, tmp: Path, jitter: float = 0.9, seed: int = 0
) -> dict[str, Any]:
    """Run the service in ``mode`` ("immediate" | "fixed"), send ``n`` commands at
    ``rate_hz`` [Hz] (each delayed by ``U(0, jitter / rate_hz)``) after ``warmup`` ones;
    returns the latencies [ms] and counts."""
    gain = VescSettings().speed_to_erpm_gain
    erpms = erpm_sequence(n)
    port = free_loopback_port()
    dev = tmp / f"dev-{mode}"
    dev.mkdir()
    toml = tmp / f"{mode}.toml"
    log_path = tmp / f"vesc_driver-{mode}.log"
    with FakeVesc(link_dir=dev) as fake:
        toml.write_text(
            f'[bus]\ncar = "latency"\nlisten = ["tcp/127.0.0.1:{port}"]\n\n'
            f'[vesc]\nport = "{fake.path}"\n'
            f"write_on_command = {'true' if mode == 'immediate' else 'false'}\n",
            encoding="utf-8",
        )
        cfg = load_config(toml)
        env = {**os.environ, "PYTHONPATH": str(ROOT), "PYTHONUNBUFFERED": "1"}
        with (
            Bus(cfg.bus, "bench", listen_default=True, mode="router") as hub,
            open(log_path, "wb") as out,
        ):
            proc = subprocess.Popen(
                [sys.executable, "-m", "services.vesc_driver", "--config", str(toml)],
                cwd=str(ROOT),
                env=env,
                stdout=out,
                stderr=subprocess.STDOUT,
            )
            try:
                if not hub.wait_alive(["vesc_driver"], START_TIMEOUT_S):
                    raise RuntimeError(f"vesc_driver did not come up; see {log_path}")
                pub = hub.publisher(hub.keys.drive_cmd, DriveCmd)
                if not pub.wait_matching(START_TIMEOUT_S):
                    raise RuntimeError("vesc_driver did not subscribe to cmd/drive")
                period = 1.0 / rate_hz
                rng = np.random.default_rng(seed)
                offsets = rng.uniform(0.0, jitter * period, warmup + n)
                speeds = [WARMUP_ERPM / gain] * warmup + [e / gain for e in erpms]
                sent: list[float] = []
                t0 = time.monotonic() + 0.05
                for i, v in enumerate(speeds):
                    delay = t0 + i * period + offsets[i] - time.monotonic()
                    if delay > 0:
                        time.sleep(delay)
                    t = time.monotonic()
                    pub.put(DriveCmd(stamp_s=time.time(), speed_mps=v, steering_rad=0.0))
                    if i >= warmup:
                        sent.append(t)
                time.sleep(DRAIN_S)
            finally:
                code = _stop(proc)
        events = fake.events(CommandId.SET_RPM)
    first: dict[int, list[float]] = {}
    for e in events:
        if e.value is not None:
            first.setdefault(round(e.value), []).append(e.t_s)
    index = {erpm: i for i, erpm in enumerate(erpms)}
    wire = sorted(
        (e.t_s, index[round(e.value)])
        for e in events
        if e.value is not None and round(e.value) in index
    )
    lat_ms: list[float] = []
    superseded = 0
    for i, (erpm, t_pub) in enumerate(zip(erpms, sent, strict=True)):
        after = [t for t in first.get(erpm, []) if t >= t_pub]
        if after:
            lat_ms.append((min(after) - t_pub) * 1e3)
            continue
        # not on the wire while newer commands are: superseded before a tick (fixed rate)
        if any(j > i for t, j in wire if t >= t_pub):
            superseded += 1
    return {
        "mode": mode,
        "sent": len(sent),
        "matched": len(lat_ms),
        "superseded": superseded,
        "latency_ms": lat_ms,
        "exit_code": code,
        "log": str(log_path),
    }


def summary(res: dict[str, Any]) -> dict[str, Any]:
    """Median, p90, p99, max and mean [ms] of one mode's latencies."""
    a = np.asarray(res["latency_ms"], dtype=float)
    out = {k: res[k] for k in ("mode", "sent", "matched", "superseded", "exit_code")}
    if a.size:
        out |= {
            "median_ms": float(np.median(a)),
            "p90_ms": float(np.percentile(a, 90)),
            "p99_ms": float(np.percentile(a, 99)),
            "max_ms": float(a.max()),
            "mean_ms": float(a.mean()),
        }
    return out


def main(argv: list[str] | None = None) -> int:
    """Run the benchmark and print the table (``--json``: also the summary as JSON)."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=1000, help="measured commands per mode")
    ap.add_argument("--rate", type=float, default=50.0, help="command rate [Hz]")
    ap.add_argument("--warmup", type=int, default=25, help="unmeasured commands first")
    ap.add_argument("--mode", choices=("both", "immediate", "fixed"), default="both")
    ap.add_argument(
        "--jitter",
        type=float,
        default=0.9,
        help="random send delay as a share of the command period, in [0, 1)",
    )
    ap.add_argument("--seed", type=int, default=0, help="seed of the send jitter")
    ap.add_argument("--json", action="store_true", help="print the summary as JSON too")
    args = ap.parse_args(argv)
    if args.n < 1 or args.rate <= 0 or not 0.0 <= args.jitter < 1.0:
        ap.error("--n must be >= 1, --rate > 0 and --jitter in [0, 1)")
    modes = ["immediate", "fixed"] if args.mode == "both" else [args.mode]
    print(
        f"cmd/drive -> SET_RPM at the fake VESC: {args.n} commands at {args.rate:g} Hz "
        f"per mode, send jitter {args.jitter:g} period (driver ticks at "
        f"{VescSettings().command_rate_hz:g} Hz)"
    )
    rows = []
    with tempfile.TemporaryDirectory(prefix="vesc-latency-") as tmp:
        for mode in modes:
            res = measure(mode, args.n, args.rate, args.warmup, Path(tmp), args.jitter, args.seed)
            rows.append(summary(res))
    print(
        f"{'mode':<10} {'matched':>11} {'superseded':>10} {'median':>8} {'p90':>8} "
        f"{'p99':>8} {'max':>8} {'mean':>8}  [ms]"
    )
    for r in rows:
        head = f"{r['mode']:<10} {r['matched']:>5}/{r['sent']:<5} {r['superseded']:>10}"
        if "median_ms" not in r:
            print(f"{head}  (nothing matched)")
            continue
        print(
            f"{head} {r['median_ms']:8.2f} {r['p90_ms']:8.2f} {r['p99_ms']:8.2f} "
            f"{r['max_ms']:8.2f} {r['mean_ms']:8.2f}"
        )
    print(
        "superseded: a newer command arrived before any tick wrote this one (never on the "
        "wire, by design);\nlost = sent - matched - superseded must be 0"
    )
    if args.json:
        print(json.dumps(rows))
    lost = sum(r["sent"] - r["matched"] - r["superseded"] for r in rows)
    return 0 if lost == 0 and all(r["exit_code"] == 0 for r in rows) else 1


if __name__ == "__main__":
    sys.exit(main())
