"""The VESC driver service: ``cmd/drive`` in, VESC serial frames out, over Zenoh.

``python -m services.vesc_driver --config FILE`` (or ``racestack run vesc_driver``). The
serial port is ``[vesc] port``; with no port present the service keeps running and retries
(``SerialLink`` back-off), it never exits for a missing or vanished device.

Threads:

* Zenoh's callback thread: each valid ``DriveCmd`` goes to ``VescDriver.on_command`` (a
  lock held for microseconds; with ``[vesc] write_on_command`` it also wakes the serial
  loop through its pipe). It never blocks.
* the driver thread (``VescService.run_driver``): the driver's own serial loop
  (``VescDriver.loop``, scheduled by ``services.vesc_driver.schedule.TickScheduler``). It
  ticks the driver at ``command_rate_hz`` (motor frames, ALIVE, GET_VALUES), runs an extra
  tick when the command watchdog expires (so the brake follows the last command by
  ``command_timeout_s`` plus scheduling delay), and - with ``write_on_command`` - an extra
  tick right after a new command (at most one such extra write per
  ``MIN_COMMAND_WRITE_GAP_S``), so a command reaches the wire without waiting up to one
  period. Between ticks it sleeps in ``select`` on the serial port and the wake pipe,
  decoding GET_VALUES replies as they arrive (their stamps are the decode time). The
  service's ``on_tick`` does no bus I/O: tick results and events go to a bounded out-box.
* the main thread (``VescService.serve``): publishes the out-box - ``vesc/state`` and
  ``vehicle/odom`` for every reply (at the tick after its decode, at most one period later,
  stamped with the decode time in wall-clock seconds), ``vehicle/imu`` for every
  GET_IMU_DATA reply with ``[vesc] poll_imu_rate_hz`` > 0 (car frame, the mounting rotation
  applied; a reply outside the message's limits is left out and counted), a warning when no
  IMU reply came for ``[vesc] stale_imu_s`` while the port is open, ``events/log`` for port
  lost / back,
  watchdog braking / commands resumed, invalid commands, invalid bus payloads (the bus's
  ``DropCounter`` grew: ``shared.bus.DropReporter``) and reply values the messages reject.
  Every kind of event is rate-limited to one per ``[vesc] event_interval_s`` (suppressed ones
  are counted into the next; ``shared.ratelimit.RateLimiter``). While no reply arrives it
  publishes a status-only ``vesc/state`` (all values None) every ``STATUS_ONLY_INTERVAL_S``.
  A record of its own that still fails validation is not sent but counted in
  ``bus.faults`` and reported the same way (``DropReporter``); the loop goes on. The bus
  session, the event log and the reports are the ``shared.service.Service`` base's.

On SIGINT/SIGTERM the driver thread writes one brake frame, closes the port, and the main
thread then closes the Zenoh session.
"""

from __future__ import annotations

import argparse
import collections
import math
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from services.vesc_driver.driver import (
    ImuRecord,
    OdometryRecord,
    TickResult,
    VescDriver,
    VescStateRecord,
)
from services.vesc_driver.serial_link import LinkState, SerialLink
from services.vesc_driver.watchdog import WatchdogState
from shared.bus import Bus, DropOldestQueue
from shared.config import RacestackConfig
from shared.config.vesc import VescSettings
from shared.keys import DRIVE_CMD, EVENTS_LOG, IMU, ODOM, VESC_STATE
from shared.messages import (
    DriveCmd,
    Imu,
    LogEvent,
    LogLevelName,
    MessageError,
    Odom,
    VescState,
    VescStatusName,
)
from shared.messages.codec import FieldInfo
from shared.ratelimit import EpisodeLimiter, GrowthLimiter
from shared.service import Service, publishes, subscribes
from shared.vesc.protocol import encode_set_current_brake
from shared.vesc.values import VescValues

#: Longest a serial write may block [s].
WRITE_TIMEOUT_S = 0.05
#: Period of a status-only ``vesc/state`` while no GET_VALUES reply arrives [s].
STATUS_ONLY_INTERVAL_S = 0.5
#: Period of the main thread's counter checks (drops, invalid commands) [s].
CHECK_PERIOD_S = 0.1
#: Period of the local "still waiting for ..." log lines [s].
WAITING_LOG_INTERVAL_S = 10.0
#: Size of the out-box between the driver thread and the publisher (oldest dropped).
OUTBOX_SIZE = 512
#: Wait for the driver thread to end after stop [s].
JOIN_TIMEOUT_S = 3.0

