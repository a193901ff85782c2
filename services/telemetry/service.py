"""The telemetry service: every key of the car in, a Rerun recording (and live stream) out.

``python -m services.telemetry --config FILE [--out DIR] [--serve PORT] [--viewer]``

* Records to ``DIR/telemetry.rrd`` (default ``<[telemetry] runs_dir>/<YYYYmmdd-HHMMSS>/``;
  never overwritten: ``telemetry-2.rrd``...), with the default layout inside (also saved as
  ``telemetry.rbl``) and, at exit, the counters in ``telemetry_stats.json``.
* ``--serve PORT`` also serves the stream live on ``[telemetry] serve_bind_ip`` (loopback by
  default) and prints the ``rerun --connect ...`` line; ``--viewer`` spawns a viewer
  connected to it, only when a display exists.
* One subscription per key hands decoded records to an ``Inbox`` without waiting (Zenoh's
  threads are never blocked); this thread is the only one that logs. When it cannot keep up
  the oldest data messages are dropped and counted per key; lap and log events never are.
* The recording is flushed every ``flush_interval_s``; SIGINT / SIGTERM close it cleanly.
  Garbage on any key is dropped by the bus and reported as a rate-limited warning.
"""

from __future__ import annotations

import argparse
import functools
import ipaddress
import json
import logging
import os
import socket
import subprocess
import sys
import threading
import time
from collections.abc import Sequence
from pathlib import Path

import rerun as rr

from services.telemetry.blueprint import default_blueprint, save_blueprint
from services.telemetry.inbox import Inbox
from services.telemetry.recorder import Recorder
from shared.bus import Bus
from shared.config import RacestackConfig
from shared.config.telemetry import TelemetrySettings
from shared.curvature import track_profile
from shared.keys import TOPIC_TYPES
from shared.messages import REGISTRY
from shared.service_shell import run_service
from shared.track import load_track

log = logging.getLogger(__name__)
SERVICE = "telemetry"
#: File name of the recording inside the run folder.
RRD_NAME = "telemetry.rrd"
#: How often the drop / queue counters are reported [s].
STATS_INTERVAL_S = 1.0
#: Period of the logging loop [s]: messages are handled in batches this often.
LOOP_PERIOD_S = 0.02
#: Longest wait for the final flush at exit [s].
CLOSE_TIMEOUT_S = 5.0


def settings_of(cfg: RacestackConfig) -> TelemetrySettings:
    """The ``[telemetry]`` section (defaults until the root config carries it)."""
    value = getattr(cfg, "telemetry", None)
    return value if isinstance(value, TelemetrySettings) else TelemetrySettings()


def new_run_dir(runs_dir: str | Path, now: float | None = None) -> Path:
    """A new, not yet existing ``<runs_dir>/<YYYYmmdd-HHMMSS>[-n]`` folder (created)."""
    stamp = time.strftime("%Y%m%d-%H%M%S", time.localtime(now))
    base = Path(runs_dir)
    for n in range(1000):
        path = base / (stamp if n == 0 else f"{stamp}-{n}")
        try:
            path.mkdir(parents=True, exist_ok=False)
            return path
        except FileExistsError:
            continue
    raise FileExistsError(f"no free run folder for {stamp} in {base}")


def free_recording_path(run_dir: Path) -> Path:
    """``run_dir/telemetry.rrd``, or ``telemetry-<n>.rrd`` if that exists (never overwrite)."""
    path = run_dir / RRD_NAME
    n = 2
    while path.exists():
        path = run_dir / f"telemetry-{n}.rrd"
        n += 1
    return path


def connect_url(host: str, port: int) -> str:
    """The URL a viewer connects to: ``rerun+http://HOST:PORT/proxy``."""
    if host in ("0.0.0.0", "::"):
        host = "127.0.0.1"
    if ":" in host:
        host = f"[{host}]"
    return f"rerun+http://{host}:{port}/proxy"


