"""The transport-free core of the telemetry: decoded records + their key -> Rerun log calls.

``Recorder.handle(suffix, record, recv_wall_s)`` turns one message into drawings, scalar
series and text logs on a ``rr.RecordingStream``; it never sees Zenoh or bytes, so tests
drive it directly. Everything is placed on the MESSAGE time (``stamp_s``), never the time
of arrival: stamps >= ``WALL_CLOCK_MIN_S`` go on the ``wall_time`` timeline (a timestamp),
smaller ones on ``sim_time`` (a duration), unless ``TelemetrySettings.timeline`` forces one.

Entity layout (units in the names or below):

* static: ``world`` (``Transform3D`` scale (1, -1, 1): the map shown north up in the 2D
  track view, see ``blueprint``), ``world/track/{centerline,left,right}`` (line strips
  [m]), ``world/track/nsc`` (centreline points coloured by the NSC), ``meta/track`` (name,
  source, length_m),
  ``meta/run`` (car, start time, timeline choice).
* drawings (at most ``visual_max_hz`` per entity, styles static): ``world/car``
  (strip 0 the ``car_length_m`` x ``car_width_m`` footprint outline, strip 1 the body: a
  line along the car as wide as the car, filling the footprint; a heading arrow; from
  ``State``),
  ``world/truth`` (simulator truth footprint), ``world/pose`` (localiser pose, drawn only
  while no ``State`` arrives),
  ``world/plan/horizon`` (predicted horizon, points coloured by planned speed),
  ``world/car_beta`` (a halo under the car coloured by the NSC), ``now`` (a text of beta,
  NSC, speed, lap, e_con, solver; at most ``NOW_MAX_HZ``),
  ``world/path/lap_<k>`` (driven path of lap k coloured by speed), ``world/scan`` (lidar
  points in the map frame, placed with the newest pose).
* scalars (at most ``series_max_hz`` messages per key and second of message time, see
  ``shedding.Decimator``; events never): ``speed/{measured,commanded,odom,truth,progress}`` [m/s],
  ``steering/{measured,commanded,odom,truth}`` [rad], ``track_error/{e_con,e_con_truth}``
  [m], ``beta/{beta,nsc}`` [-], ``solver/{solve_time_ms,status_code,iterations,
  consecutive_failures}`` (status code 0 solved, 1 fallback, 2 braking, 3 recovering),
  ``latency/<key>`` [ms], ``laps/{lap_time_s,mean_speed_mps}``, ``vesc/<field>`` (units as
  in ``VescState``), ``health/{state_valid,state_age_ms,pose_sigma_x_m,pose_sigma_y_m,
  pose_sigma_yaw_rad}``, ``imu/*``, ``state/{x_m,y_m,yaw_rad}``, ``plan/s_m``,
  ``truth/{x_m,y_m,s_m,off_track,lap,slip_rad,yaw_rate_radps}``,
  ``telemetry/{queue_depth,dropped/<key>,rejected/<key>,seq_gaps/<key>}`` [messages].
* text logs: ``events/lap`` (lap events, also as ``AnyValues`` fields for the report),
  ``events/log/<source>`` (``LogEvent``; the by-design "overwritten" drop reports are logged
  at debug level on ``events/drops/<source>`` and summarised here once per
  ``drop_summary_interval_s``), ``events/telemetry`` (stale input, solver
  fallback, off track, rejected or dropped messages), ``events/sim_control``,
  ``events/teleport``.
* ``world/opponents``: the footprints of the tracked opponents (``opponents``), labelled
  with their track ids; ``opponents/count`` [tracks].
* ``plan/info``: ``AnyValues`` (method, status) whenever they change.

Latency ``latency/<key>`` is the message age at arrival, ``recv - stamp_s`` [ms], for
wall-clock stamps; for simulation-time stamps (no shared clock) it is the age relative to the
smallest ``recv - stamp_s`` seen on that key, i.e. the queuing / transport delay on top of
the best case.
"""

from __future__ import annotations

import collections
import math
import re
import time
from collections.abc import Callable, Mapping
from typing import Any

import numpy as np
import rerun as rr

from services.telemetry import blueprint as layout
from services.telemetry import colors
from services.telemetry.inbox import EVENT_SUFFIXES
from services.telemetry.shedding import Decimator, DropSummary, Summary, parse_overwritten_drops
from shared import keys
from shared.config.telemetry import TelemetrySettings
from shared.curvature import CurvatureProfile
from shared.messages import (
    DriveCmd,
    HorizonCol,
    Imu,
    InputCol,
    LapEvent,
    LapKindName,
    LogEvent,
    LogLevelName,
    Message,
    Odom,
    Opponents,
    Plan,
    PlanStatusName,
    Pose,
    PoseAxis,
    Scan,
    SimControl,
    SimTruth,
    State,
    Teleport,
    VescState,
    VescStatusName,
)
from shared.ratelimit import RateLimiter
from shared.track import Track

