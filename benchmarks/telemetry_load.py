"""Load benchmark of the telemetry service: CPU share and dropped messages at the stack's rates.

Starts the real telemetry process (``python -m services.telemetry``) against a hub in this
process (loopback only, scouting off), replays a synthetic stream of `--laps` laps in real
time at the stack's rates (pose 40 Hz, imu 100 Hz, odom 50 Hz, state 40 Hz, plan 20 Hz with
an 11 x 4 horizon, cmd 20 Hz, truth 50 Hz, scan 10 Hz with 1080 beams, lap and log events),
samples the telemetry's CPU once a second with psutil (100 % = one core), stops it with
SIGINT and prints median / p99 / max of the per-second CPU and the message totals (sent,
logged, dropped by the telemetry queue, rejected, sequence gaps). Run from the project root:

    .venv/bin/python -m benchmarks.telemetry_load --laps 3

``--pid PID --seconds S`` only samples an already running telemetry process (e.g. one
started by ``racestack up``) for S seconds and publishes nothing.

Target (issue 5): under 20 % of one core, nothing dropped by the telemetry queue.
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path
from typing import Any

import numpy as np
import psutil

from services.telemetry import find_segments
from shared.net import free_loopback_port

ROOT = Path(__file__).resolve().parents[1]
#: Wait for the telemetry process to come up [s].
START_TIMEOUT_S = 30.0
#: Wait for it to exit after SIGINT before killing it [s].
STOP_TIMEOUT_S = 20.0


class CpuSampler:
    """Samples a process's CPU share [% of one core] every `period_s` on a thread."""

    def __init__(self, pid: int, period_s: float = 1.0) -> None:
        self.proc = psutil.Process(pid)
        self.period_s = period_s
        self.samples: list[float] = []
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)

    def _run(self) -> None:
        self.proc.cpu_percent(interval=None)  # baseline
        while not self._stop.wait(self.period_s):
            try:
                self.samples.append(self.proc.cpu_percent(interval=None))
            except psutil.Error:
                return

    def start(self) -> CpuSampler:
        """Start sampling."""
        self._thread.start()
        return self

    def stop(self) -> list[float]:
        """Stop sampling; returns the per-period CPU shares [%]."""
        self._stop.set()
        self._thread.join(timeout=5.0)
        return self.samples


def thread_cpu(pid: int, top: int = 8) -> dict[str, float]:
    """CPU seconds (user + system) of the busiest threads of `pid`, by thread name (Linux)."""
    out: dict[str, float] = {}
    try:
        for th in psutil.Process(pid).threads():
            try:
                name = Path(f"/proc/{pid}/task/{th.id}/comm").read_text().strip()
            except OSError:
                name = "?"
            key = f"{name}[{th.id}]"
            out[key] = round(th.user_time + th.system_time, 3)
    except psutil.Error:
        return {}
    return dict(sorted(out.items(), key=lambda kv: -kv[1])[:top])


def cpu_summary(samples: list[float]) -> dict[str, float | int | None]:
    """median / p99 / max / mean of per-second CPU samples [% of one core]."""
    if not samples:
        return {"n": 0, "median": None, "p99": None, "max": None, "mean": None}
    a = np.asarray(samples)
    return {"n": int(a.size), "median": float(np.median(a)),
            "p99": float(np.percentile(a, 99)), "max": float(a.max()), "mean": float(a.mean())}


