"""Settings of the telemetry service (``[telemetry]``): recording, live stream, load limits.

The telemetry service subscribes to every key of the car, turns each message into Rerun log
calls and writes them, in segments of ``segment_interval_s``, to
``<runs_dir>/<YYYYmmdd-HHMMSS>/telemetry.0000.rrd``, ``telemetry.0001.rrd``, ... (or
``--out DIR``); ``serve_port`` also serves the recording live on ``serve_bind_ip`` (loopback
by default) for ``rerun --connect rerun+http://127.0.0.1:<port>/proxy``.
"""

from __future__ import annotations

import ipaddress
from typing import Literal

from pydantic import Field, field_validator

from shared.car import CAR
from shared.config.base import Section

#: Timeline choice: "auto" puts stamps >= ``WALL_CLOCK_MIN_S`` on ``wall_time``, others on
#: ``sim_time``; the other two force one timeline for every message.
TimelineChoice = Literal["auto", "sim_time", "wall_time"]


class TelemetrySettings(Section):
    """The ``[telemetry]`` section.

    Attributes:
        runs_dir: parent folder of the run folders (``runs/<timestamp>/telemetry.NNNN.rrd``).
        app_id: Rerun application id of the recordings.
        serve_port: serve the live stream on this TCP port (None: file only).
        serve_bind_ip: address the live gRPC server binds (keep loopback; use an SSH tunnel
            or run the telemetry on the laptop to watch from another machine).
        viewer: spawn a Rerun viewer connected to the live stream when a display exists.
        timeline: "auto" | "sim_time" | "wall_time" (see ``TimelineChoice``).
        queue_size: data messages waiting for the logging thread; when full the OLDEST is
            dropped and counted per key (lap and log events have their own queue).
        event_queue_max: safety cap of the event queue (lap / log / control events), which
            is never trimmed by the queue policy below this size [messages].
        batch_interval_s: scalar series are buffered and sent as columns this often [s].
        flush_interval_s: the recording is flushed to disk this often [s] (crash safety).
        segment_interval_s: the open segment is closed (flushed, footer written) and the next
            one opened this often [s of wall time]: a SIGKILL loses at most the open segment's
            last ``flush_interval_s``, every closed segment verifies (``rerun rrd verify``),
            and the SDK's per-file memory (it keeps an index of every chunk until the footer)
            stays bounded by one segment.
        serve_memory_limit_mb: most data the live gRPC server keeps for late viewers [MiB]
            (the oldest is dropped beyond it).
        visual_max_hz: most car / truth / horizon drawings per second of message time [Hz].
        series_max_hz: most scalar samples per second of message time per key [Hz] (a 100 Hz
            key is plotted at this rate, in the recording and the live stream alike; lap and
            log events are never decimated; 0 keeps every message).
        max_queue_age_s: data messages that waited longer than this for the logging thread
            are dropped (and counted per key) instead of logged late: when the telemetry
            falls behind it catches up at once instead of lagging [s].
        drop_summary_interval_s: the services' by-design "dropped N valid messages ...
            overwritten" info reports are logged raw under ``events/drops`` and summarised
            in the event log once per this interval per service [s of message time].
        scan_max_hz: most lidar scans drawn per second of message time [Hz] (0: none).
        path_interval_s: the driven path of the current lap is redrawn this often [s of
            message time].
        max_path_points: points kept per lap of the driven path (halved when exceeded).
        speed_color_max_mps: speed [m/s] drawn in the hottest colour of the path.
        car_length_m, car_width_m: footprint of the car drawn around its position [m].
        stale_after_s: a key that went silent for this long gives a "stale input" warning [s].
        warn_interval_s: shortest interval between two warnings of one kind [s].
    """

    runs_dir: str = Field("runs", min_length=1)
    app_id: str = Field("racestack", min_length=1, max_length=64)
    serve_port: int | None = Field(None, ge=1, le=65535)
    serve_bind_ip: str = "127.0.0.1"
    viewer: bool = False
    timeline: TimelineChoice = "auto"
    queue_size: int = Field(4096, ge=16, le=1_000_000)
    event_queue_max: int = Field(100_000, ge=100, le=10_000_000)
    batch_interval_s: float = Field(0.5, gt=0.0, le=5.0)
    flush_interval_s: float = Field(1.0, gt=0.0, le=60.0)
    segment_interval_s: float = Field(60.0, gt=0.0, le=3600.0)
    serve_memory_limit_mb: int = Field(256, ge=16, le=65536)
    visual_max_hz: float = Field(20.0, gt=0.0, le=1000.0)
    series_max_hz: float = Field(30.0, ge=0.0, le=1000.0)
    max_queue_age_s: float = Field(2.0, gt=0.0, le=60.0)
    drop_summary_interval_s: float = Field(30.0, gt=0.0, le=3600.0)
    scan_max_hz: float = Field(10.0, ge=0.0, le=1000.0)
    path_interval_s: float = Field(0.5, gt=0.0, le=60.0)
    max_path_points: int = Field(5000, ge=10, le=1_000_000)
    speed_color_max_mps: float = Field(5.0, gt=0.0, le=50.0)
    car_length_m: float = Field(CAR.length_m, gt=0.0, le=10.0)
    car_width_m: float = Field(CAR.width_m, gt=0.0, le=10.0)
    stale_after_s: float = Field(0.5, gt=0.0, le=60.0)
    warn_interval_s: float = Field(5.0, ge=0.0, le=3600.0)

    @field_validator("serve_bind_ip")
    @classmethod
    def _ip_ok(cls, v: str) -> str:
        ipaddress.ip_address(v)  # ValueError on anything but an IP address
        return v
