"""A fake VESC on a pseudo-terminal: the thin I/O shell around ``shared.vesc.fake``.

The only module of ``shared.vesc`` that does I/O. ``FakeVesc`` opens a pty pair
(``os.openpty``, raw mode), points a stable symlink (``FakeVesc.path``) at the slave device
and, in a daemon thread, feeds what the driver writes to a ``FakeVescModel`` and writes the
model's replies back. The model (event log, motor state, firmware timeout, GET_VALUES
replies and the ``reply_values`` hook) is documented in ``shared.vesc.fake``.

Used by the vesc_driver's tests, ``benchmarks.vesc_wire_latency`` and the simulator's
``actuation = "fake_vesc"`` (``services.simulator.vesc_actuation``).

``unplug()`` removes the symlink and closes both ends of the pty, so the driver's next read
or write fails and reopening fails; ``replug()`` makes a new pty and re-points the symlink.
All descriptor operations happen on the fake's own thread (requests from other threads are
queued to it), so no descriptor is closed under a running ``select``.
"""

from __future__ import annotations

import contextlib
import os
import select
import threading
import time
import tty
from collections.abc import Callable
from pathlib import Path
from typing import Any

from shared.fake_thread import FakeDevice, RequestPipe, pty_available  # noqa: F401 (re-exported)
from shared.vesc.fake import (
    DEFAULT_FIRMWARE_TIMEOUT_S,
    DEFAULT_VALUES,
    MAX_EVENTS,
    FakeEvent,
    FakeImu,
    FakeMotorState,
    FakeVescModel,
    ReplyImuHook,
    ReplyValuesHook,
)
from shared.vesc.values import VescValues

#: Poll period of the fake's loop when idle [s] (also the firmware timeout resolution).
_IDLE_POLL_S = 0.005




def _state_field(name: str, doc: str) -> Any:
    """A read-only attribute of the fake: field ``name`` of its current ``FakeMotorState``."""

    def get(self: FakeVesc) -> Any:
        return getattr(self.model.state, name)

    return property(get, doc=doc)


def _model_setting(name: str, doc: str) -> Any:
    """A read-write attribute of the fake that is the model's (written under the lock)."""

    def get(self: FakeVesc) -> Any:
        return getattr(self.model, name)

    def put(self: FakeVesc, value: Any) -> None:
        with self._cond:
            setattr(self.model, name, value)

    return property(get, put, doc=doc)


