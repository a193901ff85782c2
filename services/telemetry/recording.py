"""One telemetry run on disk: its folder, its ``.rrd`` segments, the live stream, the stats.

``start_recording`` opens what the telemetry service records into (before its bus opens, so
a port that cannot be served fails at once with a configuration error): the run folder
(``<[telemetry] runs_dir>/<YYYYmmdd-HHMMSS>/`` unless given), the first segment
``telemetry.0000.rrd`` with the default layout (also saved as ``telemetry.rbl``; a second
run in the same folder is ``telemetry-2.0000.rrd``..., never overwritten), the optional live
gRPC stream and viewer, and the ``Recorder`` with the track drawn.

Segments: ``RunRecording.rotate`` (every ``[telemetry] segment_interval_s``) flushes the open
segment and replaces the stream's file sink with one writing ``<stem>.<n+1>.rrd`` (the
replaced sink writes its footer: the closed file then passes ``rerun rrd verify``); the
recorder logs the static data again, so each segment holds the track and the run
information; all are one recording id (a viewer opening several shows one run;
``racestack report`` reads them as one). A SIGKILL leaves the closed segments intact and the
open one without a footer (readable by streaming up to its last flush).

Memory (rerun-sdk 0.41): a file sink keeps an index of every chunk until its footer is
written, so one file grows the process with the race; closing segments bounds that. But a
NEW ``RecordingStream`` per segment leaks memory that is never given back, and so does every
blueprint sent (``default_blueprint=`` or ``send_blueprint``): so the run keeps ONE stream,
swaps only its file sink, and sends the default layout once, into the first segment (and
``telemetry.rbl`` beside it, for any segment alone: ``rerun telemetry.0003.rrd
telemetry.rbl``). The live stream is a separate stream (gRPC
only, at most ``serve_memory_limit_mb`` kept) that lives for the whole run.

``RunRecording.finish`` logs what is still queued and writes ``<stem>_stats.json``;
``RunRecording.close`` flushes and disconnects the open segment and the live stream.
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
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import rerun as rr

from services.telemetry.blueprint import Bounds, default_blueprint, save_blueprint
from services.telemetry.inbox import Inbox
from services.telemetry.recorder import Recorder
from shared.config import ConfigError, RacestackConfig
from shared.config.telemetry import TelemetrySettings
from shared.curvature import track_profile
from shared.net import free_loopback_port
from shared.track import Track, load_track

log = logging.getLogger(__name__)
#: Stem of the recording's segments inside the run folder (``telemetry.0000.rrd``, ...).
RRD_STEM = "telemetry"
#: File name of a single-file recording (read like a run of segments).
RRD_NAME = f"{RRD_STEM}.rrd"
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


def segment_path(run_dir: Path, stem: str, index: int) -> Path:
    """``run_dir/<stem>.<index:04d>.rrd``: segment `index` (0, 1, ...) of a recording."""
    return run_dir / f"{stem}.{index:04d}.rrd"


def free_recording_stem(run_dir: Path) -> str:
    """``telemetry``, or ``telemetry-<n>`` if a recording of that stem (single file or
    segments) is already in `run_dir` (never overwrite)."""
    stem, n = RRD_STEM, 2
    while (run_dir / f"{stem}.rrd").exists() or segment_path(run_dir, stem, 0).exists():
        stem = f"{RRD_STEM}-{n}"
        n += 1
    return stem


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


def track_bounds(track: Track) -> Bounds:
    """(x_min, x_max, y_min, y_max) [m] of the track's boundaries in the map frame."""
    pts = np.vstack([track.left_boundary, track.right_boundary])
    x0, y0 = pts.min(axis=0)
    x1, y1 = pts.max(axis=0)
    return float(x0), float(x1), float(y0), float(y1)


def open_segment(settings: TelemetrySettings, path: Path, recording_id: str,
                 bounds: Bounds | None = None) -> rr.RecordingStream:
    """A recording stream writing its first segment file, `path`, with the default layout
    (the track view on the map `bounds`, see ``blueprint.default_blueprint``)."""
    rec = rr.RecordingStream(settings.app_id, recording_id=recording_id)
    rec.set_sinks(rr.FileSink(str(path)), default_blueprint=default_blueprint(bounds))
    return rec


def switch_segment(rec: rr.RecordingStream, path: Path) -> None:
    """Flush `rec` (up to ``CLOSE_TIMEOUT_S``) and make it write to `path` instead: the
    replaced file sink writes its footer (no blueprint is sent again: each one leaks)."""
    try:
        rec.flush(timeout_sec=CLOSE_TIMEOUT_S)
    except Exception as exc:
        log.warning("flushing before a new segment failed: %s", exc)
    rec.set_sinks(rr.FileSink(str(path)))


def open_live(settings: TelemetrySettings, recording_id: str, port: int,
              bounds: Bounds | None = None) -> rr.RecordingStream:
    """A recording stream serving the run live on ``serve_bind_ip``:`port` (gRPC), keeping
    at most ``serve_memory_limit_mb`` for viewers that connect late."""
    rec = rr.RecordingStream(settings.app_id, recording_id=recording_id)
    rec.set_sinks(
        rr.GrpcServerSink(bind_ip=settings.serve_bind_ip, port=port,
                          server_memory_limit=f"{settings.serve_memory_limit_mb}MiB"),
        default_blueprint=default_blueprint(bounds),
    )
    return rec