def free_loopback_port() -> int:
    """A free TCP port on 127.0.0.1."""
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def serve_problem(ip: str, port: int) -> str | None:
    """Why the live stream cannot be served on `ip`:`port` (None if it can: the port is
    valid and free now)."""
    if not 1 <= port <= 65535:
        return f"port {port} out of range 1..65535"
    family = socket.AF_INET6 if ":" in ip else socket.AF_INET
    with socket.socket(family, socket.SOCK_STREAM) as s:
        try:
            s.bind((ip, port))
        except OSError as exc:
            return f"{ip}:{port}: {exc.strerror or exc}"
    return None


def display_available(env: dict[str, str] | None = None, platform: str | None = None) -> bool:
    """True when a viewer window can open (a DISPLAY / WAYLAND_DISPLAY, macOS or Windows)."""
    env = dict(os.environ) if env is None else env
    platform = platform or sys.platform
    if env.get("CI"):
        return False
    if platform in ("darwin", "win32"):
        return True
    return bool(env.get("DISPLAY") or env.get("WAYLAND_DISPLAY"))


def spawn_viewer(url: str) -> subprocess.Popen[bytes] | None:
    """Start a Rerun viewer connected to `url` (detached); None without a display."""
    if not display_available():
        log.warning("--viewer: no display here; connect a viewer yourself: rerun --connect %s",
                    url)
        return None
    return subprocess.Popen(
        [sys.executable, "-m", "rerun", "--connect", url],
        stdin=subprocess.DEVNULL,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
        start_new_session=True,
    )


def open_recording(
    settings: TelemetrySettings, path: Path, recording_id: str, serve_port: int | None
) -> rr.RecordingStream:
    """A recording stream writing to `path` (and serving on `serve_port` if given)."""
    rec = rr.RecordingStream(settings.app_id, recording_id=recording_id)
    sinks: list[rr.FileSink | rr.GrpcServerSink] = [rr.FileSink(str(path))]
    if serve_port is not None:
        sinks.append(rr.GrpcServerSink(bind_ip=settings.serve_bind_ip, port=serve_port))
    rec.set_sinks(*sinks, default_blueprint=default_blueprint())
    return rec


def add_args(ap: argparse.ArgumentParser) -> None:
    """The telemetry's own options."""
    ap.add_argument("--out", metavar="DIR",
                    help="run folder to record into (default: <runs_dir>/<timestamp>)")
    ap.add_argument("--serve", metavar="PORT", type=int,
                    help="also serve the live stream on this port ([telemetry] serve_bind_ip)")
    ap.add_argument("--viewer", action="store_true",
                    help="spawn a Rerun viewer on the live stream (only with a display)")


