"""A fake VESC on a pseudo-terminal, for tests and bench runs without hardware.

The fake opens a pty pair (``os.openpty``, raw mode), points a stable symlink
(``FakeVesc.path``) at the slave device, and in a daemon thread decodes what the driver
writes with the same ``FrameDecoder``. It records every command with a timestamp, answers
GET_VALUES with a plausible reply (``erpm`` = the last commanded ERPM while in RPM mode) and
models the firmware's command timeout: without SET_*/ALIVE (SET_SERVO_POS does not count) for
``timeout_s`` the motor is released and status bit 0 is set in replies.

``unplug()`` removes the symlink and closes both ends of the pty, so the driver's next read
or write fails and reopening fails; ``replug()`` makes a new pty and re-points the symlink.
All descriptor operations happen on the fake's own thread (requests from other threads are
queued to it), so no descriptor is closed under a running ``select``.
"""

from __future__ import annotations

import contextlib
import os
import queue
import select
import shutil
import tempfile
import threading
import time
import tty
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, replace
from pathlib import Path

from services.vesc_driver.decoder import FrameDecoder
from services.vesc_driver.protocol import (
    TIMEOUT_RESETTING_COMMANDS,
    CommandId,
    decode_command_value,
    encode_frame,
)
from services.vesc_driver.values import STATUS_TIMEOUT_BIT, VescValues, encode_values_payload

#: Default firmware command timeout [s] of the fake (the VESC tool's default is 1 s).
DEFAULT_FIRMWARE_TIMEOUT_S = 1.0
#: Longest a request to the fake's thread may take before it is reported as failed [s].
_REQUEST_TIMEOUT_S = 2.0
#: Poll period of the fake's loop when idle [s] (also the firmware timeout resolution).
_IDLE_POLL_S = 0.005
#: Events kept in memory.
_MAX_EVENTS = 100_000


def pty_available() -> bool:
    """Whether this machine can open pseudo-terminals (what ``FakeVesc`` needs)."""
    try:
        m, s = os.openpty()
    except OSError:
        return False
    os.close(m)
    os.close(s)
    return True


@dataclass(frozen=True, slots=True)
class FakeEvent:
    """One command seen by the fake.

    Attributes:
        t_s: the fake's clock [s] when the frame was decoded.
        command: the command id (int; compare with ``CommandId``).
        value: the decoded value in encoder units (ERPM, servo [0, 1], current [A], duty), or
            None for commands without one.
    """

    t_s: float
    command: int
    value: float | None


#: The reply template (a sitting car on a 4S battery); the fake overwrites the live fields.
DEFAULT_VALUES = VescValues(
    temp_fet_c=31.5,
    temp_motor_c=28.0,
    avg_motor_current_a=0.0,
    avg_input_current_a=0.0,
    avg_id_a=0.0,
    avg_iq_a=0.0,
    duty=0.0,
    erpm=0.0,
    v_in_v=16.8,
    amp_hours=0.0,
    amp_hours_charged=0.0,
    watt_hours=0.0,
    watt_hours_charged=0.0,
    tachometer=0,
    tachometer_abs=0,
    fault_code=0,
    pid_pos_deg=0.0,
    controller_id=0,
    temp_mos1_c=31.0,
    temp_mos2_c=31.5,
    temp_mos3_c=32.0,
    avg_vd_v=0.0,
    avg_vq_v=0.0,
    status_flags=0,
)


