"""The SCIP 2.0 session with one sensor, as a pure state machine (no I/O, no clock reads).

The service's I/O loop feeds it received bytes and the times (``now`` monotonic [s] for
timeouts, ``wall`` [s] for stamps) and writes what it returns. On every (re)connect
(``start``) it runs the handshake, one request at a time, each answered before the next::

    QT         stop a stream left running by an earlier session (any status)
    SCIP2.0    switch a SCIP 1.1 sensor (any status; a SCIP 2.0 sensor says 0E)
    VV         vendor / product / firmware / serial (logged)
    PP         the parameters: AMIN, AMAX, AFRT, ARES, DMIN, DMAX, SCAN -> beam geometry
    TM0, TM1 x tm_samples, TM2       with stamp_source = "tm": the clock offset
    MD / ME    the stream: start..end step, cluster, skip, 0 scans (= until QT)

A step not answered within ``reply_timeout_s`` is sent again, up to ``handshake_attempts``
times; then the session asks for a reconnect. While streaming, every ``MD``/``ME`` response
with status 99 becomes a ``ScanReady``; a scan that does not parse (truncated, wrong length)
is counted and dropped; no scan for ``silence_timeout_s`` asks for a reconnect.
"""

from __future__ import annotations

from dataclasses import dataclass, fields
from enum import StrEnum

import numpy as np

from shared.config.lidar import LidarDriverSettings
from shared.hokuyo.decoder import Response, ResponseDecoder
from shared.hokuyo.protocol import (
    STATUS_OK,
    STATUS_SCAN,
    Code,
    ScanRequest,
    TimeMode,
    describe_status,
    laser_off,
    parameters,
    scan_stream,
    scip2,
    time_mode,
    version,
)
from shared.hokuyo.scan import (
    BeamGeometry,
    RawScan,
    ScanError,
    SensorParams,
    parse_info,
    parse_params,
    parse_scan,
    parse_time,
    ranges_m,
)
from shared.hokuyo.timesync import SensorClock

__all__ = [
    "LidarSession",
    "Note",
    "Phase",
    "Reconnect",
    "ScanReady",
    "SessionCounters",
    "stream_rate_hz",
]


class Phase(StrEnum):
    """Where the session is."""

    IDLE = "idle"  # no link
    HANDSHAKE = "handshake"
    STREAMING = "streaming"


@dataclass(frozen=True, slots=True)
class ScanReady:
    """A decoded scan, ready to publish.

    Attributes:
        raw: the scan as the sensor sent it (steps, 24-bit stamp, ranges [mm]).
        geometry: its beam angles in the car frame.
        ranges_m: (beams,) float32 ranges [m], +inf for no return / out of the window.
        intensities: (beams,) float32 intensities (ME) or None.
        stamp_s: its host time [s] (``[lidar_driver] stamp_source``).
    """

    raw: RawScan
    geometry: BeamGeometry
    ranges_m: np.ndarray
    intensities: np.ndarray | None
    stamp_s: float


@dataclass(frozen=True, slots=True)
class Note:
    """Something worth a line on ``events/log``; ``kind`` names it for rate limiting."""

    level: str
    kind: str
    text: str


@dataclass(frozen=True, slots=True)
class Reconnect:
    """The session gave up on the link (no answer, silent sensor): close and reopen it."""

    reason: str


Output = ScanReady | Note | Reconnect


@dataclass(slots=True)
class SessionCounters:
    """What the session did.

    Attributes:
        handshakes: handshakes started; streams: streams started (MD/ME acknowledged).
        scans: scans decoded; bad_scans: scan responses that did not parse (truncated).
        retries: handshake requests sent again; sensor_errors: error statuses received.
        ignored: responses that belong to no pending request (e.g. a stale stream).
        silences: reconnects asked for because no scan came.
    """

    handshakes: int = 0
    streams: int = 0
    scans: int = 0
    bad_scans: int = 0
    retries: int = 0
    sensor_errors: int = 0
    ignored: int = 0
    silences: int = 0

    def as_dict(self) -> dict[str, int]:
        """The counters as a plain dict."""
        return {f.name: getattr(self, f.name) for f in fields(self)}


@dataclass(frozen=True, slots=True)
class _Step:
    request: bytes
    echo: bytes  # the echo that answers it (without tag)
    accept: frozenset[str] | None  # statuses that complete it (None: any)


_ANY = None
_OK = frozenset({STATUS_OK})