#: VescState fields filled from ``VescValues`` (same names), with their field rules
#: (each value is checked with ``VescState.check_field``).
_STATE_FIELDS: tuple[tuple[str, FieldInfo], ...] = tuple(
    (f.name, f) for f in VescState.fields_info() if f.name not in ("stamp_s", "seq", "status")
)


# --------------------------------------------------------------------------- conversions
def vesc_state_message(
    values: VescValues | None, status: str, stamp_s: float
) -> tuple[VescState, tuple[str, ...]]:
    """The ``vesc/state`` record of one GET_VALUES reply (or a status-only one).

    Args:
        values: the parsed reply (None: every value None, only the status).
        status: the link status, "ok" | "fault" | "stale" | "disconnected".
        stamp_s: wall-clock stamp [s] of the reply.

    Returns:
        the record, and the names of the fields left None because the message rejects
        their value (e.g. negative amp hours, a temperature beyond its range).
    """
    kwargs: dict[str, Any] = {}
    skipped: list[str] = []
    for name, _ in _STATE_FIELDS:
        value = getattr(values, name, None) if values is not None else None
        if value is not None:
            try:
                value = VescState.check_field(name, value)
            except MessageError:
                skipped.append(name)
                value = None
        kwargs[name] = value
    return VescState(stamp_s=stamp_s, status=status, **kwargs), tuple(skipped)


def odom_message(rec: OdometryRecord, stamp_s: float) -> tuple[Odom | None, tuple[str, ...]]:
    """The ``vehicle/odom`` record of one reply's odometry.

    Speed [m/s] or steering [rad] outside the message's limits -> no record; a yaw rate
    [rad/s] outside them -> ``yaw_rate_radps`` None. Returns the record (or None) and the
    names of the rejected fields.
    """
    bad: list[str] = []
    for name, value in (("speed_mps", rec.speed_mps), ("steering_rad", rec.steering_rad)):
        try:
            Odom.check_field(name, value)
        except MessageError:
            bad.append(name)
    if bad:
        return None, tuple(bad)
    yaw_rate: float | None = rec.yaw_rate_radps
    try:
        yaw_rate = Odom.check_field("yaw_rate_radps", yaw_rate)
    except MessageError:
        bad.append("yaw_rate_radps")
        yaw_rate = None
    odom = Odom(
        stamp_s=stamp_s,
        speed_mps=rec.speed_mps,
        steering_rad=rec.steering_rad,
        yaw_rate_radps=yaw_rate,
    )
    return odom, tuple(bad)


def imu_message(rec: ImuRecord, stamp_s: float) -> tuple[Imu | None, tuple[str, ...]]:
    """The ``vehicle/imu`` record of one IMU reply (car frame).

    Any value outside the message's limits -> no record (a reading with one impossible axis
    is not trusted for the others). Returns the record (or None) and the rejected fields.
    """
    values = {
        "yaw_rate_radps": rec.yaw_rate_radps,
        "ax_mps2": rec.ax_mps2,
        "ay_mps2": rec.ay_mps2,
    }
    bad: list[str] = []
    for name, value in values.items():
        try:
            Imu.check_field(name, value)
        except MessageError:
            bad.append(name)
    if bad:
        return None, tuple(bad)
    return Imu(stamp_s=stamp_s, **values), ()


# --------------------------------------------------------------------------- out-box items
@dataclass(frozen=True, slots=True)
class _Say:
    level: str
    text: str


@dataclass(frozen=True, slots=True)
class _Reply:
    status: str
    state: VescStateRecord | None
    odometry: OdometryRecord | None
    imu: ImuRecord | None = None


_Item = _Say | _Reply


