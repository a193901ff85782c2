"""A serial port that survives being unplugged: pyserial with reconnect and back-off.

``read()`` and ``write()`` never raise. When the port is missing (never appeared, or vanished:
``SerialException``/``OSError`` on read or write) the link closes it, reports
``LinkState.DISCONNECTED``, counts the event and retries opening with exponential back-off
(``backoff_initial_s`` doubling up to ``backoff_max_s``); the next successful open resumes
normal operation. The back-off reads the injected ``clock`` (default ``time.monotonic``).
"""

from __future__ import annotations

import select
import termios
import time
from collections.abc import Callable
from dataclasses import dataclass, fields
from enum import Enum
from typing import Any, Protocol

import serial

#: Exceptions that mean "the port is gone or unusable" (pyserial wraps most in
#: SerialException; raw OSError/termios.error/ValueError appear when a descriptor vanishes).
_PORT_ERRORS: tuple[type[BaseException], ...] = (
    serial.SerialException,
    OSError,
    termios.error,
    ValueError,
)

#: Default read chunk [bytes].
DEFAULT_READ_BYTES = 4096


class SerialPort(Protocol):
    """What the link needs of a pyserial ``Serial`` (lets tests pass a fake)."""

    def read(self, size: int = 1) -> bytes: ...

    def write(self, data: bytes) -> int | None: ...

    def close(self) -> None: ...

    def fileno(self) -> int: ...


class LinkState(Enum):
    """State of the serial link."""

    CONNECTED = "connected"
    DISCONNECTED = "disconnected"  # missing or lost; reopening with back-off
    CLOSED = "closed"  # closed on purpose by ``close()``; no reopening


@dataclass(slots=True)
class LinkCounters:
    """Events of the link since it was created.

    Attributes:
        open_attempts, open_failures: attempts to open the port and how many failed.
        connects: successful opens.
        disconnects: times an open port was lost (read/write error).
        read_errors, write_errors: I/O errors (each also causes a disconnect).
        write_timeouts: writes that did not complete within the write timeout (the port
            stays open; the frames are lost).
        bytes_read, bytes_written: payload traffic [bytes].
    """

    open_attempts: int = 0
    open_failures: int = 0
    connects: int = 0
    disconnects: int = 0
    read_errors: int = 0
    write_errors: int = 0
    write_timeouts: int = 0
    bytes_read: int = 0
    bytes_written: int = 0

    def as_dict(self) -> dict[str, int]:
        """The counters as a plain dict."""
        return {f.name: getattr(self, f.name) for f in fields(self)}


def default_serial_factory(write_timeout_s: float) -> Callable[[str, int], SerialPort]:
    """A factory opening a non-blocking pyserial port (read timeout 0)."""

    def open_port(port: str, baudrate: int) -> SerialPort:
        return serial.Serial(port=port, baudrate=baudrate, timeout=0, write_timeout=write_timeout_s)

    return open_port