class StreamTee:
    """Forwards every call (``log``, ``send_columns``, ``set_time``, ...) to several
    recording streams: the open segment and the live stream get the same data."""

    def __init__(self, *streams: rr.RecordingStream) -> None:
        self.streams = streams

    def __getattr__(self, name: str) -> Any:
        methods = [getattr(s, name) for s in self.streams]

        def call(*args: Any, **kwargs: Any) -> None:
            for method in methods:
                method(*args, **kwargs)

        return call


@dataclass
class RunRecording:
    """An open run: its open segment, its recorder, where it is written, when it started.

    Attributes:
        rec: the stream of the open segment.
        recorder: the ``Recorder`` logging into it (and into ``live``).
        run_dir: the run folder.
        stem: the segments' file stem (``telemetry``; ``<stem>.<n>.rrd``).
        recording_id: the Rerun recording id shared by every segment.
        settings: the ``[telemetry]`` settings.
        started_wall_s: wall-clock start [s].
        live: the live gRPC stream (None: file only).
        segments: every segment opened so far, the open one last.
    """

    rec: rr.RecordingStream
    recorder: Recorder
    run_dir: Path
    stem: str
    recording_id: str
    settings: TelemetrySettings
    started_wall_s: float
    live: rr.RecordingStream | None = None
    segments: list[Path] = field(default_factory=list)

    @property
    def rrd(self) -> Path:
        """The open segment's file."""
        return self.segments[-1]

    def flush(self) -> None:
        """Start writing out what was logged (does not wait)."""
        self.rec.flush(timeout_sec=0.0)
        if self.live is not None:
            self.live.flush(timeout_sec=0.0)

    def rotate(self) -> Path:
        """Close the open segment (series sent, flushed up to ``CLOSE_TIMEOUT_S``, its sink
        replaced: its footer is written) and go on in the next; returns the closed file."""
        closed = self.rrd
        self.recorder.flush()
        nxt = segment_path(self.run_dir, self.stem, len(self.segments))
        switch_segment(self.rec, nxt)
        self.segments.append(nxt)
        self.recorder.rebind(self.recorder.rec)  # the static data again, into the new file
        return closed

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
            "series_samples_sent": recorder.scalars.sent,
            "messages_decimated": recorder.shed,
            "drawings": recorder.drawn,
            "send_delay_ms": delay_summary(recorder.scalars.delays_s),
            "draw_delay_ms": delay_summary(recorder.draw_delays_s),
        }
        recorder.event("telemetry", "info",
                       f"recording closed: {sum(recorder.counts.values())} messages logged, "
                       f"{sum(inbox.dropped().values())} dropped by the queue, "
                       f"{sum(rejected.values())} rejected")
        recorder.close()
        stats["segments"] = [p.name for p in self.segments]
        (self.run_dir / f"{self.stem}_stats.json").write_text(
            json.dumps(stats, indent=2) + "\n", encoding="utf-8")
        log.info("closed %s: %s", self.rrd, json.dumps({k: stats[k] for k in (
            "received", "dropped_by_queue", "rejected", "seq_gaps")}))

    def close(self) -> None:
        """Flush the open segment and the live stream (up to ``CLOSE_TIMEOUT_S`` each) and
        disconnect them (the segment gets its footer)."""
        _close_stream(self.rec, self.rrd)
        if self.live is not None:
            _close_stream(self.live, None)


def delay_summary(delays_s: Iterable[float]) -> dict[str, float | int | None]:
    """n, median, p99 and max [ms] of delays [s] (None without samples)."""
    a = np.fromiter(delays_s, dtype=float) * 1e3
    if a.size == 0:
        return {"n": 0, "median": None, "p99": None, "max": None}
    return {"n": int(a.size), "median": round(float(np.median(a)), 2),
            "p99": round(float(np.percentile(a, 99)), 2), "max": round(float(a.max()), 2)}


def _close_stream(rec: rr.RecordingStream, path: Path | None) -> None:
    """Flush `rec` (up to ``CLOSE_TIMEOUT_S``) and disconnect its sinks (a file sink then
    writes its footer); a failed flush is logged, never raised."""
    try:
        rec.flush(timeout_sec=CLOSE_TIMEOUT_S)
    except Exception as exc:
        log.warning("flushing %s failed: %s", path or "the live stream", exc)
    rec.disconnect()


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
    stem = free_recording_stem(run_dir)
    rrd = segment_path(run_dir, stem, 0)
    started = time.time()
    recording_id = f"{cfg.bus.car}-{run_dir.name}-{stem}"
    bounds = track_bounds(track)
    rec = open_segment(tset, rrd, recording_id, bounds)
    live = (open_live(tset, recording_id, serve_port, bounds) if serve_port is not None
            else None)
    try:
        save_blueprint(run_dir / "telemetry.rbl", tset.app_id, bounds)
    except Exception as exc:  # the layout is also inside the recording
        log.warning("could not write telemetry.rbl: %s", exc)
    print(f"telemetry: recording to {rrd} (a new segment every {tset.segment_interval_s:g} s)",
          flush=True)
    if serve_port is not None:
        url = connect_url(tset.serve_bind_ip, serve_port)
        print(f"telemetry: watch live with: rerun --connect {url}", flush=True)
        if want_viewer:
            spawn_viewer(url)
    recorder = Recorder(rec if live is None else StreamTee(rec, live), tset)
    recorder.log_static(track, profile, {
        "car": cfg.bus.car,
        "started_wall_s": started,
        "timeline": tset.timeline,
        "track_source": cfg.track.source,
        "host": socket.gethostname(),
    })
    return RunRecording(rec, recorder, run_dir, stem, recording_id, tset, started, live, [rrd])
