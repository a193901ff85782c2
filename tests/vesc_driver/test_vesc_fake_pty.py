"""End to end through a real serial device path: the real driver against the fake VESC on a pty.

Every test that starts threads stops them with a timeout (the fixture checks they ended).
"""

from __future__ import annotations

import threading
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
import serial

from services.vesc_driver.driver import TickResult, VescDriver
from services.vesc_driver.serial_link import LinkState
from shared.config.vesc import VescSettings
from shared.vesc.fake_pty import FakeVesc, pty_available
from shared.vesc.protocol import (
    CommandId,
    encode_frame,
    encode_get_values,
    encode_set_rpm,
    encode_set_servo_pos,
)
from shared.vesc.values import parse_values

JOIN_TIMEOUT_S = 3.0


pytestmark = pytest.mark.skipif(not pty_available(), reason="needs pseudo-terminals (os.openpty)")


class Running:
    """A driver running in a thread, its tick results and any exception it raised."""

    def __init__(self, settings: VescSettings) -> None:
        self.driver = VescDriver(settings)
        self.stop = threading.Event()
        self.results: list[TickResult] = []
        self.errors: list[BaseException] = []
        self.thread = threading.Thread(target=self._main, name="vesc-driver", daemon=True)
        self.thread.start()

    def _main(self) -> None:
        try:
            self.driver.run(self.stop, self.results.append)
        except BaseException as exc:
            self.errors.append(exc)

    def command_for(self, duration_s: float, speed: float, steer: float) -> float:
        """Send commands at 50 Hz for ``duration_s``; return the time of the last one."""
        end = time.monotonic() + duration_s
        while True:
            now = self.driver.now()
            self.driver.on_command(speed, steer, now)
            if now >= end:
                return now
            time.sleep(0.02)

    def halt(self) -> None:
        self.stop.set()
        self.thread.join(JOIN_TIMEOUT_S)
        assert not self.thread.is_alive(), "driver thread did not stop"
        assert self.errors == []


def settings_for(path: str, **overrides: Any) -> VescSettings:
    base: dict[str, Any] = {
        "port": path,
        "reconnect_backoff_initial_s": 0.02,
        "reconnect_backoff_max_s": 0.2,
    }
    return VescSettings(**(base | overrides))


@pytest.fixture
def fake() -> Iterator[FakeVesc]:
    f = FakeVesc()
    try:
        yield f
    finally:
        f.close(JOIN_TIMEOUT_S)
        assert not f.running, "fake VESC thread did not stop"
        assert f.thread_error is None


@pytest.fixture
def running(fake: FakeVesc) -> Iterator[Running]:
    r = Running(settings_for(fake.path))
    try:
        yield r
    finally:
        r.halt()


def test_fake_answers_a_plain_serial_port(fake: FakeVesc) -> None:
    """The fake on its own: pyserial on the symlink path, golden request, firmware timeout."""
    fake.timeout_s = 0.2
    with serial.Serial(fake.path, 115200, timeout=1.0) as port:
        port.write(encode_set_rpm(4614) + encode_set_servo_pos(0.5) + encode_get_values())
        head = port.read(2)
        assert head[0] == 0x02
        body = port.read(head[1] + 3)
        values = parse_values(body[:-3])
        assert values is not None and values.erpm == 4614.0 and values.firmware_timeout is False
        assert fake.wait_for(lambda f: f.firmware_timed_out, 2.0)  # no ALIVE: released
        assert fake.mode == "released"
        port.write(encode_get_values())
        head = port.read(2)
        values = parse_values(port.read(head[1] + 3)[:-3])
        assert values is not None and values.erpm == 0.0 and values.firmware_timeout is True
    assert fake.last_servo == 0.5 and fake.values_requests == 2


def test_known_answer_end_to_end(fake: FakeVesc, running: Running) -> None:
    """(a) 2.0 m/s, 0.1 rad -> the fake sees SET_RPM 9228 and SET_SERVO_POS 0.409."""
    running.command_for(0.3, 2.0, 0.1)
    assert fake.wait_for(lambda f: f.last_erpm is not None and f.last_servo is not None, 2.0)
    assert fake.last_erpm == 9228.0
    assert fake.last_servo == pytest.approx(0.409, abs=1e-9)
    assert fake.mode == "rpm"
    assert fake.events(CommandId.ALIVE)
    # the odometry comes back from the fake's replies (erpm = the commanded 9228)
    odo = [r.odometry for r in running.results if r.odometry is not None]
    assert odo and odo[-1].speed_mps == pytest.approx(2.0)
    assert odo[-1].steering_rad == pytest.approx(0.1, abs=1e-3)
    states = [r.state for r in running.results if r.state is not None]
    assert states[-1].values.v_in_v == pytest.approx(16.8) and states[-1].status == "ok"
    assert running.driver.decoder.counters.errors == 0


def test_brake_within_150_ms_of_last_command(fake: FakeVesc, running: Running) -> None:
    """(b) commands stop -> brake current frames reach the fake <= 150 ms after the last."""
    t_last = running.command_for(0.3, 1.0, 0.0)
    assert fake.wait_for(
        lambda f: len([e for e in f.events(CommandId.SET_CURRENT_BRAKE) if e.t_s > t_last]) >= 3,
        2.0,
    )
    after = [e for e in fake.events() if e.t_s > t_last]
    brakes = [e for e in after if e.command == CommandId.SET_CURRENT_BRAKE]
    first = brakes[0]
    # fake and driver share time.monotonic: a direct, honest comparison
    latency_s = first.t_s - t_last
    assert 0.1 - 0.002 <= latency_s <= 0.150, latency_s
    assert first.value == 20.0
    # after the first brake: brake held, no motor command and no ALIVE
    later = [e.command for e in after if e.t_s >= first.t_s]
    assert CommandId.SET_RPM not in later and CommandId.ALIVE not in later
    assert fake.mode == "brake" and not fake.firmware_timed_out