class SerialLink:
    """A reconnecting serial port; all methods are safe to call in any state."""

    def __init__(
        self,
        port: str,
        baudrate: int = 115200,
        *,
        backoff_initial_s: float = 0.05,
        backoff_max_s: float = 2.0,
        write_timeout_s: float = 0.05,
        clock: Callable[[], float] = time.monotonic,
        serial_factory: Callable[[str, int], Any] | None = None,
    ) -> None:
        """Create the link (closed until the first ``maintain``/``read``/``write``).

        Args:
            port: device path (may be a symlink that is re-pointed while unplugged).
            baudrate: [bit/s].
            backoff_initial_s, backoff_max_s: first and longest delay [s] between reopen
                attempts; the delay doubles after each failed attempt.
            write_timeout_s: longest a write may block [s].
            clock: monotonic time source [s].
            serial_factory: ``(port, baudrate) -> port object``; default pyserial.
        """
        if not 0.0 < backoff_initial_s <= backoff_max_s:
            raise ValueError("need 0 < backoff_initial_s <= backoff_max_s")
        self.port = port
        self.baudrate = baudrate
        self.backoff_initial_s = backoff_initial_s
        self.backoff_max_s = backoff_max_s
        self.counters = LinkCounters()
        self.last_error: str | None = None
        self._clock = clock
        self._factory = serial_factory or default_serial_factory(write_timeout_s)
        self._ser: Any | None = None
        self._state = LinkState.DISCONNECTED
        self._backoff_s = backoff_initial_s
        self._next_attempt_s = float("-inf")

    # -- state -----------------------------------------------------------------------------
    @property
    def state(self) -> LinkState:
        """Current state."""
        return self._state

    @property
    def connected(self) -> bool:
        """True while the port is open."""
        return self._state is LinkState.CONNECTED

    @property
    def next_attempt_s(self) -> float:
        """Clock time [s] of the next reopen attempt (-inf: immediately)."""
        return self._next_attempt_s

    @property
    def backoff_s(self) -> float:
        """Delay [s] that the next failed attempt will wait."""
        return self._backoff_s

    def maintain(self) -> LinkState:
        """Try to (re)open the port if it is down and the back-off has elapsed."""
        if self._state is LinkState.DISCONNECTED and self._clock() >= self._next_attempt_s:
            self._try_open()
        return self._state

    def _try_open(self) -> None:
        self.counters.open_attempts += 1
        try:
            self._ser = self._factory(self.port, self.baudrate)
        except Exception as exc:  # the link must never raise: any open failure is "missing"
            self.counters.open_failures += 1
            self.last_error = f"open {self.port}: {exc}"
            self._schedule_retry()
            return
        self._state = LinkState.CONNECTED
        self.counters.connects += 1
        self._backoff_s = self.backoff_initial_s
        self.last_error = None

    def _schedule_retry(self) -> None:
        self._next_attempt_s = self._clock() + self._backoff_s
        self._backoff_s = min(self._backoff_s * 2.0, self.backoff_max_s)

    def _lost(self, what: str, exc: BaseException) -> None:
        """The open port failed: close it and retry at once, then with back-off."""
        self.last_error = f"{what} {self.port}: {exc}"
        self.counters.disconnects += 1
        self._close_port()
        self._state = LinkState.DISCONNECTED
        self._backoff_s = self.backoff_initial_s
        self._next_attempt_s = self._clock()

    def _close_port(self) -> None:
        ser, self._ser = self._ser, None
        if ser is not None:
            try:
                ser.close()
            except Exception:  # closing a vanished device may fail; it is gone either way
                pass

    # -- I/O -------------------------------------------------------------------------------
    def read(self, max_bytes: int = DEFAULT_READ_BYTES) -> bytes:
        """Bytes available now (up to ``max_bytes``; never blocks long, never raises).

        Returns b"" when nothing is waiting or the port is down.
        """
        if self.maintain() is not LinkState.CONNECTED:
            return b""
        try:
            data = bytes(self._ser.read(max_bytes))  # type: ignore[union-attr]
        except _PORT_ERRORS as exc:
            self.counters.read_errors += 1
            self._lost("read", exc)
            return b""
        self.counters.bytes_read += len(data)
        return data

    def write(self, data: bytes) -> bool:
        """Write ``data``; True if it was handed to the port (never raises)."""
        if not data or self.maintain() is not LinkState.CONNECTED:
            return False
        try:
            n = self._ser.write(data)  # type: ignore[union-attr]
        except serial.SerialTimeoutException as exc:
            self.counters.write_timeouts += 1
            self.last_error = f"write {self.port}: {exc}"
            return False
        except _PORT_ERRORS as exc:
            self.counters.write_errors += 1
            self._lost("write", exc)
            return False
        self.counters.bytes_written += len(data) if n is None else n
        return True

    def wait_readable(self, timeout_s: float) -> bool:
        """Block up to ``timeout_s`` [s] until bytes can be read; False on timeout or when down.

        Returns at once (False) when the port is down; the caller sleeps instead.
        """
        if self._state is not LinkState.CONNECTED or self._ser is None:
            return False
        try:
            ready, _, _ = select.select([self._ser.fileno()], [], [], max(0.0, timeout_s))
        except _PORT_ERRORS:
            return True  # let the next read() find and report the error
        return bool(ready)

    def fileno(self) -> int | None:
        """The open port's file descriptor (to ``select`` on), or None when down or unknown."""
        if self._state is not LinkState.CONNECTED or self._ser is None:
            return None
        try:
            fd = int(self._ser.fileno())
        except Exception:  # a port closed under us: the next read reports it
            return None
        return fd if fd >= 0 else None

    def close(self) -> None:
        """Close the port for good (``read``/``write`` then do nothing)."""
        self._close_port()
        self._state = LinkState.CLOSED

    def __enter__(self) -> SerialLink:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
