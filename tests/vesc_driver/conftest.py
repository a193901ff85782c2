"""Fixtures of the VESC driver tests: a scripted serial port, a manual clock, a deadline."""

from __future__ import annotations

import faulthandler
import sys
from collections.abc import Iterator

import pytest
import serial

#: Hard limit of one VESC test [s]: past it the stacks are dumped and the run ends, so a
#: hung thread or pty can never hang the suite.
TEST_DEADLINE_S = 30.0


@pytest.fixture(autouse=True)
def _vesc_deadline() -> Iterator[None]:
    faulthandler.dump_traceback_later(TEST_DEADLINE_S, exit=True, file=sys.stderr)
    try:
        yield
    finally:
        faulthandler.cancel_dump_traceback_later()


class ManualClock:
    """A clock [s] the test advances by hand."""

    def __init__(self, t: float = 100.0) -> None:
        self.t = t

    def __call__(self) -> float:
        return self.t

    def advance(self, dt: float) -> float:
        self.t += dt
        return self.t


class ScriptedPort:
    """An in-memory stand-in for a pyserial port: queued input, recorded output, faults."""

    def __init__(self) -> None:
        self.rx = bytearray()
        self.tx: list[bytes] = []
        self.fail_read = False
        self.fail_write = False
        self.timeout_write = False
        self.closed = False

    def read(self, size: int = 1) -> bytes:
        if self.closed:
            raise serial.PortNotOpenError()
        if self.fail_read:
            raise serial.SerialException("device reports readiness to read but returned no data")
        out = bytes(self.rx[:size])
        del self.rx[:size]
        return out

    def write(self, data: bytes) -> int:
        if self.fail_write:
            raise OSError(5, "Input/output error")
        if self.timeout_write:
            raise serial.SerialTimeoutException("Write timeout")
        self.tx.append(bytes(data))
        return len(data)

    def close(self) -> None:
        self.closed = True

    def fileno(self) -> int:
        return -1


class PortFactory:
    """``serial_factory`` for ``SerialLink``: opens ScriptedPorts while ``present``."""

    def __init__(self) -> None:
        self.present = True
        self.opened: list[ScriptedPort] = []
        self.calls = 0

    def __call__(self, port: str, baudrate: int) -> ScriptedPort:
        self.calls += 1
        if not self.present:
            raise serial.SerialException(2, f"could not open port {port}: No such file")
        p = ScriptedPort()
        self.opened.append(p)
        return p

    @property
    def current(self) -> ScriptedPort:
        return self.opened[-1]


@pytest.fixture
def clock() -> ManualClock:
    return ManualClock()


@pytest.fixture
def factory() -> PortFactory:
    return PortFactory()
