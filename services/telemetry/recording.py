"""One telemetry run on disk: its folder, its ``.rrd`` recording, the live stream, the stats.

``start_recording`` opens what the telemetry service records into (before its bus opens, so
a port that cannot be served fails at once with a configuration error): the run folder
(``<[telemetry] runs_dir>/<YYYYmmdd-HHMMSS>/`` unless given; never overwritten:
``telemetry-2.rrd``...), the recording stream with the default layout (also saved as
``telemetry.rbl``), the optional live gRPC stream and viewer, and the ``Recorder`` with the
track drawn. ``RunRecording.finish`` logs what is still queued and writes
``telemetry_stats.json``; ``RunRecording.close`` flushes and disconnects the stream.
"""

from __future__ import annotations

import ipaddress
import json
import logging
import os
import socket
import subprocess
import sys
import time
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path

import rerun as rr

from services.telemetry.blueprint import default_blueprint, save_blueprint
from services.telemetry.inbox import Inbox
from services.telemetry.recorder import Recorder
from shared.config import ConfigError, RacestackConfig
from shared.config.telemetry import TelemetrySettings
from shared.curvature import track_profile
from shared.net import free_loopback_port
from shared.track import load_track

log = logging.getLogger(__name__)
#: File name of the recording inside the run folder.
RRD_NAME = "telemetry.rrd"
#: Longest wait for the final flush at exit [s].
CLOSE_TIMEOUT_S = 5.0
#: Port of the live stream with ``--viewer`` on a non-loopback address and no port given.
DEFAULT_SERVE_PORT = 9876


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


@dataclass
class RunRecording:
    """An open run: the stream, its recorder, where it is written, when it started.

    Attributes:
        rec: the Rerun recording stream.
        recorder: the ``Recorder`` logging into it.
        rrd: the recording file.
        started_wall_s: wall-clock start [s].
    """

    rec: rr.RecordingStream
    recorder: Recorder
    rrd: Path
    started_wall_s: float

    def finish(
        self,
        inbox: Inbox,
        rejected: Mapping[tuple[str, str], int],
        seq_gaps: Mapping[str, int],
    ) -> None:
        """After the bus closed: log what is still queued, close the recorder and write
        ``<rrd stem>_stats.json`` (received, logged, dropped, rejected, gaps, errors)."""
        recorder = self.recorder
        for item in inbox.drain():
            recorder.handle(item.suffix, item.msg, item.recv_wall_s)
        recorder.note_rejected(rejected)
        recorder.note_queue(0, inbox.dropped(), seq_gaps)
        stats = {
            "recording": str(self.rrd),
            "duration_s": time.time() - self.started_wall_s,
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
        self.rrd.with_name(f"{self.rrd.stem}_stats.json").write_text(
            json.dumps(stats, indent=2) + "\n", encoding="utf-8")
        log.info("closed %s: %s", self.rrd, json.dumps({k: stats[k] for k in (
            "received", "dropped_by_queue", "rejected", "seq_gaps")}))

    def close(self) -> None:
        """Flush the stream (up to ``CLOSE_TIMEOUT_S``) and disconnect its sinks."""
        try:
            self.rec.flush(timeout_sec=CLOSE_TIMEOUT_S)
        except Exception as exc:
            log.warning("final flush failed: %s", exc)
        self.rec.disconnect()


def start_recording(
    cfg: RacestackConfig,
    out: str | None = None,
    serve: int | None = None,
    viewer: bool = False,
) -> RunRecording:
    """Open the run of the telemetry service (see the module docstring).

    Args:
        cfg: the configuration (``[telemetry]``, ``[track]``, ``[curvature]``, car name).
        out: the run folder (None: a new one under ``runs_dir``).
        serve: port of the live stream (None: ``[telemetry] serve_port``).
        viewer: spawn a viewer on the live stream (also ``[telemetry] viewer``).

    Raises:
        ConfigError: the live stream cannot be served on that address and port.
    """
    tset = cfg.telemetry
    track = load_track(cfg.track.source)
    profile = track_profile(track, cfg.curvature)
    serve_port = serve if serve is not None else tset.serve_port
    want_viewer = bool(viewer or tset.viewer)
    if want_viewer and serve_port is None:
        loopback = tset.serve_bind_ip == "127.0.0.1"
        serve_port = free_loopback_port() if loopback else DEFAULT_SERVE_PORT
    if serve_port is not None:
        problem = serve_problem(tset.serve_bind_ip, serve_port)
        if problem:
            raise ConfigError(f"cannot serve the live stream: {problem}")
        if not ipaddress.ip_address(tset.serve_bind_ip).is_loopback:
            log.warning("the live stream is served on %s (not loopback): anyone on that "
                        "network can read it", tset.serve_bind_ip)
    run_dir = Path(out) if out else new_run_dir(tset.runs_dir)
    run_dir.mkdir(parents=True, exist_ok=True)
    rrd = free_recording_path(run_dir)
    started = time.time()
    rec = open_recording(tset, rrd, f"{cfg.bus.car}-{run_dir.name}-{rrd.stem}", serve_port)
    try:
        save_blueprint(run_dir / "telemetry.rbl", tset.app_id)
    except Exception as exc:  # the layout is also inside the recording
        log.warning("could not write telemetry.rbl: %s", exc)
    print(f"telemetry: recording to {rrd}", flush=True)
    if serve_port is not None:
        url = connect_url(tset.serve_bind_ip, serve_port)
        print(f"telemetry: watch live with: rerun --connect {url}", flush=True)
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
    return RunRecording(rec, recorder, rrd, started)