# --------------------------------------------------------------------------- the service
class VescService(Service):
    """The driver, its serial loop thread and the bus side (see the module docstring)."""

    NAME = "vesc_driver"
    PORTS = (
        subscribes(DRIVE_CMD, DriveCmd),
        publishes(VESC_STATE, VescState),
        publishes(ODOM, Odom),
        publishes(IMU, Imu),
        publishes(EVENTS_LOG, LogEvent),
    )

    def __init__(
        self,
        settings: VescSettings,
        bus: Bus,
        *,
        clock: Callable[[], float] = time.monotonic,
        wall_clock: Callable[[], float] = time.time,
    ) -> None:
        """Create the driver (port opened lazily by the loop) and subscribe ``cmd/drive``.

        Args:
            settings: the ``[vesc]`` section.
            bus: the service's open bus.
            clock: monotonic clock [s] of the driver.
            wall_clock: wall clock [s] for message stamps.
        """
        super().__init__(
            bus,
            clock=clock,
            wall_clock=wall_clock,
            report_period_s=settings.event_interval_s,
            event_interval_s=settings.event_interval_s,
        )
        self.settings = settings
        link = SerialLink(
            settings.port,
            settings.baudrate,
            backoff_initial_s=settings.reconnect_backoff_initial_s,
            backoff_max_s=settings.reconnect_backoff_max_s,
            write_timeout_s=WRITE_TIMEOUT_S,
            clock=clock,
        )
        self.driver = VescDriver(settings, link, clock=clock)
        self.outbox: DropOldestQueue[_Item] = DropOldestQueue(OUTBOX_SIZE)
        self.commands_received = 0
        self.driver_error: BaseException | None = None
        #: Reply fields / odometry the messages rejected: field name -> count.
        self.rejected_fields: collections.Counter[str] = collections.Counter()
        self.status: str = VescStatusName.DISCONNECTED  #: link status of the newest tick
        # driver-thread state (transitions)
        self._prev_link: LinkState | None = None
        self._ever_connected = False
        self._prev_wd: WatchdogState | None = None
        self._link_events = EpisodeLimiter(settings.event_interval_s)
        self._brake_events = EpisodeLimiter(settings.event_interval_s)
        # main-thread state
        self._invalid_report = GrowthLimiter(settings.event_interval_s)
        self._rejected_report = GrowthLimiter(settings.event_interval_s)
        self._last_state_pub_s = -math.inf
        self.pub_state = self.publisher(VESC_STATE)
        self.pub_odom = self.publisher(ODOM)
        self.pub_imu = self.publisher(IMU)
        self.imu_published = 0
        self._imu_stale = GrowthLimiter(settings.event_interval_s)
        self._imu_stale_count = 0
        self._imu_was_stale = False
        self._imu_ref_s: float | None = None  # when the open port began to owe IMU replies
        self._imu_ref_epoch = -1
        self.sub = self.subscribe(DRIVE_CMD, self.on_drive_cmd)

    @classmethod
    def create(cls, cfg: RacestackConfig, args: argparse.Namespace, bus: Bus) -> VescService:
        """The driver with ``[vesc]`` (``--port`` overrides its port)."""
        settings = cfg.vesc
        if args.port:
            settings = VescSettings.model_validate({**settings.model_dump(), "port": args.port})
        return cls(settings, bus)

    @staticmethod
    def add_args(ap: argparse.ArgumentParser) -> None:
        """``--port``."""
        ap.add_argument("--port", help="serial device (overrides [vesc] port)")

    # -- Zenoh thread --------------------------------------------------------------------
    def on_drive_cmd(self, cmd: DriveCmd) -> None:
        """Hand a valid drive command to the driver (which wakes its loop); never blocks."""
        self.driver.on_command(cmd.speed_mps, cmd.steering_rad, self.clock())
        self.commands_received += 1

    # -- driver thread -------------------------------------------------------------------
    def run_driver(self, stop: threading.Event) -> None:
        """The driver's serial loop (see the module docstring) until ``stop`` is set; then
        brake once and close the port. Exceptions are kept in ``driver_error``."""
        try:
            self.driver.loop(stop, self._after_tick)
        except BaseException as exc:  # reported by the main thread
            self.driver_error = exc
        finally:
            self._brake_and_close()

    def _after_tick(self, result: TickResult) -> None:
        """Transitions of the link and the watchdog -> events; replies -> the out-box."""
        self.status = result.status
        now = result.stamp_s
        s = self.settings
        link = result.link
        if link is not self._prev_link:
            port = s.port
            if link is LinkState.CONNECTED:
                reported = self._link_events.end()
                if not self._ever_connected:
                    self._ever_connected = True
                    self._say(LogLevelName.INFO, f"VESC port {port} open")
                elif reported:
                    self._say(LogLevelName.INFO, f"VESC port {port} back: resuming")
            elif link is LinkState.DISCONNECTED:
                err = self.driver.link.last_error or "not present"
                if self._prev_link is None:
                    self._say(
                        LogLevelName.WARNING, f"waiting for the VESC port {port} ({err}); retrying"
                    )
                    self._link_events.start(now)
                else:
                    n = self._link_events.start(now)
                    if n is not None:
                        more = f" ({n} more losses since the last report)" if n else ""
                        self._say(
                            LogLevelName.ERROR, f"lost the VESC port {port} ({err}); retrying{more}"
                        )
            self._prev_link = link
        wd = result.watchdog
        if wd is not self._prev_wd:
            if wd is WatchdogState.FRESH:
                if self._prev_wd in (None, WatchdogState.NO_COMMAND):
                    self._say(LogLevelName.INFO, "first drive command received: driving")
                elif self._brake_events.end():
                    self._say(LogLevelName.INFO, "drive commands resumed: driving")
            elif wd is WatchdogState.EXPIRED:
                n = self._brake_events.start(now)
                if n is not None:
                    more = f" ({n} more since the last report)" if n else ""
                    self._say(
                        LogLevelName.WARNING,
                        f"no drive command for {s.command_timeout_s * 1e3:.0f} ms: braking "
                        f"({s.brake_current_a:g} A){more}",
                    )
            elif wd is WatchdogState.NO_COMMAND and self._prev_wd is None:
                key = self.bus.keys.drive_cmd
                self._say(LogLevelName.INFO, f"waiting for the first drive command on {key}")
            self._prev_wd = wd
        if result.state is not None or result.odometry is not None or result.imu is not None:
            self.outbox.put(_Reply(result.status, result.state, result.odometry, result.imu))

    def _say(self, level: str, text: str) -> None:
        self.outbox.put(_Say(level, text))

    def _brake_and_close(self) -> None:
        link = self.driver.link
        try:
            if link.connected:
                ok = link.write(encode_set_current_brake(self.settings.brake_current_a))
                said = "stopping: brake sent" if ok else "stopping"
                self.outbox.put(_Say(LogLevelName.INFO, said))
        finally:
            self.driver.close()

    # -- main thread ---------------------------------------------------------------------
    def serve(self, stop: threading.Event) -> int:
        """Run the driver thread and publish until ``stop`` is set; 0, or 1 if the loop died."""
        s = self.settings
        self.log.info(
            "VESC driver on %s at %g Hz (write on command: %s); commands from %s",
            s.port,
            s.command_rate_hz,
            "yes" if s.write_on_command else "no",
            self.sub.key,
        )
        thread = threading.Thread(target=self.run_driver, args=(stop,), name="vesc-serial")
        thread.start()
        code = 0
        next_check = 0.0
        next_waiting_log = self.clock() + WAITING_LOG_INTERVAL_S
        try:
            while not stop.is_set():
                item = self.outbox.get(timeout_s=CHECK_PERIOD_S)
                while item is not None:
                    self._publish(item)
                    item = self.outbox.get()
                now = self.clock()
                if now >= next_check:
                    next_check = now + CHECK_PERIOD_S
                    self._check_counters(now)
                if now >= next_waiting_log:
                    next_waiting_log = now + WAITING_LOG_INTERVAL_S
                    self._log_waiting()
                if not thread.is_alive() and not stop.is_set():
                    self.say(LogLevelName.ERROR, f"serial loop failed: {self.driver_error!r}")
                    code = 1
                    break
        finally:
            stop.set()
            self.driver.wake()
            thread.join(JOIN_TIMEOUT_S)
            if thread.is_alive():
                self.log.error("the serial loop did not stop within %.1f s", JOIN_TIMEOUT_S)
                code = 1
            for item in self.outbox.drain():
                self._publish(item)
            self.log.info("counters: %s", self.diagnostics())
        return code

    def _stamp(self, mono_s: float) -> float:
        """Wall-clock stamp [s] of a driver-clock time ``mono_s``."""
        return max(0.0, self.wall_clock() - (self.clock() - mono_s))

    def _publish(self, item: _Item) -> None:
        """Publish one out-box item; a record that fails validation anyway (the values are
        checked field by field first) is counted in ``bus.faults``, never raised."""
        if isinstance(item, _Say):
            self.say(item.level, item.text)
            return
        faults = self.bus.faults
        if item.state is not None:
            with faults.guard(self.pub_state.key):
                stamp = self._stamp(item.state.stamp_s)
                msg, skipped = vesc_state_message(item.state.values, item.status, stamp)
                self.rejected_fields.update(skipped)
                self.pub_state.put(msg)
                self._last_state_pub_s = self.clock()
        if item.odometry is not None:
            with faults.guard(self.pub_odom.key):
                odom, bad = odom_message(item.odometry, self._stamp(item.odometry.stamp_s))
                self.rejected_fields.update(f"odom.{b}" for b in bad)
                if odom is not None:
                    self.pub_odom.put(odom)
        if item.imu is not None:
            with faults.guard(self.pub_imu.key):
                imu, bad = imu_message(item.imu, self._stamp(item.imu.stamp_s))
                self.rejected_fields.update(f"imu.{b}" for b in bad)
                if imu is not None:
                    self.pub_imu.put(imu)
                    self.imu_published += 1

    def _check_counters(self, now: float) -> None:
        """Rate-limited events for grown drop / invalid-command / rejected-field counts."""
        self.report()
        c = self.driver.counters
        invalid = c.out_of_range_commands + c.nonfinite_commands
        if self._invalid_report.check(invalid, now):
            action = "braked" if self.settings.invalid_command == "brake" else "clamped"
            self.say(
                LogLevelName.WARNING,
                f"{invalid} invalid drive commands since start: {c.out_of_range_commands} out "
                f"of the VESC range ({action}), {c.nonfinite_commands} non-finite (braked)",
            )
        rejected = sum(self.rejected_fields.values())
        if self._rejected_report.check(rejected, now):
            parts = [f"{k} x{n}" for k, n in sorted(self.rejected_fields.items())]
            self.say(
                LogLevelName.WARNING,
                f"{rejected} VESC reply values outside the message limits were left out "
                f"({', '.join(parts)})",
            )
        self._check_imu(now)
        if now - self._last_state_pub_s >= STATUS_ONLY_INTERVAL_S:
            msg, _ = vesc_state_message(None, self.status, self.wall_clock())
            self.pub_state.put(msg)
            self._last_state_pub_s = now

    def _check_imu(self, now: float) -> None:
        """Warn (rate-limited) while the IMU is polled, the port is open and no valid IMU
        reply came for ``stale_imu_s``; say when the replies are back."""
        s = self.settings
        if s.poll_imu_rate_hz <= 0.0 or not self.driver.link.connected:
            return
        if self._imu_ref_s is None or self._imu_ref_epoch != self.driver.link.counters.connects:
            # (re)connected: give the first replies stale_imu_s from now
            self._imu_ref_s = now
            self._imu_ref_epoch = self.driver.link.counters.connects
        age = self.driver.imu_age_s(now)
        if age is None or age > now - self._imu_ref_s:
            age = now - self._imu_ref_s
        if age > s.stale_imu_s:
            if not self._imu_was_stale:
                self._imu_stale_count += 1
            self._imu_was_stale = True
            if self._imu_stale.check(self._imu_stale_count, now):
                c = self.driver.counters
                self.say(
                    LogLevelName.WARNING,
                    f"no valid VESC IMU reply for {age:.1f} s ({c.imu_replies} replies, "
                    f"{c.malformed_imu} malformed so far): vehicle/imu is silent",
                )
        elif self._imu_was_stale:
            self._imu_was_stale = False
            self.say(
                LogLevelName.INFO, "VESC IMU replies back: publishing vehicle/imu", limit="imu_back"
            )

    def _log_waiting(self) -> None:
        link = self.driver.link
        if not link.connected:
            self.log.info(
                "still waiting for the VESC port %s (%s)",
                self.settings.port,
                link.last_error or "not open yet",
            )
        if self.commands_received == 0:
            self.log.info("still waiting for the first drive command on %s", self.sub.key)

    def diagnostics(self) -> dict[str, int]:
        """The driver's counters plus the service's own (``service.*``)."""
        out = self.driver.diagnostics()
        out["service.commands_received"] = self.commands_received
        out["service.bus_drops"] = self.bus.drops.total
        out["service.own_faults"] = self.bus.faults.total
        out["service.outbox_dropped"] = self.outbox.dropped
        out["service.rejected_fields"] = sum(self.rejected_fields.values())
        out["service.imu_published"] = self.imu_published
        return out

    def close(self) -> None:
        """Close the port (call after the bus session is closed)."""
        self.driver.close()


main = VescService.main