class FakeVesc(FakeDevice):
    """A VESC stand-in on a pty; use as a context manager or call ``close()``.

    Reading the applied commands: ``motor_state()`` (a consistent ``FakeMotorState``), the
    single fields as attributes (``mode``, ``last_erpm``, ``last_servo``, ...), or
    ``events()``. ``wait_for(predicate, timeout_s)`` waits for a condition.
    """

    # the motor state, field by field (each read alone; use motor_state() for several)
    mode = _state_field("mode", '"released" | "rpm" | "brake" | "current" | "duty"')
    last_erpm = _state_field("last_erpm", "newest SET_RPM [ERPM] (None before any)")
    last_erpm_s = _state_field("last_erpm_s", "its time [s]")
    last_servo = _state_field("last_servo", "newest SET_SERVO_POS [0, 1] (None before any)")
    last_servo_s = _state_field("last_servo_s", "its time [s]")
    last_brake_a = _state_field("last_brake_a", "newest SET_CURRENT_BRAKE [A]")
    last_brake_s = _state_field("last_brake_s", "its time [s]")
    last_alive_s = _state_field("last_alive_s", "newest SET_* or ALIVE [s]")
    firmware_timed_out = _state_field("firmware_timed_out", "the firmware timeout released")
    firmware_timeouts = _state_field("firmware_timeouts", "firmware timeouts so far")
    # settings of the model (settable at any time)
    timeout_s = _model_setting("timeout_s", "firmware command timeout [s]")
    values = _model_setting("values", "template of the GET_VALUES replies")
    reply_length = _model_setting("reply_length", "reply payload length [bytes] or None")
    replies_enabled = _model_setting("replies_enabled", "False: GET_VALUES is not answered")
    reply_values = _model_setting("reply_values", "the ReplyValuesHook or None")
    imu = _model_setting("imu", "the IMU board reading (FakeImu) of GET_IMU_DATA replies")
    imu_replies_enabled = _model_setting("imu_replies_enabled", "False: no IMU replies")
    reply_imu = _model_setting("reply_imu", "the ReplyImuHook or None")

    def __init__(
        self,
        *,
        timeout_s: float = DEFAULT_FIRMWARE_TIMEOUT_S,
        values: VescValues = DEFAULT_VALUES,
        reply_length: int | None = None,
        reply_values: ReplyValuesHook | None = None,
        max_events: int = MAX_EVENTS,
        link_dir: str | Path | None = None,
        clock: Callable[[], float] = time.monotonic,
        imu: FakeImu | None = None,
        reply_imu: ReplyImuHook | None = None,
    ) -> None:
        """Create the pty and start the fake's thread.

        Args:
            timeout_s: firmware command timeout [s].
            values: template of GET_VALUES replies (erpm, the motor current and the status
                are set from the fake's motor state).
            reply_length: truncate replies to this many payload bytes (older firmware).
            reply_values: ``(motor state, reply) -> values`` replacing each GET_VALUES reply
                (None: the reply as is). It runs on the fake's thread with the fake's
                (re-entrant) lock held: keep it short.
            max_events: events kept in memory (the oldest dropped; 0: none).
            link_dir: folder for the stable symlink (default: a new temporary folder,
                removed by ``close()``).
            clock: time source [s] of the event and motor-state timestamps.
            imu: the IMU board reading of GET_IMU_DATA replies (default: level, at rest).
            reply_imu: ``(motor state, reading) -> reading`` replacing each IMU reply's
                reading (runs on the fake's thread with its lock held, like reply_values).
        """
        self.model = FakeVescModel(
            timeout_s=timeout_s,
            values=values,
            reply_length=reply_length,
            reply_values=reply_values,
            max_events=max_events,
            imu=imu,
            reply_imu=reply_imu,
        )
        self._clock = clock
        self._init_device("the fake VESC", link_dir, "fake-vesc")
        self.path = str(self._dir / "vesc")
        self._cond = threading.Condition(threading.RLock())
        self._master: int | None = None
        self._slave: int | None = None
        self.device_path: str | None = None
        self.bytes_dropped = 0
        self.thread_error: BaseException | None = None
        self._plug()
        self._start("fake-vesc")

    # -- public API --------------------------------------------------------------------------
    @property
    def plugged(self) -> bool:
        """True while the pty exists and the symlink points at it."""
        return self._master is not None

    @property
    def running(self) -> bool:
        """True while the fake's thread runs."""
        return self._thread.is_alive()

    @property
    def values_requests(self) -> int:
        """GET_VALUES requests seen so far."""
        return self.model.values_requests

    @property
    def replies_sent(self) -> int:
        """GET_VALUES replies sent so far."""
        return self.model.replies_sent

    @property
    def imu_requests(self) -> int:
        """GET_IMU_DATA requests seen so far."""
        return self.model.imu_requests

    @property
    def imu_replies_sent(self) -> int:
        """GET_IMU_DATA replies sent so far."""
        return self.model.imu_replies_sent

    def motor_state(self) -> FakeMotorState:
        """A consistent copy of what the commands applied (mode, newest values, timeout)."""
        with self._cond:
            return self.model.state

    def events(self, command: int | None = None) -> list[FakeEvent]:
        """A copy of the recorded events (only those of ``command`` if given)."""
        with self._cond:
            return self.model.events(command)

    def clear_events(self) -> None:
        """Forget recorded events."""
        with self._cond:
            self.model.clear_events()

    def wait_for(self, predicate: Callable[[FakeVesc], bool], timeout_s: float) -> bool:
        """Wait up to ``timeout_s`` [s] until ``predicate(self)`` holds (rechecked per event).

        The predicate runs without the fake's lock held (it may call ``events()``).
        """
        deadline = time.monotonic() + timeout_s
        while True:
            if predicate(self):
                return True
            left = deadline - time.monotonic()
            if left <= 0.0:
                return False
            with self._cond:
                self._cond.wait(min(left, 0.02))

    def unplug(self) -> None:
        """Pull the cable: remove the symlink and close the pty (driver I/O then fails)."""
        self._request(self._unplug)

    def replug(self) -> None:
        """Plug back in: a new pty, the symlink re-pointed at it."""
        self._request(self._plug)

    def inject(self, data: bytes) -> None:
        """Write raw bytes (e.g. garbage) to the driver, between the fake's own replies."""
        self._request(lambda: self._write(data))

    # -- pty (only on the fake's thread after start) -----------------------------------------
    def _plug(self) -> None:
        if self._master is not None:
            return
        master, slave = os.openpty()
        tty.setraw(slave)
        os.set_blocking(master, False)
        self._master, self._slave = master, slave
        self.device_path = os.ttyname(slave)
        tmp = f"{self.path}.tmp"
        with contextlib.suppress(FileNotFoundError):
            os.unlink(tmp)
        os.symlink(self.device_path, tmp)
        os.replace(tmp, self.path)
        with self._cond:
            self.model.reset_link()

    def _unplug(self) -> None:
        with contextlib.suppress(FileNotFoundError):
            os.unlink(self.path)
        for fd in (self._master, self._slave):
            if fd is not None:
                with contextlib.suppress(OSError):
                    os.close(fd)
        self._master = self._slave = None
        self.device_path = None

    def _write(self, data: bytes) -> None:
        if self._master is None:
            return
        try:
            n = os.write(self._master, data)
        except BlockingIOError:
            n = 0
        except OSError:
            return
        self.bytes_dropped += len(data) - n

    # -- the fake's thread --------------------------------------------------------------------
    def _run(self) -> None:
        try:
            while not self._stop.is_set():
                self._requests.serve()
                wake = self._requests.wake_fd
                fds = [wake] if self._master is None else [wake, self._master]
                ready, _, _ = select.select(fds, [], [], _IDLE_POLL_S)
                if wake in ready:
                    self._requests.drain()
                    self._requests.serve()
                if self._master is not None and self._master in ready:
                    try:
                        data = os.read(self._master, 4096)
                    except BlockingIOError:
                        data = b""
                    except OSError:
                        data = b""  # the slave side went away; wait for a replug
                    if data:
                        self._on_bytes(data)
                with self._cond:
                    if self.model.check_timeout(self._clock()):
                        self._cond.notify_all()
        except BaseException as exc:  # report instead of dying silently
            self.thread_error = exc
        finally:
            self._requests.serve()

    def _on_bytes(self, data: bytes) -> None:
        now = self._clock()
        with self._cond:
            replies = self.model.feed(data, now)
            self._cond.notify_all()
        if replies:
            self._write(replies)
