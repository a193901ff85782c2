"""The lidar's byte link: a USB serial port or a TCP connection, reopened when it is lost.

``Link(address)`` opens ``tcp://HOST:PORT`` as a TCP connection (Ethernet Hokuyos) and any
other address as a serial device (pyserial; the USB UTM-30LX is a CDC-ACM port). ``read``
and ``write`` never raise: an error (or EOF on TCP) closes the link, counts it and reports
``connected == False``; ``maintain(now)`` reopens it at most once per ``reconnect_period_s``
(the caller passes ``now`` [s] of a monotonic clock). ``drop(reason)`` closes it on purpose
(e.g. a silent sensor) and lets the next ``maintain`` reopen it after the period.
"""

from __future__ import annotations

import contextlib
import select
import socket
import termios
from collections.abc import Callable
from dataclasses import dataclass, fields
from typing import Any, Protocol

import serial

__all__ = ["Link", "LinkCounters", "Transport", "open_transport"]

#: What means "the device or connection is gone".
_ERRORS: tuple[type[BaseException], ...] = (
    serial.SerialException,
    OSError,
    termios.error,
    ValueError,
)
#: Longest a TCP connect may block [s].
CONNECT_TIMEOUT_S = 1.0
#: Longest a write may block [s].
WRITE_TIMEOUT_S = 0.2
_READ_BYTES = 65536


class Transport(Protocol):
    """An open byte stream (non-blocking reads)."""

    def read(self, n: int) -> bytes: ...

    def write(self, data: bytes) -> None: ...

    def fileno(self) -> int: ...

    def close(self) -> None: ...


class _Serial:
    def __init__(self, path: str, baudrate: int) -> None:
        self._s = serial.Serial(
            port=path, baudrate=baudrate, timeout=0, write_timeout=WRITE_TIMEOUT_S
        )

    def read(self, n: int) -> bytes:
        return bytes(self._s.read(n))

    def write(self, data: bytes) -> None:
        self._s.write(data)

    def fileno(self) -> int:
        return int(self._s.fileno())

    def close(self) -> None:
        self._s.close()


class _Tcp:
    def __init__(self, host: str, port: int) -> None:
        self._s = socket.create_connection((host, port), timeout=CONNECT_TIMEOUT_S)
        self._s.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        self._s.settimeout(WRITE_TIMEOUT_S)

    def read(self, n: int) -> bytes:
        try:
            data = self._s.recv(n, socket.MSG_DONTWAIT)
        except BlockingIOError:
            return b""
        if not data:
            raise ConnectionError("the sensor closed the connection")
        return data

    def write(self, data: bytes) -> None:
        self._s.sendall(data)

    def fileno(self) -> int:
        return self._s.fileno()

    def close(self) -> None:
        self._s.close()


def open_transport(address: str, baudrate: int) -> Transport:
    """Open ``tcp://HOST:PORT`` or a serial device (raises on failure)."""
    if address.startswith("tcp://"):
        host, _, port = address[6:].rpartition(":")
        return _Tcp(host, int(port))
    return _Serial(address, baudrate)


@dataclass(slots=True)
class LinkCounters:
    """Events of the link.

    Attributes:
        open_attempts, open_failures, connects: opens tried, failed, succeeded.
        losses: an open link failed (read/write error, EOF).
        drops: closed on purpose (``drop``).
        bytes_read, bytes_written: traffic [bytes].
    """

    open_attempts: int = 0
    open_failures: int = 0
    connects: int = 0
    losses: int = 0
    drops: int = 0
    bytes_read: int = 0
    bytes_written: int = 0

    def as_dict(self) -> dict[str, int]:
        """The counters as a plain dict."""
        return {f.name: getattr(self, f.name) for f in fields(self)}


class Link:
    """A reconnecting byte link (module docstring); every method is safe in any state."""

    def __init__(
        self,
        address: str,
        baudrate: int = 115200,
        *,
        reconnect_period_s: float = 1.0,
        opener: Callable[[str, int], Any] = open_transport,
    ) -> None:
        self.address = address
        self.baudrate = baudrate
        self.reconnect_period_s = reconnect_period_s
        self.counters = LinkCounters()
        self.last_error: str | None = None
        self._opener = opener
        self._t: Any | None = None
        self._next_attempt_s = float("-inf")

    @property
    def connected(self) -> bool:
        """True while the transport is open."""
        return self._t is not None

    def maintain(self, now: float) -> bool:
        """Open the link if it is down and the period since the last try passed; connected?"""
        if self._t is None and now >= self._next_attempt_s:
            self.counters.open_attempts += 1
            self._next_attempt_s = now + self.reconnect_period_s
            try:
                self._t = self._opener(self.address, self.baudrate)
            except Exception as exc:  # any failure to open is "not there (yet)"
                self.counters.open_failures += 1
                self.last_error = f"open {self.address}: {exc}"
            else:
                self.counters.connects += 1
                self.last_error = None
        return self._t is not None

    def _lost(self, what: str, exc: BaseException) -> None:
        self.last_error = f"{what} {self.address}: {exc}"
        self.counters.losses += 1
        self._close()

    def _close(self) -> None:
        t, self._t = self._t, None
        if t is not None:
            with contextlib.suppress(Exception):
                t.close()

    def read(self) -> bytes:
        """The bytes waiting now (b"" when none or down); never raises."""
        if self._t is None:
            return b""
        try:
            data = self._t.read(_READ_BYTES)
        except _ERRORS as exc:
            self._lost("read", exc)
            return b""
        self.counters.bytes_read += len(data)
        return data

    def write(self, data: bytes) -> bool:
        """Send ``data``; True if it was handed over (never raises)."""
        if self._t is None or not data:
            return False
        try:
            self._t.write(data)
        except _ERRORS as exc:
            self._lost("write", exc)
            return False
        self.counters.bytes_written += len(data)
        return True

    def wait_readable(self, timeout_s: float) -> bool:
        """Block up to ``timeout_s`` [s] until bytes can be read; False on timeout or down."""
        if self._t is None:
            return False
        try:
            ready, _, _ = select.select([self._t.fileno()], [], [], max(0.0, timeout_s))
        except _ERRORS:
            return True  # let read() find and report the error
        return bool(ready)

    def drop(self, reason: str, now: float) -> None:
        """Close on purpose (e.g. a silent sensor); reopened after ``reconnect_period_s``."""
        if self._t is not None:
            self.counters.drops += 1
            self.last_error = reason
            self._close()
        self._next_attempt_s = now + self.reconnect_period_s

    def close(self) -> None:
        """Close the transport (the next ``maintain`` may open it again)."""
        self._close()