def stream_rate_hz(scan_rpm: float, skip: int) -> float:
    """Scans per second an ``MD``/``ME`` stream delivers: the motor turns ``scan_rpm / 60``
    times a second (``PP`` SCAN; 2400 rpm = 40 Hz on the UTM-30LX), one scan a turn, and
    the skip count of the request (SCIP 2.0: the scans left out between two sent ones, 0 =
    every scan, 1 = every other one) divides that by ``1 + skip``."""
    return scan_rpm / 60.0 / (1 + skip)

class LidarSession:
    """The handshake and the stream of one sensor (module docstring)."""

    def __init__(self, settings: LidarDriverSettings) -> None:
        self.settings = settings
        self.decoder = ResponseDecoder()
        self.clock = SensorClock(
            settings.time_sync_window_s, prefer_round_trip=settings.stamp_source == "tm"
        )
        self.counters = SessionCounters()
        self.phase = Phase.IDLE
        self.params: SensorParams | None = None
        self.identity: dict[str, str] = {}
        self.request: ScanRequest | None = None
        self._steps: list[_Step] = []
        self._sent_at = 0.0
        self._sent_wall = 0.0
        self._attempts = 0
        self._last_scan_at = 0.0
        self._geometry: dict[tuple[int, int, int], BeamGeometry] = {}

    # -- the handshake ---------------------------------------------------------------------
    def _plan(self) -> list[_Step]:
        steps = [
            _Step(laser_off(), b"QT", _ANY),
            _Step(scip2(), b"SCIP2.0", _ANY),
            _Step(version(), b"VV", _OK),
            _Step(parameters(), b"PP", _OK),
        ]
        if self.settings.stamp_source == "tm":
            steps.append(_Step(time_mode(TimeMode.ENTER), b"TM0", frozenset({"00", "02"})))
            steps += [
                _Step(time_mode(TimeMode.READ), b"TM1", _OK)
                for _ in range(self.settings.tm_samples)
            ]
            steps.append(_Step(time_mode(TimeMode.LEAVE), b"TM2", frozenset({"00", "03"})))
        return steps  # the MD/ME step is added once PP has answered

    def start(self, now: float, wall: float) -> bytes:
        """A new link: forget the stream and the clock, send the first handshake request."""
        self.decoder.reset()
        self.clock.reset()
        self.phase = Phase.HANDSHAKE
        self.counters.handshakes += 1
        self._steps = self._plan()
        self._attempts = 0
        return self._send(now, wall)

    def lost(self) -> None:
        """The link is gone."""
        self.phase = Phase.IDLE
        self._steps = []

    def _send(self, now: float, wall: float) -> bytes:
        self._sent_at, self._sent_wall = now, wall
        self._attempts += 1
        return self._steps[0].request

    def stop_request(self) -> bytes:
        """What to send before closing: ``QT`` (stream off, laser off)."""
        return laser_off()

    # -- input -----------------------------------------------------------------------------
    def feed(self, data: bytes, now: float, wall: float) -> tuple[bytes, list[Output]]:
        """Received bytes -> (bytes to send, outputs)."""
        send = bytearray()
        out: list[Output] = []
        for resp in self.decoder.feed(data):
            if self.phase is Phase.STREAMING and resp.code in (Code.MD, Code.ME):
                self._on_stream(resp, now, wall, out)
            elif (
                self.phase is Phase.HANDSHAKE
                and self._steps
                and resp.echo == self._steps[0].echo
                and resp.status != STATUS_SCAN  # a scan of a stream not stopped yet
            ):
                send += self._on_step(resp, now, wall, out)
            else:
                self.counters.ignored += 1
        return bytes(send), out

    def _on_step(self, resp: Response, now: float, wall: float, out: list[Output]) -> bytes:
        step = self._steps[0]
        if step.accept is not None and resp.status not in step.accept:
            self.counters.sensor_errors += 1
            out.append(
                Note(
                    "warning",
                    "sensor_error",
                    f"lidar answered {resp.code} with status {resp.status} "
                    f"({describe_status(resp.code, resp.status)})",
                )
            )
            return b""  # the timeout sends it again
        if resp.code is Code.VV:
            self.identity = parse_info(resp)
        elif resp.code is Code.PP:
            try:
                self.params = parse_params(resp)
            except ScanError as exc:
                out.append(Note("error", "bad_params", f"lidar PP answer unusable: {exc}"))
                return b""
            self._steps.append(self._stream_step(self.params, out))
        elif resp.code is Code.TM and resp.echo == b"TM1":
            try:
                raw = parse_time(resp)
            except ScanError:
                return b""
            self.clock.add_round_trip(self._sent_wall, wall, raw)
        elif resp.code in (Code.MD, Code.ME):
            self.phase = Phase.STREAMING
            self.counters.streams += 1
            self._last_scan_at = now
            self._steps = []
            out.append(Note("info", "streaming", self._describe_stream()))
            return b""
        self._steps.pop(0)
        self._attempts = 0
        return self._send(now, wall) if self._steps else b""

    def _stream_step(self, p: SensorParams, out: list[Output]) -> _Step:
        s = self.settings
        first = p.amin if s.first_step is None else s.first_step
        last = p.amax if s.last_step is None else s.last_step
        if not p.amin <= first <= last <= p.amax:
            out.append(
                Note(
                    "warning",
                    "steps",
                    f"lidar steps {first}..{last} outside the sensor's {p.amin}..{p.amax}: "
                    "clamped",
                )
            )
            first = min(max(first, p.amin), p.amax)
            last = min(max(last, first), p.amax)
        code = Code.ME if s.intensity else Code.MD
        self.request = ScanRequest(code, first, last, s.cluster, s.skip, 0)
        self._geometry.clear()
        return _Step(scan_stream(self.request), self.request.body().encode("ascii"), _OK)

    def _describe_stream(self) -> str:
        p, r = self.params, self.request
        assert p is not None and r is not None
        g = self._geometry_of(r)
        who = self.identity.get("PROD") or p.model
        return (
            f"lidar {who} ({self.identity.get('SERI', '?')}, firmware "
            f"{self.identity.get('FIRM', '?')}): {g.beams} beams from "
            f"{g.angle_min_rad:+.3f} rad by {g.angle_increment_rad:+.5f} rad at "
            f"{stream_rate_hz(p.scan_rpm, r.skip):.1f} Hz, stamps from "
            f"{self.settings.stamp_source}"
        )

    def _geometry_of(self, req: ScanRequest) -> BeamGeometry:
        key = (req.start_step, req.end_step, req.cluster)
        g = self._geometry.get(key)
        if g is None:
            assert self.params is not None
            g = self._geometry[key] = BeamGeometry.of(
                self.params,
                req,
                mount_yaw_rad=self.settings.mount_yaw_rad,
                upside_down=self.settings.upside_down,
            )
        return g

    def _on_stream(self, resp: Response, now: float, wall: float, out: list[Output]) -> None:
        if resp.status != STATUS_SCAN:
            if resp.status != STATUS_OK:
                self.counters.sensor_errors += 1
                out.append(
                    Note(
                        "error" if resp.status != "98" else "info",
                        "sensor_error",
                        f"lidar stream status {resp.status} "
                        f"({describe_status(resp.code, resp.status)})",
                    )
                )
            return
        try:
            raw = parse_scan(resp)
        except ScanError:
            self.counters.bad_scans += 1
            return
        self._last_scan_at = now
        s = self.settings
        sensor_s = self.clock.unwrap_s(raw.sensor_ms)
        if s.stamp_source == "host":
            stamp = wall
        else:
            self.clock.add_receipt(wall, sensor_s)
            stamp = max(0.0, self.clock.stamp(sensor_s, not_after_s=wall))
        inten = None if raw.intensities is None else raw.intensities.astype(np.float32)
        self.counters.scans += 1
        out.append(
            ScanReady(
                raw,
                self._geometry_of(raw.request),
                ranges_m(raw.ranges_mm, s.range_min_m, s.range_max_m),
                inten,
                stamp,
            )
        )

    # -- time --------------------------------------------------------------------------------
    def next_deadline(self) -> float | None:
        """The monotonic time [s] at which ``tick`` has something to do (None: nothing)."""
        if self.phase is Phase.HANDSHAKE and self._steps:
            return self._sent_at + self.settings.reply_timeout_s
        if self.phase is Phase.STREAMING:
            return self._last_scan_at + self.settings.silence_timeout_s
        return None

    def tick(self, now: float, wall: float) -> tuple[bytes, list[Output]]:
        """Timeouts: resend a handshake request, or ask for a reconnect."""
        s = self.settings
        if self.phase is Phase.HANDSHAKE and self._steps:
            if now - self._sent_at < s.reply_timeout_s:
                return b"", []
            step = self._steps[0]
            name = step.echo.decode("ascii", "replace")
            if self._attempts >= s.handshake_attempts:
                self.lost()
                return b"", [
                    Reconnect(f"no answer to {name} after {self._attempts} tries")
                ]
            self.counters.retries += 1
            return self._send(now, wall), []
        if self.phase is Phase.STREAMING and now - self._last_scan_at >= s.silence_timeout_s:
            self.counters.silences += 1
            self.lost()
            return b"", [Reconnect(f"no scan for {s.silence_timeout_s:g} s")]
        return b"", []