def test_driver_hang_lets_firmware_timeout_release(fake: FakeVesc) -> None:
    """A hung driver sends nothing, so the firmware timeout releases the motor."""
    fake.timeout_s = 0.2
    r = Running(settings_for(fake.path))
    try:
        r.command_for(0.2, 1.0, 0.0)
    finally:
        r.halt()  # the driver "hangs": no more frames at all
    assert fake.mode == "rpm"
    assert fake.wait_for(lambda f: f.firmware_timed_out, 2.0)
    assert fake.mode == "released"


def test_unplug_and_replug(fake: FakeVesc, running: Running) -> None:
    """(c) unplug -> disconnected, keeps running, reconnects; commands arrive again."""
    running.command_for(0.2, 1.0, 0.0)
    assert fake.wait_for(lambda f: f.last_erpm == 4614.0, 2.0)
    fake.unplug()
    assert not Path(fake.path).exists()
    t_unplug = time.monotonic()
    running.command_for(0.4, 1.0, 0.0)
    assert running.driver.link.state is LinkState.DISCONNECTED
    assert any(r.status == "disconnected" for r in running.results if r.stamp_s > t_unplug)
    link_counters = running.driver.link.counters
    assert link_counters.disconnects == 1 and link_counters.open_failures >= 1
    assert running.thread.is_alive()

    fake.clear_events()
    fake.replug()
    t_replug = running.command_for(0.4, 1.5, 0.0)
    assert fake.wait_for(lambda f: f.last_erpm == pytest.approx(6921.0), 2.0)
    assert running.driver.link.state is LinkState.CONNECTED
    assert link_counters.connects == 2
    assert fake.events(CommandId.SET_RPM)
    odo = [r.odometry for r in running.results if r.odometry is not None and r.stamp_s <= t_replug]
    assert odo and odo[-1].speed_mps == pytest.approx(1.5)
    assert running.errors == []


def test_port_that_appears_later(tmp_path: Path) -> None:
    """The port is missing at start: retried with back-off until the fake appears."""
    r = Running(settings_for(str(tmp_path / "vesc")))
    try:
        time.sleep(0.3)
        assert r.driver.link.state is LinkState.DISCONNECTED
        assert r.driver.link.counters.open_failures >= 2
        with FakeVesc(link_dir=tmp_path) as late:
            r.command_for(0.4, 1.0, 0.0)
            assert late.wait_for(lambda f: f.last_erpm == 4614.0, 2.0)
            assert r.driver.link.state is LinkState.CONNECTED
    finally:
        r.halt()


def test_garbage_on_the_line_is_counted_and_ignored(fake: FakeVesc, running: Running) -> None:
    """(d) garbage from the fake is counted by the driver's decoder; later replies parse."""
    running.command_for(0.2, 1.0, 0.0)
    dec = running.driver.decoder.counters
    assert fake.wait_for(lambda f: running.driver.counters.values_replies >= 3, 2.0)
    before_replies = running.driver.counters.values_replies
    before_garbage = dec.garbage_bytes
    noise = b"\xde\xad\xbe\xef" * 8
    bad_crc = bytearray(encode_frame(b"\x04" + bytes(20)))
    bad_crc[-2] ^= 0xFF
    fake.inject(noise)
    fake.inject(bytes(bad_crc))
    running.command_for(0.3, 1.0, 0.0)
    assert fake.wait_for(
        lambda f: running.driver.counters.values_replies >= before_replies + 5, 2.0
    )
    assert dec.garbage_bytes >= before_garbage + len(noise)
    assert dec.crc_errors >= 1 and dec.bad_start >= 1
    assert running.driver.counters.malformed_values == 0
    odo = [r.odometry for r in running.results if r.odometry is not None]
    assert odo[-1].speed_mps == pytest.approx(1.0)


@pytest.mark.parametrize("write_on_command", [True, False])
def test_the_driver_loop_writes_a_new_command_at_once_only_with_write_on_command(
    fake: FakeVesc, write_on_command: bool
) -> None:
    """The one serial loop (``VescDriver.loop``, also the service's): with a 1 Hz fixed
    rate a command reaches the wire long before the next fixed tick only when
    ``write_on_command`` is on; ``wake()`` ends a sleeping loop at once."""
    r = Running(settings_for(fake.path, command_rate_hz=1.0, write_on_command=write_on_command))
    try:
        assert fake.wait_for(lambda f: f.values_requests >= 1, 2.0)  # the first fixed tick
        time.sleep(0.05)
        t_cmd = r.driver.now()
        r.driver.on_command(1.0, 0.0, t_cmd)
        got = fake.wait_for(lambda f: f.last_erpm == 4614.0, 0.3)
        assert got is write_on_command
        if got:
            first = fake.events(CommandId.SET_RPM)[0]
            assert first.t_s - t_cmd < 0.1
    finally:
        t_stop = time.monotonic()
        r.stop.set()
        r.driver.wake()
        r.halt()
    assert time.monotonic() - t_stop < 0.5  # not the rest of a 1 s period