def run_replay(track_spec: str, laps: float, speed_mps: float, stamps: str,
               out: Path) -> dict[str, Any]:
    """Start the telemetry, replay the stream, stop it; returns the figures."""
    from services.telemetry.synthetic import lap_stream, replay
    from shared.bus import Bus
    from shared.config import load_config
    from shared.track import load_track

    track = load_track(track_spec)
    duration_s = laps * track.length_m / speed_mps
    port = free_loopback_port()
    toml = out / "bench.toml"
    toml.write_text(f'[track]\nsource = "{track.source}"\n\n'
                    f'[bus]\ncar = "bench"\nlisten = ["tcp/127.0.0.1:{port}"]\n',
                    encoding="utf-8")
    cfg = load_config(toml)
    run_dir = out / "run"
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    env.setdefault("XDG_CONFIG_HOME", str(out / "xdg-config"))
    env.setdefault("XDG_DATA_HOME", str(out / "xdg-data"))
    os.environ.setdefault("XDG_CONFIG_HOME", env["XDG_CONFIG_HOME"])
    os.environ.setdefault("XDG_DATA_HOME", env["XDG_DATA_HOME"])
    log_path = out / "telemetry.log"
    with Bus(cfg.bus, "bench", listen_default=True) as hub, open(log_path, "wb") as log:
        proc = subprocess.Popen(
            [sys.executable, "-m", "services.telemetry", "--config", str(toml),
             "--out", str(run_dir)],
            cwd=str(ROOT), env=env, stdout=log, stderr=subprocess.STDOUT,
        )
        try:
            if not hub.wait_alive(["telemetry"], timeout_s=START_TIMEOUT_S):
                raise RuntimeError("telemetry did not start:\n" + log_path.read_text())
            print(f"telemetry pid {proc.pid} up; replaying {laps:g} laps of {track.name} "
                  f"({duration_s:.1f} s) at the stack's rates ...", flush=True)
            t0 = time.time() if stamps == "wall" else 100.0
            lag: list[float] = []
            start = time.monotonic()

            def note_lag(t: float) -> None:
                lag.append(time.monotonic() - start - t)

            sampler = CpuSampler(proc.pid).start()
            wall = time.monotonic()
            sent = replay(hub, lap_stream(track, duration_s, t0_s=t0, speed_mps=speed_mps),
                          before_put=note_lag)
            wall = time.monotonic() - wall
            cpu = sampler.stop()
            threads = thread_cpu(proc.pid)
            time.sleep(0.5)  # let the last messages arrive
        finally:
            if proc.poll() is None:
                proc.send_signal(signal.SIGINT)
                try:
                    proc.wait(timeout=STOP_TIMEOUT_S)
                except subprocess.TimeoutExpired:
                    proc.kill()
                    proc.wait(timeout=5)
    stats_path = run_dir / "telemetry_stats.json"
    stats = json.loads(stats_path.read_text()) if stats_path.exists() else {}
    segments = find_segments(run_dir)  # the recording's one-minute segments
    return {
        "track": track.name,
        "laps": laps,
        "stream_s": duration_s,
        "replay_wall_s": wall,
        "publisher_lag_ms": {"p99": float(np.percentile(lag, 99)) * 1e3,
                             "max": float(np.max(lag)) * 1e3},
        "cpu_percent_of_one_core": cpu_summary(cpu),
        "cpu_samples": [round(c, 1) for c in cpu],
        "sent": sent,
        "sent_total": sum(sent.values()),
        "logged_total": sum(stats.get("logged", {}).values()),
        "dropped_by_queue": stats.get("dropped_by_queue"),
        "rejected": stats.get("rejected"),
        "seq_gaps": stats.get("seq_gaps"),
        "record_errors": stats.get("record_errors"),
        "top_threads_cpu_s": threads,
        "rrd_mb": sum(f.stat().st_size for f in segments) / 1e6 if segments else None,
        "exit_code": proc.returncode,
        "run_dir": str(run_dir),
    }


def main(argv: list[str] | None = None) -> int:
    """Run the benchmark and print the figures; exit code 1 if a target is missed."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--track", default="builtin:paperlike")
    ap.add_argument("--laps", type=float, default=3.0)
    ap.add_argument("--speed", type=float, default=3.3, help="car speed [m/s]")
    ap.add_argument("--stamps", choices=["wall", "sim"], default="wall",
                    help="wall-clock stamps (like the stack) or simulation time")
    ap.add_argument("--out", help="keep the run here (default: a temp dir, deleted)")
    ap.add_argument("--pid", type=int, help="only sample this running telemetry process")
    ap.add_argument("--seconds", type=float, default=60.0, help="sampling time with --pid")
    ap.add_argument("--json", action="store_true", help="print the figures as JSON only")
    args = ap.parse_args(argv)
    if args.pid:
        sampler = CpuSampler(args.pid).start()
        time.sleep(args.seconds)
        res: dict[str, Any] = {"pid": args.pid,
                               "cpu_percent_of_one_core": cpu_summary(sampler.stop())}
    elif args.out:
        out = Path(args.out)
        out.mkdir(parents=True, exist_ok=True)
        res = run_replay(args.track, args.laps, args.speed, args.stamps, out)
    else:
        with tempfile.TemporaryDirectory(prefix="telemetry-load-") as tmp:
            res = run_replay(args.track, args.laps, args.speed, args.stamps, Path(tmp))
    cpu = res["cpu_percent_of_one_core"]
    print(json.dumps(res, indent=2))
    if not args.json:
        if cpu["n"]:
            print(f"\nCPU of the telemetry [% of one core], {cpu['n']} one-second samples: "
                  f"median {cpu['median']:.1f}, p99 {cpu['p99']:.1f}, max {cpu['max']:.1f}, "
                  f"mean {cpu['mean']:.1f}")
        if "sent_total" in res:
            dropped = sum((res["dropped_by_queue"] or {}).values())
            gaps = sum((res["seq_gaps"] or {}).values())
            print(f"messages: sent {res['sent_total']}, logged {res['logged_total']}, "
                  f"dropped by the telemetry queue {dropped}, lost in transport (seq gaps) "
                  f"{gaps}, rejected {sum((res['rejected'] or {}).values())}; "
                  f"recording {res['rrd_mb']:.1f} MB")
    ok = bool(cpu["n"]) and cpu["median"] < 20.0 and not res.get("dropped_by_queue")
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