#: Stamps at or above this [s] (2001-09-09) are wall-clock seconds since the epoch.
WALL_CLOCK_MIN_S = 1e9
SIM_TIME = "sim_time"
WALL_TIME = "wall_time"
#: Send delays kept for the statistics (the newest samples) [samples].
DELAY_SAMPLES = 100_000
#: Most "Now" panel updates per second of message time [Hz].
NOW_MAX_HZ = 5.0
#: ``solver/status_code`` of each ``Plan.status``.
STATUS_CODES = {
    PlanStatusName.SOLVED: 0,
    PlanStatusName.FALLBACK: 1,
    PlanStatusName.BRAKING: 2,
    PlanStatusName.RECOVERING: 3,
}
_LEVELS = {
    LogLevelName.DEBUG: rr.TextLogLevel.DEBUG,
    LogLevelName.INFO: rr.TextLogLevel.INFO,
    LogLevelName.WARNING: rr.TextLogLevel.WARN,
    LogLevelName.ERROR: rr.TextLogLevel.ERROR,
}
_INFO, _WARNING, _ERROR = LogLevelName.INFO, LogLevelName.WARNING, LogLevelName.ERROR
_UNSAFE = re.compile(r"[^A-Za-z0-9_-]")
_VESC_FIELDS = tuple(
    f.name
    for f in VescState.fields_info()
    if f.name not in ("status", "stamp_s", "seq")
)
#: Keys whose silence is reported as stale input (once seen).
WATCHED_SUFFIXES = (keys.STATE, keys.POSE, keys.ODOM, keys.PLAN, keys.DRIVE_CMD)


def flat(suffix: str) -> str:
    """An entity-path-safe name of a key suffix: ``vehicle/pose`` -> ``vehicle_pose``."""
    return _UNSAFE.sub("_", suffix.replace("/", "_"))


def timeline_of(stamp_s: float, choice: str = "auto") -> str:
    """The timeline a stamp [s] goes on: ``sim_time`` or ``wall_time`` (see module doc)."""
    if choice == "auto":
        return WALL_TIME if stamp_s >= WALL_CLOCK_MIN_S else SIM_TIME
    return choice


def car_body(x: float, y: float, yaw: float, length: float, width: float) -> np.ndarray:
    """(2, 2) axis [m] of the car's body, drawn as a line `width` wide with round ends: it
    fills the `length` x `width` footprint centred at (x, y), heading `yaw`."""
    half = max(0.0, 0.5 * (length - width))
    d = np.array([math.cos(yaw), math.sin(yaw)]) * half
    c = np.array([x, y])
    return np.stack([c - d, c + d])


def footprint(x: float, y: float, yaw: float, length: float, width: float) -> np.ndarray:
    """Closed (5, 2) outline [m] of a `length` x `width` box centred at (x, y), heading yaw."""
    c, s = math.cos(yaw), math.sin(yaw)
    hl, hw = 0.5 * length, 0.5 * width
    local = np.array([[hl, hw], [-hl, hw], [-hl, -hw], [hl, -hw], [hl, hw]])
    rot = np.array([[c, -s], [s, c]])
    return local @ rot.T + np.array([x, y])


def now_text(beta: float, nsc: float | None, plan: Plan, lap: int,
             speed_mps: float | None) -> str:
    """The "Now" panel: beta and NSC at the car, speed, lap, contour error, solver."""
    lines = [f"beta {beta:.2f}" + (f"   NSC {nsc:.2f}" if nsc is not None else "   NSC -")]
    v = f"{speed_mps:.2f} m/s" if speed_mps is not None else "-"
    lines.append(f"v {v}   lap {lap}")
    lines.append(f"e_con {plan.e_con_m:+.3f} m   s {plan.s_m:.1f} m")
    lines.append(f"{plan.method} {plan.status} {plan.solve_time_ms:.1f} ms")
    return "\n".join(lines)


class ScalarBatcher:
    """Buffers scalar samples per (entity, timeline) and sends them as columns.

    One ``send_columns`` of many samples costs about as much as one ``log`` call, so the
    series cost almost nothing per message.
    """

    def __init__(self, rec: rr.RecordingStream, clock: Callable[[], float] = time.time) -> None:
        self._rec = rec
        self._clock = clock
        self._buf: dict[tuple[str, str], tuple[list[float], list[float]]] = {}
        self.pending = 0  #: samples buffered
        self.muted = False  #: True while the message being handled is decimated away
        self.sent = 0  #: samples sent so far
        #: send delay [s] (wall clock at the send - the sample's ``wall_time`` stamp) of the
        #: most recent samples sent
        self.delays_s: collections.deque[float] = collections.deque(maxlen=DELAY_SAMPLES)

    def add(self, entity: str, timeline: str, t_s: float, value: float) -> None:
        """Buffer one sample: `value` of `entity` at time `t_s` [s] on `timeline` (ignored
        while ``muted``)."""
        if self.muted:
            return
        entry = self._buf.get((entity, timeline))
        if entry is None:
            entry = self._buf[(entity, timeline)] = ([], [])
        entry[0].append(t_s)
        entry[1].append(value)
        self.pending += 1

    def rebind(self, rec: rr.RecordingStream) -> None:
        """Send what is buffered, then go on into `rec` (the counters carry on)."""
        self.flush()
        self._rec = rec

    def flush(self) -> None:
        """Send every buffered series (one chunk per entity and timeline)."""
        if not self.pending:
            return
        buf, self._buf, self.pending = self._buf, {}, 0
        now = self._clock()
        for (entity, timeline), (times, values) in buf.items():
            t = np.asarray(times, dtype=np.float64)
            self.sent += t.size
            if timeline == WALL_TIME:
                self.delays_s.extend((now - t).tolist())
            index = (
                rr.TimeColumn(timeline, timestamp=t)
                if timeline == WALL_TIME
                else rr.TimeColumn(timeline, duration=t)
            )
            self._rec.send_columns(
                entity,
                indexes=[index],
                columns=rr.Scalars.columns(scalars=np.asarray(values, dtype=np.float64)),
            )