class FakeVesc:
    """A VESC stand-in on a pty; use as a context manager or call ``close()``."""

    def __init__(
        self,
        *,
        timeout_s: float = DEFAULT_FIRMWARE_TIMEOUT_S,
        values: VescValues = DEFAULT_VALUES,
        reply_length: int | None = None,
        link_dir: str | Path | None = None,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        """Create the pty and start the fake's thread.

        Args:
            timeout_s: firmware command timeout [s].
            values: template of GET_VALUES replies (erpm, duty, currents and status are set
                from the fake's motor state).
            reply_length: truncate replies to this many payload bytes (older firmware).
            link_dir: folder for the stable symlink (default: a new temporary folder,
                removed by ``close()``).
            clock: time source [s] of the event timestamps.
        """
        self.timeout_s = timeout_s
        self.values = values
        self.reply_length = reply_length
        self.replies_enabled = True
        self.decoder = FrameDecoder()
        self._clock = clock
        self._own_dir = link_dir is None
        self._dir = Path(link_dir) if link_dir is not None else Path(tempfile.mkdtemp("fake-vesc"))
        self.path = str(self._dir / "vesc")
        self._lock = threading.Lock()
        self._cond = threading.Condition(self._lock)
        self._events: deque[FakeEvent] = deque(maxlen=_MAX_EVENTS)
        self._requests: queue.SimpleQueue[tuple[Callable[[], object], _Reply]] = queue.SimpleQueue()
        self._wake_r, self._wake_w = os.pipe()
        os.set_blocking(self._wake_r, False)
        self._stop = threading.Event()
        self._master: int | None = None
        self._slave: int | None = None
        self.device_path: str | None = None
        # motor model (guarded by _lock)
        self.mode = "released"  # "released" | "rpm" | "brake" | "current" | "duty"
        self.last_erpm: float | None = None
        self.last_erpm_s: float | None = None
        self.last_servo: float | None = None
        self.last_servo_s: float | None = None
        self.last_brake_a: float | None = None
        self.last_brake_s: float | None = None
        self.last_alive_s: float | None = None
        self.firmware_timed_out = False
        self.firmware_timeouts = 0
        self.values_requests = 0
        self.replies_sent = 0
        self.bytes_dropped = 0
        self.thread_error: BaseException | None = None
        self._plug()
        self._thread = threading.Thread(target=self._run, name="fake-vesc", daemon=True)
        self._thread.start()

    # -- public API --------------------------------------------------------------------------
    @property
    def plugged(self) -> bool:
        """True while the pty exists and the symlink points at it."""
        return self._master is not None

    def events(self, command: int | None = None) -> list[FakeEvent]:
        """A copy of the recorded events (only those of ``command`` if given)."""
        with self._lock:
            return [e for e in self._events if command is None or e.command == command]

    def clear_events(self) -> None:
        """Forget recorded events."""
        with self._lock:
            self._events.clear()

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

    def close(self, timeout_s: float = 2.0) -> None:
        """Stop the thread (joined with ``timeout_s`` [s]), close the pty, remove the link."""
        if self._stop.is_set():
            return
        self._stop.set()
        self._wake()
        self._thread.join(timeout_s)
        self._unplug()
        for fd in (self._wake_r, self._wake_w):
            with contextlib.suppress(OSError):
                os.close(fd)
        if self._own_dir:
            shutil.rmtree(self._dir, ignore_errors=True)

    def __enter__(self) -> FakeVesc:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # -- requests to the fake's thread -------------------------------------------------------
    def _wake(self) -> None:
        with contextlib.suppress(OSError):
            os.write(self._wake_w, b"\x00")

    def _request(self, action: Callable[[], object]) -> None:
        if self._stop.is_set() or not self._thread.is_alive():
            raise RuntimeError("the fake VESC is closed")
        reply = _Reply()
        self._requests.put((action, reply))
        self._wake()
        if not reply.done.wait(_REQUEST_TIMEOUT_S):
            raise TimeoutError("the fake VESC thread did not answer")
        if reply.error is not None:
            raise reply.error

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
        self.decoder.reset()

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
                self._serve_requests()
                fds = [self._wake_r] if self._master is None else [self._wake_r, self._master]
                ready, _, _ = select.select(fds, [], [], _IDLE_POLL_S)
                if self._wake_r in ready:
                    with contextlib.suppress(BlockingIOError):
                        os.read(self._wake_r, 4096)
                    self._serve_requests()
                if self._master is not None and self._master in ready:
                    try:
                        data = os.read(self._master, 4096)
                    except BlockingIOError:
                        data = b""
                    except OSError:
                        data = b""  # the slave side went away; wait for a replug
                    if data:
                        self._on_bytes(data)
                self._check_timeout(self._clock())
        except BaseException as exc:  # report instead of dying silently
            self.thread_error = exc
        finally:
            self._serve_requests()

    def _serve_requests(self) -> None:
        while True:
            try:
                action, reply = self._requests.get_nowait()
            except queue.Empty:
                return
            try:
                action()
            except BaseException as exc:
                reply.error = exc
            reply.done.set()

    def _on_bytes(self, data: bytes) -> None:
        now = self._clock()
        for frame in self.decoder.feed(data):
            cid = frame.command_id
            value = decode_command_value(frame.payload)
            with self._cond:
                self._events.append(FakeEvent(t_s=now, command=cid, value=value))
                if cid in TIMEOUT_RESETTING_COMMANDS:
                    self.last_alive_s = now
                    self.firmware_timed_out = False
                if cid == CommandId.SET_RPM and value is not None:
                    self.mode, self.last_erpm, self.last_erpm_s = "rpm", value, now
                elif cid == CommandId.SET_CURRENT_BRAKE and value is not None:
                    self.mode, self.last_brake_a, self.last_brake_s = "brake", value, now
                elif cid == CommandId.SET_SERVO_POS and value is not None:
                    self.last_servo, self.last_servo_s = value, now
                elif cid == CommandId.SET_CURRENT:
                    self.mode = "current"
                elif cid == CommandId.SET_DUTY:
                    self.mode = "duty"
                self._cond.notify_all()
            if cid == CommandId.GET_VALUES:
                self.values_requests += 1
                if self.replies_enabled:
                    self._write(self._reply())
                    self.replies_sent += 1

    def _check_timeout(self, now: float) -> None:
        with self._cond:
            if (
                self.mode != "released"
                and self.last_alive_s is not None
                and now - self.last_alive_s > self.timeout_s
            ):
                self.mode = "released"
                self.firmware_timed_out = True
                self.firmware_timeouts += 1
                self._cond.notify_all()

    def _reply(self) -> bytes:
        with self._lock:
            erpm = self.last_erpm if self.mode == "rpm" and self.last_erpm is not None else 0.0
            flags = (self.values.status_flags or 0) & ~STATUS_TIMEOUT_BIT
            if self.firmware_timed_out:
                flags |= STATUS_TIMEOUT_BIT
            brake = self.last_brake_a if self.mode == "brake" else 0.0
        values = replace(
            self.values,
            erpm=erpm,
            avg_motor_current_a=-(brake or 0.0),
            status_flags=flags,
        )
        return encode_frame(encode_values_payload(values, self.reply_length))


class _Reply:
    """Completion of a request handed to the fake's thread."""

    __slots__ = ("done", "error")

    def __init__(self) -> None:
        self.done = threading.Event()
        self.error: BaseException | None = None
