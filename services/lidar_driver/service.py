"""The lidar driver service: a Hokuyo (SCIP 2.0) on USB serial or TCP -> ``vehicle/scan``.

``python -m services.lidar_driver --config FILE`` (or ``racestack run lidar_driver``),
settings ``[lidar_driver]``. Its own process, not a part of the localisation bridge: the
serial read loop is blocking I/O, and a USB hiccup or a hung sensor must not take the
localisation (or anything else) down with it; the bridge only sees scans stop.

Threads:

* the I/O worker (``LidarService.run_io``, ``Service.start_worker``): keeps the link open
  (``link.Link``: reopened every ``reconnect_period_s`` while the sensor is missing), sleeps
  in ``select`` on it, feeds the bytes to the session (``session.LidarSession``: handshake,
  stream, clock offset) and publishes each scan at once (the scan rate of the sensor), so a
  scan's latency is decode + publish. A silent sensor (no scan for ``silence_timeout_s``)
  or a handshake that gets no answer closes the link; it is reopened after the period.
* the main thread (the base's ``serve``): drop and fault reports, and ``tick``: decoder
  and scan errors (garbage, bad checksums, truncated scans) reported as they grow, at most
  once per ``event_interval_s``.

Events on ``events/log``: lidar port open / lost / back, silent sensor, handshake failures,
sensor error statuses, the stream's description (model, beams, angles, rate), the counts
of dropped input. On SIGINT/SIGTERM it sends ``QT`` (stream and laser off) and closes.
"""

from __future__ import annotations

import argparse
import math
import threading
import time
from collections.abc import Callable

from pydantic import ValidationError

from services.lidar_driver.link import Link
from services.lidar_driver.session import LidarSession, Note, Phase, Reconnect, ScanReady
from shared.bus import Bus
from shared.config import ConfigError, RacestackConfig
from shared.config.lidar import LidarDriverSettings
from shared.keys import EVENTS_LOG, SCAN
from shared.messages import LogEvent, LogLevelName, MessageError, Scan
from shared.ratelimit import GrowthLimiter
from shared.service import Service, publishes

#: Longest sleep of the I/O loop while waiting for bytes or a reconnect [s].
MAX_WAIT_S = 0.05