class Recorder:
    """Turns decoded records into Rerun log calls on one recording stream.

    Args:
        rec: the recording stream (its sinks decide where the data goes).
        settings: the ``[telemetry]`` settings.
        clock: wall clock [s] (for rate limits and silence checks).

    Not thread-safe: one thread (the service's logging thread) calls every method.
    """

    def __init__(
        self,
        rec: rr.RecordingStream,
        settings: TelemetrySettings | None = None,
        clock: Callable[[], float] = time.time,
    ) -> None:
        self.rec = rec
        self.cfg = settings or TelemetrySettings()
        self._clock = clock
        self.scalars = ScalarBatcher(rec, clock)
        self._decimator = Decimator(self.cfg.series_max_hz)
        self._drops = DropSummary(self.cfg.drop_summary_interval_s)
        self._styled: set[str] = set()  # latency entities whose style is logged
        self.drawn = 0  #: drawings logged (car, truth, pose, horizon, scan)
        #: delay [s] from a drawing's ``wall_time`` stamp to its logging (newest ones)
        self.draw_delays_s: collections.deque[float] = collections.deque(maxlen=DELAY_SAMPLES)
        self._warn_limits: dict[str, RateLimiter] = {}
        self._profile: CurvatureProfile | None = None
        self._timeline: str | None = None  # the timeline set on the stream now
        self._last_batch_wall = clock()
        # message-time bookkeeping
        self.last_stamp: tuple[str, float] | None = None  #: (timeline, stamp) of the newest
        self._last_stamp_wall = clock()
        self._min_offset: dict[str, float] = {}
        self._last_visual: dict[str, float] = {}
        self._last_seen_wall: dict[str, float] = {}
        self._silent: set[str] = set()
        # state of the drawings
        self._pose_xyyaw: tuple[float, float, float] | None = None
        self._speed_now: float | None = None  # newest State (else truth) speed [m/s]
        self._lap = 0
        self._path: list[tuple[float, float, float]] = []
        self._path_stride = 1
        self._path_skip = 0
        self._path_last_t: float | None = None
        self._path_from_truth = True  # until the first State arrives
        self._path_entities: set[str] = set()
        self._recv_wall = 0.0  # arrival time of the record being handled [s]
        self._plan_info: tuple[str, str] | None = None
        self._plan_status: str = PlanStatusName.SOLVED
        self._state_valid = True
        self._off_track = False
        self._vesc_status: str | None = None
        self._rejected_seen: dict[tuple[str, str], int] = {}
        self._dropped_seen: dict[str, int] = {}
        self.counts: dict[str, int] = {}  #: records handled per key suffix
        self.errors = 0  #: records whose logging raised (counted, never fatal)
        self._handlers: dict[str, Callable[[Any, str, float, float], None]] = {
            keys.POSE: self._pose,
            keys.IMU: self._imu,
            keys.ODOM: self._odom,
            keys.SCAN: self._scan,
            keys.STATE: self._state,
            keys.DRIVE_CMD: self._cmd,
            keys.PLAN: self._plan,
            keys.LAP: self._lap_event,
            keys.VESC_STATE: self._vesc,
            keys.SIM_TRUTH: self._truth,
            keys.EVENTS_LOG: self._log_event,
            keys.SIM_CONTROL: self._sim_control,
            keys.TELEPORT: self._teleport,
            keys.OPPONENTS: self._opponents,
        }
        self._static: tuple[Track | None, CurvatureProfile | None,
                            Mapping[str, str | float | int] | None] | None = None
        self._prepare_stream()

    def _prepare_stream(self) -> None:
        """The stream's own timelines off, the drawing styles as static data."""
        self.rec.set_log_time_enabled(False)
        self.rec.set_log_tick_enabled(False)
        self._log_styles()

    def rebind(self, rec: rr.RecordingStream) -> None:
        """Go on logging into `rec` (the same stream, now writing the next segment, or
        another one): the buffered series are sent first; then the styles and the static
        data (track, run information) are logged again, so every segment holds them."""
        self.scalars.rebind(rec)
        self.rec = rec
        self._timeline = None
        self._path_entities = set()
        self._styled = set()
        self._plan_info = None
        self._prepare_stream()
        if self._static is not None:
            self.log_static(*self._static)

    def _log_styles(self) -> None:
        """Colours, radii and draw order of the drawings, logged once as static data (each
        tick then sends only its geometry, which is what costs)."""
        rec = self.rec
        # the map frame shown north up (a 2D view draws +y down): see blueprint.py
        rec.log(layout.MAP_ENTITY, rr.Transform3D(scale=layout.MAP_TO_VIEW_SCALE), static=True)
        body_r = 0.5 * self.cfg.car_width_m
        styles: dict[str, list[Any]] = {
            # strip 0: the footprint outline (UI points wide, visible at any zoom);
            # strip 1: the body, a line along the car as wide as the car (the footprint filled)
            "world/car": [
                rr.LineStrips2D.from_fields(colors=[colors.CAR_OUTLINE, colors.CAR],
                                            radii=[-1.5, body_r], draw_order=30.0),
                rr.Arrows2D.from_fields(colors=[colors.CAR_OUTLINE], radii=[-2.0],
                                        draw_order=31.0),
            ],
            "world/truth": [rr.LineStrips2D.from_fields(colors=[colors.TRUTH], radii=[-1.0],
                                                        draw_order=29.0)],
            "world/pose": [rr.Points2D.from_fields(colors=[colors.TRUTH], radii=[0.05],
                                                   draw_order=4.0)],
            "world/plan/horizon": [
                rr.LineStrips2D.from_fields(colors=[colors.HORIZON], radii=[0.01],
                                            draw_order=20.0),
                rr.Points2D.from_fields(radii=[0.035], draw_order=21.0),
            ],
            # a halo under the car coloured by the NSC (its numbers are in the Now panel)
            "world/car_beta": [rr.Points2D.from_fields(
                radii=[0.5 * self.cfg.car_length_m + 0.1], show_labels=False, draw_order=8.0)],
            "world/scan": [rr.Points2D.from_fields(colors=[colors.SCAN], radii=[0.015],
                                                   draw_order=3.0)],
        }
        for entity, parts in styles.items():
            rec.log(entity, *parts, static=True)

    # ------------------------------------------------------------------ static data
    def log_static(
        self,
        track: Track | None,
        profile: CurvatureProfile | None = None,
        meta: Mapping[str, str | float | int] | None = None,
    ) -> None:
        """Log the track (centreline, both boundaries, NSC colours), its name / source and
        `meta` (run information) as static data, plus the series styles."""
        rec = self.rec
        self._profile = profile
        self._static = (track, profile, meta)
        if track is not None:
            for name, pts, color, width in (
                ("centerline", track.xy, colors.CENTRELINE, -1.0),
                ("left", track.left_boundary, colors.TRACK_EDGE, -1.5),
                ("right", track.right_boundary, colors.TRACK_EDGE, -1.5),
            ):
                closed = np.vstack([pts, pts[:1]])
                rec.log(
                    f"world/track/{name}",
                    rr.LineStrips2D([closed], colors=[color], radii=[width], draw_order=1.0),
                    static=True,
                )
            if profile is not None:
                rec.log(
                    "world/track/nsc",
                    rr.Points2D(track.xy, colors=colors.ramp(profile.nsc), radii=-2.0,
                                draw_order=2.0),
                    static=True,
                )
            rec.log(
                "meta/track",
                rr.AnyValues(name=track.name, source=track.source, length_m=track.length_m,
                             n_points=track.n_points),
                rr.TextDocument(
                    f"track {track.name} ({track.length_m:.2f} m, {track.n_points} points)\n"
                    f"source: {track.source}"
                ),
                static=True,
            )
        if meta:
            rec.log("meta/run", rr.AnyValues(**dict(meta)), static=True)
        for entity, style in layout.SERIES_STYLES.items():
            rec.log(entity, _series_style(style), static=True)

    # ------------------------------------------------------------------ time
    def _set_time(self, timeline: str, t_s: float) -> None:
        if self._timeline is not None and self._timeline != timeline:
            self.rec.disable_timeline(self._timeline)
        self._timeline = timeline
        if timeline == WALL_TIME:
            self.rec.set_time(timeline, timestamp=t_s)
        else:
            self.rec.set_time(timeline, duration=t_s)

    def _now_stamp(self) -> tuple[str, float]:
        """The current message time: the newest stamp plus the wall time since it came."""
        if self.last_stamp is None:
            now = self._clock()
            return timeline_of(now, self.cfg.timeline), now
        tl, t = self.last_stamp
        return tl, t + max(0.0, self._clock() - self._last_stamp_wall)

    def _scalar(self, entity: str, tl: str, t: float, value: float | None) -> None:
        if value is not None:
            self.scalars.add(entity, tl, t, float(value))

    def _visual_due(self, entity: str, t: float, max_hz: float) -> bool:
        if max_hz <= 0.0:
            return False
        last = self._last_visual.get(entity)
        if last is not None and 0.0 <= t - last < 0.9 / max_hz:
            return False
        self._last_visual[entity] = t
        self.drawn += 1
        if t >= WALL_CLOCK_MIN_S:
            self.draw_delays_s.append(self._recv_wall - t)
        return True

    # ------------------------------------------------------------------ entry points
    def handle(self, suffix: str, msg: Message, recv_wall_s: float) -> None:
        """Log one record received on key `suffix` at wall time `recv_wall_s` [s].

        Unknown suffixes are ignored; an exception while logging is counted in ``errors``
        and reported as a rate-limited warning, never raised.
        """
        handler = self._handlers.get(suffix)
        if handler is None:
            return
        self.counts[suffix] = self.counts.get(suffix, 0) + 1
        t = msg.stamp_s
        tl = timeline_of(t, self.cfg.timeline)
        self.last_stamp = (tl, t)
        self._last_stamp_wall = recv_wall_s
        self._last_seen_wall[suffix] = recv_wall_s
        self._recv_wall = recv_wall_s
        if suffix in self._silent:
            self._silent.discard(suffix)
            self.event("telemetry", _INFO, f"{suffix}: messages again (input no longer stale)")
        # high-rate keys: their scalar samples at most series_max_hz (events, drawings and
        # the driven path are not affected)
        self.scalars.muted = (suffix not in EVENT_SUFFIXES
                              and not self._decimator.due(suffix, t))
        try:
            self._latency(suffix, tl, t, recv_wall_s)
            handler(msg, tl, t, recv_wall_s)
        except Exception as exc:
            self.errors += 1
            self.warn("record_error", f"could not log a {type(msg).__name__} on {suffix}: "
                      f"{type(exc).__name__}: {exc}")
        finally:
            self.scalars.muted = False

    @property
    def shed(self) -> int:
        """Messages whose scalar samples were left out by the decimation (``series_max_hz``)."""
        return self._decimator.skipped

    def periodic(self, wall_now: float | None = None) -> None:
        """Housekeeping (call often): send the scalar batches when due, report silence."""
        now = self._clock() if wall_now is None else wall_now
        if now - self._last_batch_wall >= self.cfg.batch_interval_s or self.scalars.pending > 20000:
            self._last_batch_wall = now
            self.check_silence(now)
            if self.last_stamp is not None:  # windows close on message time, never ahead
                for summary in self._drops.due(self.last_stamp[1]):
                    self._log_summary(summary)
            self.scalars.flush()

    def flush(self) -> None:
        """Send every buffered scalar now (then ``rec.flush`` writes them out)."""
        self.scalars.flush()

    def event(self, source: str, level: str, text: str, stamp: tuple[str, float] | None = None,
              entity: str | None = None) -> None:
        """A text log on ``events/<source>`` (or `entity`) at message time `stamp`."""
        tl, t = stamp or self._now_stamp()
        self._set_time(tl, t)
        self.rec.log(entity or f"events/{source}", rr.TextLog(text, level=_LEVELS[level]))

    def warn(self, kind: str, text: str, stamp: tuple[str, float] | None = None,
             level: str = _WARNING) -> bool:
        """A rate-limited warning of `kind` on ``events/telemetry``; True if it was logged."""
        limit = self._warn_limits.get(kind)
        if limit is None:
            limit = self._warn_limits[kind] = RateLimiter(self.cfg.warn_interval_s)
        ok, suppressed = limit.allow(self._clock())
        if not ok:
            return False
        if suppressed:
            text += f" (+{suppressed} similar in the last {limit.interval_s:g} s)"
        self.event("telemetry", level, text, stamp)
        return True

    def check_silence(self, wall_now: float) -> None:
        """Warn once when a watched key that was seen has been silent past ``stale_after_s``."""
        for suffix in WATCHED_SUFFIXES:
            seen = self._last_seen_wall.get(suffix)
            if seen is None or suffix in self._silent:
                continue
            if wall_now - seen > self.cfg.stale_after_s:
                self._silent.add(suffix)
                self.event("telemetry", _WARNING,
                           f"stale input: no message on {suffix} for "
                           f"{wall_now - seen:.2f} s")

    def note_rejected(self, snapshot: Mapping[tuple[str, str], int]) -> None:
        """Report payloads the bus rejected (``bus.drops.snapshot()``: (key, reason) -> n).

        Logs cumulative counts per key as ``telemetry/rejected/<key>`` and a rate-limited
        warning with the new drops since the last report.
        """
        new = {kr: n - self._rejected_seen.get(kr, 0) for kr, n in snapshot.items()}
        new = {kr: d for kr, d in new.items() if d > 0}
        if not new:
            return
        tl, t = self._now_stamp()
        per_key: dict[str, int] = {}
        for (key, _reason), n in snapshot.items():
            per_key[key] = per_key.get(key, 0) + n
        for key, n in per_key.items():
            self._scalar(f"telemetry/rejected/{flat(key)}", tl, t, n)
        text = "rejected messages (invalid payloads): " + ", ".join(
            f"{key} {reason} x{n}" for (key, reason), n in sorted(new.items())
        )
        if self.warn("rejected", text, (tl, t)):
            self._rejected_seen = dict(snapshot)

    def note_queue(self, depth: int, dropped: Mapping[str, int],
                   seq_gaps: Mapping[str, int] | None = None) -> None:
        """Report the inbox: queue depth, drops per key (cumulative) and sequence gaps.

        Nothing is logged before the first message: the recording's timeline starts with
        the stack, not with the telemetry's own counters."""
        if self.last_stamp is None and not dropped:
            return
        tl, t = self._now_stamp()
        self._scalar("telemetry/queue_depth", tl, t, depth)
        for suffix, n in (seq_gaps or {}).items():
            if n:
                self._scalar(f"telemetry/seq_gaps/{flat(suffix)}", tl, t, n)
        new = {k: n - self._dropped_seen.get(k, 0) for k, n in dropped.items()}
        new = {k: d for k, d in new.items() if d > 0}
        if not new:
            return
        for suffix, n in dropped.items():
            self._scalar(f"telemetry/dropped/{flat(suffix)}", tl, t, n)
        text = "telemetry overloaded, dropped the oldest messages: " + ", ".join(
            f"{k} x{d}" for k, d in sorted(new.items())
        )
        if self.warn("queue_drop", text, (tl, t)):
            self._dropped_seen = dict(dropped)

    def close(self) -> None:
        """Draw the last path points, log the open drop summaries, send every buffered
        series."""
        if self._path:
            self._log_path()
        for summary in self._drops.flush():
            self._log_summary(summary)
        self.scalars.flush()

    # ------------------------------------------------------------------ per key
    def _latency(self, suffix: str, tl: str, t: float, recv: float) -> None:
        if self.scalars.muted:
            return
        entity = f"latency/{flat(suffix)}"
        if entity not in self._styled:
            self._styled.add(entity)
            self.rec.log(entity, _series_style(layout.SeriesStyle(
                flat(suffix), layout.LATENCY_STYLE.color, layout.LATENCY_STYLE.width,
                points=True)), static=True)
        offset = recv - t
        if tl == SIM_TIME:
            best = self._min_offset.get(suffix)
            if best is None or offset < best:
                best = self._min_offset[suffix] = offset
            offset -= best
        self.scalars.add(entity, tl, t, offset * 1e3)

    def _pose(self, m: Pose, tl: str, t: float, _recv: float) -> None:
        self._pose_xyyaw = (m.x_m, m.y_m, m.yaw_rad)
        add = self.scalars.add
        add("pose/x_m", tl, t, m.x_m)
        add("pose/y_m", tl, t, m.y_m)
        add("pose/yaw_rad", tl, t, m.yaw_rad)
        if m.cov is not None:
            add("health/pose_sigma_x_m", tl, t, math.sqrt(m.cov[PoseAxis.X, PoseAxis.X]))
            add("health/pose_sigma_y_m", tl, t, math.sqrt(m.cov[PoseAxis.Y, PoseAxis.Y]))
            add("health/pose_sigma_yaw_rad", tl, t,
                math.sqrt(m.cov[PoseAxis.YAW, PoseAxis.YAW]))
        # the localiser's pose is drawn only while no State comes (the car shows the State)
        if (self._recv_wall - self._last_seen_wall.get(keys.STATE, -1e18) > 1.0
                and self._visual_due("world/pose", t, self.cfg.visual_max_hz)):
            self._set_time(tl, t)
            self.rec.log("world/pose", rr.Points2D.from_fields(positions=[[m.x_m, m.y_m]]))

    def _imu(self, m: Imu, tl: str, t: float, _recv: float) -> None:
        add = self.scalars.add
        add("imu/yaw_rate_radps", tl, t, m.yaw_rate_radps)
        add("imu/ax_mps2", tl, t, m.ax_mps2)
        add("imu/ay_mps2", tl, t, m.ay_mps2)

    def _odom(self, m: Odom, tl: str, t: float, _recv: float) -> None:
        self.scalars.add("speed/odom", tl, t, m.speed_mps)
        self.scalars.add("steering/odom", tl, t, m.steering_rad)
        self._scalar("odom/yaw_rate_radps", tl, t, m.yaw_rate_radps)

    def _scan(self, m: Scan, tl: str, t: float, _recv: float) -> None:
        if self._pose_xyyaw is None or not self._visual_due("world/scan", t, self.cfg.scan_max_hz):
            return
        x, y, yaw = self._pose_xyyaw
        r = m.ranges_m
        ok = np.isfinite(r)
        ang = (yaw + m.angles_rad())[ok]
        rr_ = r[ok].astype(np.float64)
        pts = np.stack([x + rr_ * np.cos(ang), y + rr_ * np.sin(ang)], axis=1)
        self._set_time(tl, t)
        self.rec.log("world/scan", rr.Points2D.from_fields(positions=pts))

    def _state(self, m: State, tl: str, t: float, _recv: float) -> None:
        add = self.scalars.add
        add("state/x_m", tl, t, m.x_m)
        add("state/y_m", tl, t, m.y_m)
        add("state/yaw_rad", tl, t, m.yaw_rad)
        add("speed/measured", tl, t, m.speed_mps)
        add("steering/measured", tl, t, m.steering_rad)
        add("state/yaw_rate_radps", tl, t, m.yaw_rate_radps)
        add("health/state_valid", tl, t, 1.0 if m.valid else 0.0)
        age = t - m.source_stamp_s
        add("health/state_age_ms", tl, t, age * 1e3)
        self._pose_xyyaw = (m.x_m, m.y_m, m.yaw_rad)
        self._speed_now = m.speed_mps
        if m.valid != self._state_valid:
            self._state_valid = m.valid
            if m.valid:
                self.event("telemetry", _INFO, "state valid again", (tl, t))
            else:
                self.event("telemetry", _WARNING, "state not valid (stale input)", (tl, t))
        elif age > self.cfg.stale_after_s:
            self.warn("stale_state", f"stale input: state built from data {age:.2f} s old",
                      (tl, t))
        if self._path_from_truth:
            self._path_from_truth = False
            self._path.clear()
        self._path_add(m.x_m, m.y_m, m.speed_mps, tl, t)
        if self._visual_due("world/car", t, self.cfg.visual_max_hz):
            self._set_time(tl, t)
            c = self.cfg
            box = footprint(m.x_m, m.y_m, m.yaw_rad, c.car_length_m, c.car_width_m)
            self.rec.log(
                "world/car",
                rr.LineStrips2D.from_fields(strips=[box, car_body(
                    m.x_m, m.y_m, m.yaw_rad, c.car_length_m, c.car_width_m)]),
                rr.Arrows2D.from_fields(
                    origins=[[m.x_m, m.y_m]],
                    vectors=[[1.2 * c.car_length_m * math.cos(m.yaw_rad),
                              1.2 * c.car_length_m * math.sin(m.yaw_rad)]]),
            )

    def _cmd(self, m: DriveCmd, tl: str, t: float, _recv: float) -> None:
        self.scalars.add("speed/commanded", tl, t, m.speed_mps)
        self.scalars.add("steering/commanded", tl, t, m.steering_rad)

    def _plan(self, m: Plan, tl: str, t: float, _recv: float) -> None:
        add = self.scalars.add
        beta = float(m.beta[0])
        add("solver/solve_time_ms", tl, t, m.solve_time_ms)
        add("solver/status_code", tl, t, STATUS_CODES.get(m.status, -1))
        add("solver/iterations", tl, t, m.iterations)
        add("solver/consecutive_failures", tl, t, m.consecutive_failures)
        add("speed/progress", tl, t, float(m.inputs[0, InputCol.V_P]))
        add("track_error/e_con", tl, t, m.e_con_m)
        add("plan/s_m", tl, t, m.s_m)
        add("beta/beta", tl, t, beta)
        nsc = float(self._profile.nsc_at(m.s_m)) if self._profile is not None else None
        self._scalar("beta/nsc", tl, t, nsc)
        info = (m.method, m.status)
        if info != self._plan_info:
            self._plan_info = info
            self._set_time(tl, t)
            self.rec.log("plan/info", rr.AnyValues(method=m.method, status=m.status,
                                                   solver_status=m.solver_status))
        if m.status != self._plan_status:
            if m.status == PlanStatusName.SOLVED:
                self.event("telemetry", _INFO, f"solver recovered ({m.solver_status})", (tl, t))
            self._plan_status = m.status
        if m.status != PlanStatusName.SOLVED:
            level = _ERROR if m.status == PlanStatusName.BRAKING else _WARNING
            self.warn(f"solver_{m.status}",
                      f"solver {m.status}: {m.solver_status} "
                      f"({m.consecutive_failures} failures in a row)", (tl, t), level=level)
        if self._visual_due("world/plan", t, self.cfg.visual_max_hz):
            self._set_time(tl, t)
            xy = m.horizon[:, [HorizonCol.X, HorizonCol.Y]]
            v = np.append(m.inputs[:, InputCol.V_L], m.inputs[-1, InputCol.V_L])
            self.rec.log(
                "world/plan/horizon",
                rr.LineStrips2D.from_fields(strips=[xy]),
                rr.Points2D.from_fields(
                    positions=xy, colors=colors.ramp(v, 0.0, self.cfg.speed_color_max_mps)),
            )
            self.rec.log(
                "world/car_beta",
                rr.Points2D.from_fields(
                    positions=xy[:1],
                    colors=colors.ramp(nsc if nsc is not None else 1.0 - beta)),
            )
        if self._visual_due(layout.NOW_ENTITY, t, NOW_MAX_HZ):
            self._set_time(tl, t)
            self.rec.log(layout.NOW_ENTITY, rr.TextDocument(now_text(
                beta, nsc, m, self._lap, self._speed_now)))

    def _lap_event(self, m: LapEvent, tl: str, t: float, _recv: float) -> None:
        if m.kind == LapKindName.LAP:
            self.scalars.add("laps/lap_time_s", tl, t, float(m.lap_time_s or 0.0))
            self._scalar("laps/mean_speed_mps", tl, t, m.mean_speed_mps)
            speed = f", {m.mean_speed_mps:.3f} m/s" if m.mean_speed_mps is not None else ""
            econ = (f", max |e_con| {m.max_abs_e_con_m:.3f} m"
                    if m.max_abs_e_con_m is not None else "")
            text = (f"lap {m.lap}: {m.lap_time_s:.3f} s{speed}{econ}, "
                    f"{m.off_track_events} off-track")
            level = _INFO
        elif m.kind == LapKindName.START:
            text, level = f"timing started (lap {m.lap + 1})", _INFO
        elif m.kind == LapKindName.OFF_TRACK:
            text, level = f"OFF TRACK during lap {m.lap + 1}", _WARNING
        else:
            text, level = f"back on track (lap {m.lap + 1})", _INFO
        self._set_time(tl, t)
        self.rec.log(
            "events/lap",
            rr.TextLog(text, level=_LEVELS[level]),
            rr.AnyValues(
                kind=m.kind,
                lap=m.lap,
                lap_time_s=_nan(m.lap_time_s),
                mean_speed_mps=_nan(m.mean_speed_mps),
                off_track_events=m.off_track_events,
                max_abs_e_con_m=_nan(m.max_abs_e_con_m),
            ),
        )
        if m.kind in (LapKindName.START, LapKindName.LAP) and m.lap + 1 != self._lap:
            if self._path:
                self._log_path()
            self._lap = m.lap + 1
            self._path, self._path_stride, self._path_skip = [], 1, 0
            self._path_last_t = None

    def _vesc(self, m: VescState, tl: str, t: float, _recv: float) -> None:
        for name in _VESC_FIELDS:
            v = getattr(m, name)
            if v is not None:
                self.scalars.add(f"vesc/{name}", tl, t, float(v))
        if m.status != self._vesc_status:
            level = _INFO if m.status == VescStatusName.OK else _WARNING
            self.event("vesc", level, f"VESC status {m.status}"
                       + (f" (fault code {m.fault_code})" if m.fault_code else ""), (tl, t))
            self._vesc_status = m.status

    def _truth(self, m: SimTruth, tl: str, t: float, _recv: float) -> None:
        add = self.scalars.add
        add("truth/x_m", tl, t, m.x_m)
        add("truth/y_m", tl, t, m.y_m)
        add("truth/yaw_rad", tl, t, m.yaw_rad)
        add("speed/truth", tl, t, m.speed_mps)
        add("steering/truth", tl, t, m.steering_rad)
        add("truth/s_m", tl, t, m.s_m)
        add("track_error/e_con_truth", tl, t, m.e_con_m)
        add("truth/slip_rad", tl, t, m.slip_rad)
        add("truth/yaw_rate_radps", tl, t, m.yaw_rate_radps)
        add("truth/off_track", tl, t, 1.0 if m.off_track else 0.0)
        add("truth/lap", tl, t, m.lap)
        if m.off_track != self._off_track:
            self._off_track = m.off_track
            if m.off_track:
                self.event("telemetry", _WARNING,
                           f"off track at s = {m.s_m:.2f} m (e_con {m.e_con_m:+.2f} m)", (tl, t))
            else:
                self.event("telemetry", _INFO, "back on track", (tl, t))
        self._pose_xyyaw = (m.x_m, m.y_m, m.yaw_rad)
        if self._path_from_truth:
            self._speed_now = m.speed_mps
            self._path_add(m.x_m, m.y_m, m.speed_mps, tl, t)
        if self._visual_due("world/truth", t, self.cfg.visual_max_hz):
            self._set_time(tl, t)
            c = self.cfg
            self.rec.log(
                "world/truth",
                rr.LineStrips2D.from_fields(strips=[footprint(
                    m.x_m, m.y_m, m.yaw_rad, c.car_length_m, c.car_width_m)]),
            )

    def _opponents(self, m: Opponents, tl: str, t: float, _recv: float) -> None:
        """The tracked opponents: their number, and their footprints in the 2-D view."""
        self.scalars.add("opponents/count", tl, t, len(m.tracks))
        if self._visual_due("world/opponents", t, self.cfg.visual_max_hz):
            self._set_time(tl, t)
            self.rec.log(
                "world/opponents",
                rr.LineStrips2D(
                    [footprint(o.x_m, o.y_m, o.yaw_rad, o.length_m, o.width_m)
                     for o in m.tracks],
                    labels=[f"#{o.id}" for o in m.tracks],
                ),
            )

    def _log_event(self, m: LogEvent, tl: str, t: float, _recv: float) -> None:
        source = _UNSAFE.sub("_", m.source) or "unknown"
        self._set_time(tl, t)
        counts = parse_overwritten_drops(m.text) if m.level == _INFO else None
        if counts is None:
            self.rec.log(f"events/log/{source}", rr.TextLog(f"[{m.source}] {m.text}",
                                                            level=_LEVELS[m.level]))
            return
        # a by-design drop report: raw at debug level beside the event log, summarised in it
        self.rec.log(f"{layout.DROPS_ENTITY}/{source}",
                     rr.TextLog(f"[{m.source}] {m.text}", level=rr.TextLogLevel.DEBUG))
        summary = self._drops.add(m.source, t, counts)
        if summary is not None:
            self._log_summary(summary)

    def _log_summary(self, summary: Summary) -> None:
        """One summary of a source's overwritten-drop reports in the event log."""
        source = _UNSAFE.sub("_", summary.source) or "unknown"
        stamp = (timeline_of(summary.end_s, self.cfg.timeline), summary.end_s)
        self.event("log", _INFO, summary.text(), stamp, entity=f"events/log/{source}")

    def _sim_control(self, m: SimControl, tl: str, t: float, _recv: float) -> None:
        self.event("sim_control", _INFO, f"simulator {m.action} requested", (tl, t))

    def _teleport(self, m: Teleport, tl: str, t: float, _recv: float) -> None:
        self.event("teleport", _INFO, f"car put at ({m.x_m:.2f}, {m.y_m:.2f}) m, "
                   f"{m.yaw_rad:.2f} rad, {m.speed_mps:.2f} m/s", (tl, t))

    # ------------------------------------------------------------------ driven path
    def _path_add(self, x: float, y: float, v: float, tl: str, t: float) -> None:
        self._path_skip += 1
        if self._path_skip >= self._path_stride:
            self._path_skip = 0
            self._path.append((x, y, v))
            if len(self._path) > self.cfg.max_path_points:
                self._path = self._path[::2]
                self._path_stride *= 2
        if self._path_last_t is None or not 0.0 <= t - self._path_last_t < self.cfg.path_interval_s:
            self._path_last_t = t
            self._set_time(tl, t)
            self._log_path()

    def _log_path(self) -> None:
        p = np.asarray(self._path, dtype=np.float64)
        if p.size == 0:
            return
        entity = f"world/path/lap_{self._lap}"
        if entity not in self._path_entities:
            self._path_entities.add(entity)
            self.rec.log(entity, rr.Points2D.from_fields(radii=[0.025], draw_order=6.0),
                         static=True)
        self.rec.log(
            entity,
            rr.Points2D.from_fields(
                positions=p[:, :2],
                colors=colors.ramp(p[:, 2], 0.0, self.cfg.speed_color_max_mps)),
        )


def _series_style(style: layout.SeriesStyle) -> Any:
    """The static ``SeriesLines`` / ``SeriesPoints`` of a scalar entity."""
    if style.points:
        return rr.SeriesPoints(names=style.name or None, colors=[style.color], markers="circle",
                               marker_sizes=style.width)
    return rr.SeriesLines(names=style.name or None, colors=[style.color], widths=style.width)


def _nan(v: float | None) -> float:
    return float("nan") if v is None else float(v)
