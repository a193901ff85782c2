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

Load shedding (issue 25): ``--compare`` runs the replay twice, every message logged
(``series_max_hz = 0``, as before the decimation) and decimated to the default
``series_max_hz``, and prints CPU, the scalar samples sent per second (the log rate) and the
delay from a message's stamp to its sending (``send_delay_ms``: series, batched every
``batch_interval_s``; ``draw_delay_ms``: drawings, logged as they come). ``--serve`` also
serves the live stream (what ``racestack up --serve`` costs); ``--viewer-lag`` (with
``--serve``) connects a headless Rerun viewer to it (needs a Vulkan driver, e.g. Mesa's
lavapipe, ``apt-get install mesa-vulkan-drivers``; a manual check, no test needs it) and
samples once a second how far the viewer's time cursor (following the newest data) is behind
the wall clock.

Target (issue 5): under 20 % of one core, nothing dropped by the telemetry queue.
"""

from __future__ import annotations

import argparse
import functools
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


class HeadlessViewer:
    """A headless Rerun viewer on loopback (``rerun --headless``, software rendering is
    fine), driven by ``rerun.experimental.ViewerClient``: open recordings or a live stream,
    save screenshots, sample how far its time cursor (following the newest data) is behind
    the wall clock [s] once a second."""

    def __init__(self, out: Path, window: str = "1600x1000") -> None:
        from rerun.experimental import ViewerClient

        self.port = free_loopback_port()
        env = {**os.environ, "WGPU_BACKEND": os.environ.get("WGPU_BACKEND", "vulkan")}
        self.log = open(out / "viewer.log", "wb")  # closed in stop()
        self.proc = subprocess.Popen(
            [sys.executable, "-m", "rerun", "--headless", "--bind", "127.0.0.1", "--port",
             str(self.port), "--window-size", window, "--hide-welcome-screen"],
            env=env, stdout=self.log, stderr=subprocess.STDOUT,
            start_new_session=True)  # `python -m rerun` runs the viewer binary as its child:
        # stop() ends the whole group, or the binary outlives its wrapper
        self.client: Any = None
        self.samples: list[float] = []
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        deadline = time.monotonic() + START_TIMEOUT_S
        while self.client is None and time.monotonic() < deadline and self.proc.poll() is None:
            try:
                client = ViewerClient.connect(f"rerun+http://127.0.0.1:{self.port}/proxy")
                client.get_state()
                self.client = client
            except Exception:
                time.sleep(0.5)
        if self.client is None:
            self.stop()
            raise RuntimeError(f"no headless viewer (see {out / 'viewer.log'}; it needs a "
                               "Vulkan driver, e.g. Debian's mesa-vulkan-drivers)")

    def open(self, *urls: str, settle_s: float = 3.0) -> None:
        """Open files / a live stream URL and wait until they are loaded (+ `settle_s`)."""
        for url in urls:
            self.client.open(url)
        deadline = time.monotonic() + START_TIMEOUT_S
        while self.client.get_state().loading and time.monotonic() < deadline:
            time.sleep(0.5)
        time.sleep(settle_s)

    def screenshot(self, path: Path) -> Path:
        """Save the whole viewer as a PNG at `path`."""
        self.client.save_screenshot(str(path))
        return path

    def sample_lag(self) -> None:
        """Start sampling the lag of the ``wall_time`` cursor once a second."""
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _run(self) -> None:
        while not self._stop.wait(1.0):
            try:
                state = self.client.get_state()
            except Exception:
                continue
            now = time.time()
            for r in state.recordings:
                if r.current_timeline == "wall_time" and r.current_time is not None:
                    self.samples.append(now - r.current_time / 1e9)

    def stop_sampling(self) -> None:
        """Stop sampling the lag (the stream ended: the cursor stays at its last data)."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=5.0)

    def stop(self) -> list[float]:
        """Stop sampling and the viewer (by its pid); returns the lags [s]."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=5.0)
        for sig in (signal.SIGTERM, signal.SIGKILL):
            try:
                os.killpg(self.proc.pid, sig)  # the group this viewer's wrapper leads
            except ProcessLookupError:
                break
            try:
                self.proc.wait(timeout=10)
                break
            except subprocess.TimeoutExpired:
                continue
        self.log.close()
        return self.samples


def run_replay(track_spec: str, laps: float, speed_mps: float, stamps: str,
               out: Path, telemetry_toml: str = "", serve: bool = False,
               viewer_lag: bool = False, screenshot: Path | None = None) -> dict[str, Any]:
    """Start the telemetry (with extra `[telemetry]` lines `telemetry_toml`, serving the live
    stream with `serve`, a headless viewer on it with `viewer_lag`, saving `screenshot` at
    the end of the replay), replay the stream, stop it; returns the figures."""
    from services.telemetry.synthetic import lap_stream, replay
    from shared.bus import Bus
    from shared.config import load_config
    from shared.track import load_track

    track = load_track(track_spec)
    duration_s = laps * track.length_m / speed_mps
    port = free_loopback_port()
    toml = out / "bench.toml"
    toml.write_text(f'[track]\nsource = "{track.source}"\n\n'
                    f'[bus]\ncar = "bench"\nlisten = ["tcp/127.0.0.1:{port}"]\n\n'
                    f"[telemetry]\n{telemetry_toml}\n", encoding="utf-8")
    cfg = load_config(toml)
    run_dir = out / "run"
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    env.setdefault("XDG_CONFIG_HOME", str(out / "xdg-config"))
    env.setdefault("XDG_DATA_HOME", str(out / "xdg-data"))
    os.environ.setdefault("XDG_CONFIG_HOME", env["XDG_CONFIG_HOME"])
    os.environ.setdefault("XDG_DATA_HOME", env["XDG_DATA_HOME"])
    log_path = out / "telemetry.log"
    serve_port = free_loopback_port() if serve else None
    viewer: HeadlessViewer | None = None
    with Bus(cfg.bus, "bench", listen_default=True) as hub, open(log_path, "wb") as log:
        proc = subprocess.Popen(
            [sys.executable, "-m", "services.telemetry", "--config", str(toml),
             "--out", str(run_dir),
             *(["--serve", str(serve_port)] if serve_port is not None else [])],
            cwd=str(ROOT), env=env, stdout=log, stderr=subprocess.STDOUT,
        )
        try:
            if not hub.wait_alive(["telemetry"], timeout_s=START_TIMEOUT_S):
                raise RuntimeError("telemetry did not start:\n" + log_path.read_text())
            print(f"telemetry pid {proc.pid} up; replaying {laps:g} laps of {track.name} "
                  f"({duration_s:.1f} s) at the stack's rates ...", flush=True)
            if viewer_lag and serve_port is not None:
                viewer = HeadlessViewer(out)
                viewer.open(f"rerun+http://127.0.0.1:{serve_port}/proxy", settle_s=0.0)
                viewer.sample_lag()
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
            if viewer is not None:
                viewer.stop_sampling()
            threads = thread_cpu(proc.pid)
            time.sleep(0.5)  # let the last messages arrive
            if viewer is not None and screenshot is not None:
                viewer.screenshot(screenshot)
        finally:
            lags = viewer.stop() if viewer is not None else []
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
        "series_samples_sent": stats.get("series_samples_sent"),
        "series_samples_per_s": (stats.get("series_samples_sent") or 0) / duration_s,
        "messages_decimated": stats.get("messages_decimated"),
        "drawings_per_s": (stats.get("drawings") or 0) / duration_s,
        "send_delay_ms": stats.get("send_delay_ms"),
        "draw_delay_ms": stats.get("draw_delay_ms"),
        "viewer_lag_s": cpu_summary(lags) if viewer_lag else None,
        "viewer_lag_samples": [round(x, 2) for x in lags] if viewer_lag else None,
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
    ap.add_argument("--series-max-hz", type=float,
                    help="[telemetry] series_max_hz of the run (default: the setting's)")
    ap.add_argument("--compare", action="store_true",
                    help="run twice: every message (series_max_hz = 0), then decimated")
    ap.add_argument("--serve", action="store_true", help="also serve the live stream")
    ap.add_argument("--viewer-lag", action="store_true",
                    help="with --serve: a headless viewer on it, its lag behind the wall clock")
    ap.add_argument("--screenshot", metavar="PNG",
                    help="with --viewer-lag: save the live viewer at the end of the replay")
    args = ap.parse_args(argv)
    if args.compare:
        return compare(args)
    if args.pid:
        sampler = CpuSampler(args.pid).start()
        time.sleep(args.seconds)
        res: dict[str, Any] = {"pid": args.pid,
                               "cpu_percent_of_one_core": cpu_summary(sampler.stop())}
    else:
        extra = ("" if args.series_max_hz is None
                 else f"series_max_hz = {args.series_max_hz}")
        res = _replay_in(args, extra)
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


def _replay_in(args: argparse.Namespace, telemetry_toml: str) -> dict[str, Any]:
    """``run_replay`` in ``--out`` (or a temporary folder, deleted)."""
    run = functools.partial(run_replay, args.track, args.laps, args.speed, args.stamps,
                            telemetry_toml=telemetry_toml, serve=args.serve,
                            viewer_lag=args.viewer_lag,
                            screenshot=Path(args.screenshot) if args.screenshot else None)
    if args.out:
        out = Path(args.out) / (telemetry_toml.replace(" ", "").replace("=", "-") or "default")
        out.mkdir(parents=True, exist_ok=True)
        return run(out)
    with tempfile.TemporaryDirectory(prefix="telemetry-load-") as tmp:
        return run(Path(tmp))


def _fmt(d: dict[str, Any] | None, key: str) -> str:
    v = (d or {}).get(key)
    return "-" if v is None else f"{v:.1f}"


def recorder_cost(series_max_hz: float, seconds: float = 20.0, repeats: int = 3,
                  track_spec: str = "builtin:paperlike") -> float:
    """CPU [% of one core] of the logging thread alone (``Recorder.handle`` / ``periodic``
    into a file) for the synthetic stream at the stack's rates: the median of `repeats`
    runs of `seconds` of stream (no bus, no decoding; less noisy than the process)."""
    import rerun as rr

    from services.telemetry.recorder import Recorder
    from services.telemetry.synthetic import lap_stream
    from shared.config.telemetry import TelemetrySettings
    from shared.track import load_track

    track = load_track(track_spec)
    msgs = list(lap_stream(track, seconds, t0_s=1.7e9, speed_mps=3.3))
    shares = []
    with tempfile.TemporaryDirectory(prefix="telemetry-cost-") as tmp:
        for k in range(repeats):
            rec = rr.RecordingStream("bench", recording_id=f"cost-{k}")
            rec.set_sinks(rr.FileSink(str(Path(tmp) / f"{k}.rrd")))
            recorder = Recorder(rec, TelemetrySettings(series_max_hz=series_max_hz))
            recorder.log_static(track)
            cpu = time.process_time()
            for t, suffix, msg in msgs:
                recorder.handle(suffix, msg, 1.7e9 + t + 0.002)
                recorder.periodic(1.7e9 + t)
            recorder.close()
            shares.append(100.0 * (time.process_time() - cpu) / seconds)
            rec.flush(timeout_sec=5.0)
            rec.disconnect()
    return float(np.median(shares))


def compare(args: argparse.Namespace) -> int:
    """Every message logged vs decimated: one table of CPU, log rate and delays."""
    from shared.config.telemetry import TelemetrySettings

    default_hz = TelemetrySettings().series_max_hz
    for hz in (0.0, default_hz):
        print(f"logging thread alone, series_max_hz = {hz:g}: {recorder_cost(hz):.1f} % of "
              "one core (median of 3 x 20 s of stream)", flush=True)
    rows = []
    for label, extra in (("every message (series_max_hz = 0)", "series_max_hz = 0"),
                         ("decimated (default series_max_hz)", "")):
        res = _replay_in(args, extra)
        rows.append((label, res))
        keys = ("cpu_percent_of_one_core", "series_samples_per_s", "send_delay_ms",
                "draw_delay_ms", "viewer_lag_s", "viewer_lag_samples", "dropped_by_queue",
                "rrd_mb", "top_threads_cpu_s")
        print(f"{label}: {json.dumps({k: res[k] for k in keys})}", flush=True)
    print("\n| run | CPU median / p99 [% of a core] | series samples/s | drawings/s | "
          "send delay median / p99 [ms] | draw delay median / p99 [ms] | viewer lag median / "
          "max [s] | recording [MB] | dropped |")
    print("|---|---|---|---|---|---|---|---|---|")
    for label, res in rows:
        cpu, sd, dd = res["cpu_percent_of_one_core"], res["send_delay_ms"], res["draw_delay_ms"]
        lag = res["viewer_lag_s"]
        print(f"| {label} | {_fmt(cpu, 'median')} / {_fmt(cpu, 'p99')} | "
              f"{res['series_samples_per_s']:.0f} | {res['drawings_per_s']:.0f} | "
              f"{_fmt(sd, 'median')} / {_fmt(sd, 'p99')} | {_fmt(dd, 'median')} / "
              f"{_fmt(dd, 'p99')} | {_fmt(lag, 'median')} / {_fmt(lag, 'max')} | "
              f"{res['rrd_mb']:.1f} | {sum((res['dropped_by_queue'] or {}).values())} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