class LidarService(Service):
    """The driver's shell (module docstring)."""

    NAME = "lidar_driver"
    PORTS = (publishes(SCAN, Scan), publishes(EVENTS_LOG, LogEvent))

    def __init__(
        self,
        settings: LidarDriverSettings,
        bus: Bus,
        *,
        clock: Callable[[], float] = time.monotonic,
        wall_clock: Callable[[], float] = time.time,
        link: Link | None = None,
    ) -> None:
        """The driver on its open bus; the link opens in the I/O worker.

        Args:
            settings: the ``[lidar_driver]`` section.
            bus: the service's bus.
            clock, wall_clock: monotonic [s] (timeouts) and wall [s] (stamps) clocks.
            link: the byte link (default: ``Link(settings.port, ...)``).
        """
        super().__init__(
            bus,
            clock=clock,
            wall_clock=wall_clock,
            report_period_s=settings.event_interval_s,
            event_interval_s=settings.event_interval_s,
        )
        self.settings = settings
        self.link = link or Link(
            settings.port, settings.baudrate, reconnect_period_s=settings.reconnect_period_s
        )
        self.session = LidarSession(settings)
        self.pub_scan = self.publisher(SCAN)
        self.published = 0  #: scans published
        self.rejected = 0  #: scans the Scan record rejected (counted, dropped)
        self._ever_connected = False
        self._lost_reported = False
        self._input_report = GrowthLimiter(settings.event_interval_s)
        self._lock = threading.Lock()

    @classmethod
    def create(cls, cfg: RacestackConfig, args: argparse.Namespace, bus: Bus) -> LidarService:
        """The driver with ``[lidar_driver]`` (``--port`` overrides its port)."""
        settings = cfg.lidar_driver
        if args.port:
            try:
                settings = LidarDriverSettings.model_validate(
                    {**settings.model_dump(), "port": args.port}
                )
            except ValidationError as exc:
                msg = "; ".join(e["msg"] for e in exc.errors())
                raise ConfigError(f"--port {args.port!r}: {msg}") from None
        return cls(settings, bus)

    @staticmethod
    def add_args(ap: argparse.ArgumentParser) -> None:
        """``--port``."""
        ap.add_argument("--port", help="serial device or tcp://host:port ([lidar_driver] port)")

    # -- the I/O worker ------------------------------------------------------------------------
    def serve(self, stop: threading.Event) -> int:
        """Start the I/O worker, then the base's watchdog loop until ``stop``."""
        s = self.settings
        self.log.info("lidar driver on %s; scans on %s", s.port, self.keys.key(SCAN))
        self.start_worker("lidar-io", lambda: self.run_io(stop), stop)
        return super().serve(stop)

    def run_io(self, stop: threading.Event) -> None:
        """The I/O loop until ``stop`` is set; then ``QT`` and close the link."""
        try:
            while not stop.is_set():
                self.io_step()
        finally:
            if self.link.connected:
                self.link.write(self.session.stop_request())
            self.link.close()

    def io_step(self) -> None:
        """One round: (re)connect, wait for bytes or a deadline, feed, publish, timeouts."""
        link, session = self.link, self.session
        now = self.clock()
        if not link.connected:
            if session.phase is not Phase.IDLE:
                session.lost()
                self._on_lost()
            if not link.maintain(now):
                time.sleep(MAX_WAIT_S)
                return
            self._on_connected()
            link.write(session.start(now, self.wall_clock()))
        deadline = session.next_deadline()
        wait = MAX_WAIT_S if deadline is None else min(MAX_WAIT_S, max(0.0, deadline - now))
        if link.wait_readable(wait):
            data = link.read()
            if data:
                send, outputs = session.feed(data, self.clock(), self.wall_clock())
                if send:
                    link.write(send)
                self._handle(outputs)
        send, outputs = session.tick(self.clock(), self.wall_clock())
        if send:
            link.write(send)
        self._handle(outputs)

    def _handle(self, outputs: list[ScanReady | Note | Reconnect]) -> None:
        for item in outputs:
            if isinstance(item, ScanReady):
                self._publish(item)
            elif isinstance(item, Note):
                self.say(item.level, item.text, limit=item.kind)
            else:
                self.say(
                    LogLevelName.WARNING,
                    f"lidar {self.settings.port}: {item.reason}; reconnecting",
                    limit="reconnect",
                )
                self.link.drop(item.reason, self.clock())
                self._lost_reported = True

    def _publish(self, item: ScanReady) -> None:
        g = item.geometry
        try:
            msg = Scan(
                stamp_s=item.stamp_s,
                angle_min_rad=g.angle_min_rad,
                angle_increment_rad=g.angle_increment_rad,
                ranges_m=item.ranges_m,
            )
        except MessageError as exc:
            self.rejected += 1
            self.bus.faults.record("lidar_driver/scan", exc.reason, exc.detail)
            return
        self.pub_scan.put(msg)
        self.published += 1

    def _on_connected(self) -> None:
        port = self.settings.port
        if not self._ever_connected:
            self._ever_connected = True
            self.say(LogLevelName.INFO, f"lidar port {port} open: handshake")
        elif self._lost_reported:
            self.say(LogLevelName.INFO, f"lidar port {port} back: handshake")
        self._lost_reported = False

    def _on_lost(self) -> None:
        err = self.link.last_error or "lost"
        if not self._lost_reported:
            self.say(LogLevelName.ERROR, f"lost the lidar port ({err}); retrying", limit="lost")
            self._lost_reported = True

    # -- the main thread -----------------------------------------------------------------------
    def tick(self) -> None:
        """Report dropped input (garbage, checksums, truncated scans) as it grows."""
        link = self.link
        if not self._ever_connected and not link.connected and link.counters.open_failures:
            self.say(
                LogLevelName.WARNING,
                f"waiting for the lidar port {self.settings.port} ({link.last_error}); retrying",
                limit="waiting",
            )
        d = self.session.decoder.counters
        c = self.session.counters
        total = d.errors + c.bad_scans + d.garbage_bytes  # noise grows the bytes at least
        if self._input_report.check(total, self.clock()):
            self.say(
                LogLevelName.WARNING,
                f"lidar input dropped so far: {d.checksum_errors} bad checksums, "
                f"{d.truncated + c.bad_scans} truncated scans, {d.no_echo} noise pieces, "
                f"{d.overlong} overlong, {d.garbage_bytes} bytes",
            )

    def diagnostics(self) -> dict[str, float]:
        """Counters of the link, the decoder, the session and the service."""
        out: dict[str, float] = {}
        out.update({f"link.{k}": v for k, v in self.link.counters.as_dict().items()})
        out.update({f"decoder.{k}": v for k, v in self.session.decoder.counters.as_dict().items()})
        out.update({f"session.{k}": v for k, v in self.session.counters.as_dict().items()})
        out["service.published"] = self.published
        out["service.rejected"] = self.rejected
        off = self.session.clock.offset_s()
        out["clock.offset_s"] = math.nan if off is None else off
        return out

    def close(self) -> None:
        """Close the link (after the bus)."""
        self.link.close()


main = LidarService.main