def run(cfg: RacestackConfig, args: argparse.Namespace, stop: threading.Event) -> int:
    """The service body (see the module docstring)."""
    tset = settings_of(cfg)
    track = load_track(cfg.track.source)
    profile = track_profile(track, cfg.curvature)
    serve_port = args.serve if args.serve is not None else tset.serve_port
    want_viewer = bool(args.viewer or tset.viewer)
    if want_viewer and serve_port is None:
        serve_port = free_loopback_port() if tset.serve_bind_ip == "127.0.0.1" else 9876
    if serve_port is not None:
        problem = serve_problem(tset.serve_bind_ip, serve_port)
        if problem:
            print(f"{SERVICE}: error: cannot serve the live stream: {problem}", file=sys.stderr)
            return 2
        if not ipaddress.ip_address(tset.serve_bind_ip).is_loopback:
            log.warning("the live stream is served on %s (not loopback): anyone on that "
                        "network can read it", tset.serve_bind_ip)
    run_dir = Path(args.out) if args.out else new_run_dir(tset.runs_dir)
    run_dir.mkdir(parents=True, exist_ok=True)
    rrd = free_recording_path(run_dir)
    started = time.time()
    recording_id = f"{cfg.bus.car}-{run_dir.name}-{rrd.stem}"
    rec = open_recording(tset, rrd, recording_id, serve_port)
    try:
        save_blueprint(run_dir / "telemetry.rbl", tset.app_id)
    except Exception as exc:  # the layout is also inside the recording
        log.warning("could not write telemetry.rbl: %s", exc)
    print(f"{SERVICE}: recording to {rrd}", flush=True)
    if serve_port is not None:
        url = connect_url(tset.serve_bind_ip, serve_port)
        print(f"{SERVICE}: watch live with: rerun --connect {url}", flush=True)
        if want_viewer:
            spawn_viewer(url)
    recorder = Recorder(rec, tset)
    recorder.log_static(track, profile, {
        "car": cfg.bus.car,
        "started_wall_s": started,
        "timeline": tset.timeline,
        "track_source": cfg.track.source,
        "host": socket.gethostname(),
    })
    inbox = Inbox(tset.queue_size, tset.event_queue_max)
    try:
        with Bus(cfg.bus, SERVICE, announce=False) as bus:
            subs = {
                suffix: bus.subscribe(bus.keys.key(suffix), REGISTRY[tag],
                                      callback=functools.partial(inbox.put, suffix))
                for suffix, tag in TOPIC_TYPES.items()
            }
            bus.declare_alive(SERVICE)  # alive = subscribed: publishers may start
            log.info("recording %s/** on %s", bus.keys.prefix, rrd)
            next_stats = next_flush = time.monotonic()
            while not stop.is_set():
                tick = time.monotonic()
                for item in inbox.get_batch(timeout_s=LOOP_PERIOD_S):
                    recorder.handle(item.suffix, item.msg, item.recv_wall_s)
                recorder.periodic()
                mono = time.monotonic()
                if mono >= next_stats:
                    next_stats = mono + STATS_INTERVAL_S
                    recorder.note_rejected(bus.drops.snapshot())
                    recorder.note_queue(len(inbox), inbox.dropped(),
                                        {s: sub.seq_gaps for s, sub in subs.items()})
                if mono >= next_flush:
                    next_flush = mono + tset.flush_interval_s
                    recorder.flush()
                    rec.flush(timeout_sec=0.0)
                rest = LOOP_PERIOD_S - (time.monotonic() - tick)
                if rest > 0.0:  # work in batches: fewer wake-ups, cheaper per message
                    stop.wait(rest)
            rejected = bus.drops.snapshot()
            seq_gaps = {s: sub.seq_gaps for s, sub in subs.items()}
        # the session is closed: nothing arrives any more; log what is still queued
        for item in inbox.drain():
            recorder.handle(item.suffix, item.msg, item.recv_wall_s)
        recorder.note_rejected(rejected)
        recorder.note_queue(0, inbox.dropped(), seq_gaps)
        stats = {
            "recording": str(rrd),
            "duration_s": time.time() - started,
            "received": inbox.received(),
            "logged": dict(recorder.counts),
            "dropped_by_queue": inbox.dropped(),
            "rejected": {f"{k} {r}": n for (k, r), n in rejected.items()},
            "seq_gaps": {k: n for k, n in seq_gaps.items() if n},
            "record_errors": recorder.errors,
        }
        recorder.event("telemetry", "info",
                       f"recording closed: {sum(recorder.counts.values())} messages logged, "
                       f"{sum(inbox.dropped().values())} dropped by the queue, "
                       f"{sum(rejected.values())} rejected")
        recorder.close()
        rrd.with_name(f"{rrd.stem}_stats.json").write_text(
            json.dumps(stats, indent=2) + "\n", encoding="utf-8")
        log.info("closed %s: %s", rrd, json.dumps({k: stats[k] for k in (
            "received", "dropped_by_queue", "rejected", "seq_gaps")}))
    finally:
        try:
            rec.flush(timeout_sec=CLOSE_TIMEOUT_S)
        except Exception as exc:
            log.warning("final flush failed: %s", exc)
        rec.disconnect()
    return 0


def main(argv: Sequence[str] | None = None) -> int:
    """``python -m services.telemetry`` / ``racestack run telemetry``."""
    return run_service(SERVICE, argv, run, add_args, description=__doc__.splitlines()[0])
