"""The reconnecting serial link, with a scripted port and a manual clock (no real device)."""

from __future__ import annotations

import itertools
from typing import Any

import pytest

from services.vesc_driver.serial_link import LinkState, SerialLink


def make_link(clock: Any, factory: Any) -> SerialLink:
    return SerialLink(
        "/dev/fake", 115200, backoff_initial_s=0.1, backoff_max_s=0.8, clock=clock,
        serial_factory=factory,
    )  # fmt: skip


def test_opens_reads_writes(clock: Any, factory: Any) -> None:
    link = make_link(clock, factory)
    assert link.state is LinkState.DISCONNECTED  # nothing opened yet
    assert link.write(b"abc")
    assert link.connected and factory.current.tx == [b"abc"]
    factory.current.rx += b"xyz"
    assert link.read() == b"xyz" and link.read() == b""
    assert link.counters.bytes_read == 3 and link.counters.bytes_written == 3
    assert link.counters.connects == 1
    assert not link.write(b"")


def test_missing_port_backs_off_exponentially(clock: Any, factory: Any) -> None:
    factory.present = False
    link = make_link(clock, factory)
    attempts_at = []
    for _ in range(400):  # 4 s in 10 ms steps
        before = factory.calls
        assert link.read() == b"" and not link.write(b"x")
        if factory.calls != before:
            attempts_at.append(round(clock(), 3))
        clock.advance(0.01)
    gaps = [round(b - a, 2) for a, b in itertools.pairwise(attempts_at)]
    assert gaps[:4] == [0.1, 0.2, 0.4, 0.8]
    assert set(gaps[4:]) == {0.8}  # capped at backoff_max_s
    assert link.state is LinkState.DISCONNECTED
    assert link.counters.open_failures == link.counters.open_attempts == len(attempts_at)
    assert "could not open" in (link.last_error or "")
    factory.present = True
    clock.advance(0.8)
    assert link.write(b"back") and link.connected and link.backoff_s == pytest.approx(0.1)


@pytest.mark.parametrize("fault", ["fail_read", "fail_write"])
def test_vanishing_port_reconnects(clock: Any, factory: Any, fault: str) -> None:
    link = make_link(clock, factory)
    assert link.write(b"1")
    first = factory.current
    setattr(first, fault, True)
    factory.present = False
    link.read()
    link.write(b"2")
    assert link.state is LinkState.DISCONNECTED and first.closed
    assert link.counters.disconnects == 1
    assert link.counters.read_errors + link.counters.write_errors == 1
    # while unplugged: retries with back-off, nothing raises
    for _ in range(50):
        clock.advance(0.01)
        assert link.read() == b""
    factory.present = True
    clock.advance(1.0)
    assert link.write(b"3")
    assert link.connected and factory.current is not first and factory.current.tx == [b"3"]
    assert link.counters.connects == 2


def test_write_timeout_keeps_port(clock: Any, factory: Any) -> None:
    link = make_link(clock, factory)
    assert link.write(b"1")
    factory.current.timeout_write = True
    assert not link.write(b"2")
    assert link.connected and link.counters.write_timeouts == 1 and link.counters.disconnects == 0


def test_factory_raising_anything_is_contained(clock: Any) -> None:
    def boom(port: str, baud: int) -> Any:
        raise RuntimeError("driver bug")

    link = SerialLink("/dev/x", clock=clock, serial_factory=boom)
    assert link.read() == b"" and not link.write(b"x")
    assert link.counters.open_failures == 1


def test_close_is_final(clock: Any, factory: Any) -> None:
    with make_link(clock, factory) as link:
        assert link.write(b"x")
    assert link.state is LinkState.CLOSED and factory.current.closed
    clock.advance(10.0)
    assert not link.write(b"y") and link.read() == b"" and not link.wait_readable(0.0)
    assert factory.calls == 1


def test_bad_backoff_rejected() -> None:
    with pytest.raises(ValueError):
        SerialLink("/dev/x", backoff_initial_s=1.0, backoff_max_s=0.5)
