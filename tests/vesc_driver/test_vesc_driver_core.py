"""The driver core without threads: a scripted port, a manual clock, explicit ticks."""

from __future__ import annotations

import math
from typing import Any

import pytest

from services.vesc_driver.driver import TickResult, VescDriver
from services.vesc_driver.serial_link import LinkState, SerialLink
from services.vesc_driver.watchdog import WatchdogState
from shared.config.vesc import VescSettings
from shared.vesc.decoder import FrameDecoder
from shared.vesc.fake import DEFAULT_VALUES
from shared.vesc.protocol import CommandId, decode_command_value, encode_frame
from shared.vesc.values import encode_values_payload


def make_driver(clock: Any, factory: Any, **overrides: Any) -> VescDriver:
    s = VescSettings(port="/dev/fake", **overrides)
    link = SerialLink(
        s.port,
        backoff_initial_s=s.reconnect_backoff_initial_s,
        backoff_max_s=s.reconnect_backoff_max_s,
        clock=clock,
        serial_factory=factory,
    )
    return VescDriver(s, link, clock=clock)


def sent(result: TickResult) -> list[tuple[int, float | None]]:
    dec = FrameDecoder()
    frames = dec.feed(b"".join(result.frames_written))
    assert dec.counters.errors == 0
    return [(f.command_id, decode_command_value(f.payload)) for f in frames]


def reply(**changes: Any) -> bytes:
    from dataclasses import replace

    return encode_frame(encode_values_payload(replace(DEFAULT_VALUES, **changes)))


def test_known_answer_frames(clock: Any, factory: Any) -> None:
    drv = make_driver(clock, factory)
    drv.on_command(2.0, 0.1, clock())
    r = drv.tick(clock())
    cmds = sent(r)
    assert cmds[0] == (CommandId.SET_RPM, 9228.0)
    assert cmds[1] == (CommandId.SET_SERVO_POS, pytest.approx(0.409))
    assert [c for c, _ in cmds[2:]] == [CommandId.ALIVE, CommandId.GET_VALUES]
    assert not r.braking and r.watchdog is WatchdogState.FRESH and r.link is LinkState.CONNECTED
    assert factory.current.tx == [b"".join(r.frames_written)]  # one write per tick


def test_no_command_brakes_without_alive(clock: Any, factory: Any) -> None:
    drv = make_driver(clock, factory)
    r = drv.tick(clock())
    assert r.braking and r.watchdog is WatchdogState.NO_COMMAND
    assert [c for c, _ in sent(r)] == [CommandId.SET_CURRENT_BRAKE, CommandId.GET_VALUES]
    assert sent(r)[0][1] == 20.0


def test_timeout_brakes_and_holds(clock: Any, factory: Any) -> None:
    drv = make_driver(clock, factory, poll_values_rate_hz=0.0)
    t0 = clock()
    drv.on_command(1.0, 0.0, t0)
    assert [c for c, _ in sent(drv.tick(clock.advance(0.05)))] == [
        CommandId.SET_RPM,
        CommandId.SET_SERVO_POS,
        CommandId.ALIVE,
    ]
    for _ in range(10):  # from t0 + 0.1 on: brake only, every tick
        r = drv.tick(clock.advance(0.05))
        if clock() - t0 >= 0.1:
            assert r.braking and r.watchdog is WatchdogState.EXPIRED
            assert sent(r) == [(CommandId.SET_CURRENT_BRAKE, 20.0)]
    assert drv.watchdog.expiries == 1
    drv.on_command(1.0, 0.0, clock())  # a new command releases the brake
    assert sent(drv.tick(clock()))[0][0] == CommandId.SET_RPM


def test_invalid_commands_counted(clock: Any, factory: Any) -> None:
    drv = make_driver(clock, factory, poll_values_rate_hz=0.0)
    drv.on_command(math.nan, 0.1, clock())
    r = drv.tick(clock())
    assert r.braking and [c for c, _ in sent(r)] == [
        CommandId.SET_CURRENT_BRAKE,
        CommandId.SET_SERVO_POS,
        CommandId.ALIVE,
    ]
    drv.on_command(50.0, 0.0, clock())
    assert sent(drv.tick(clock()))[0] == (CommandId.SET_RPM, 23250.0)
    assert drv.counters.nonfinite_commands == 1 and drv.counters.out_of_range_commands == 1


def test_poll_rate(clock: Any, factory: Any) -> None:
    drv = make_driver(clock, factory, poll_values_rate_hz=10.0)
    polls = 0
    for _ in range(50):  # 1 s of 50 Hz ticks
        polls += [c for c, _ in sent(drv.tick(clock.advance(0.02)))].count(CommandId.GET_VALUES)
    assert 9 <= polls <= 11


def test_values_state_and_odometry(clock: Any, factory: Any) -> None:
    drv = make_driver(clock, factory)
    drv.on_command(2.0, 0.1, clock())
    r = drv.tick(clock())
    assert r.state is None and r.odometry is None and r.status == "stale"
    factory.current.rx += reply(erpm=9228.0)
    r = drv.tick(clock.advance(0.02))
    assert r.state is not None and r.state.status == "ok" and r.status == "ok"
    assert r.state.values.v_in_v == pytest.approx(16.8)
    odo = r.odometry
    assert odo is not None and odo.stamp_s == clock()
    assert odo.speed_mps == pytest.approx(2.0)
    assert odo.steering_rad == pytest.approx((0.409 - 0.5304) / -1.2135, abs=1e-3)
    assert odo.yaw_rate_radps == pytest.approx(2.0 * math.tan(odo.steering_rad) / 0.324)
    assert drv.tick(clock.advance(0.02)).state is None  # each reply reported once
    factory.current.rx += reply(fault_code=4)
    assert drv.tick(clock.advance(0.02)).status == "fault"
    clock.advance(1.0)
    assert drv.tick(clock()).status == "stale"


def test_malformed_garbage_and_other_frames(clock: Any, factory: Any) -> None:
    drv = make_driver(clock, factory)
    drv.tick(clock())
    port = factory.current
    port.rx += b"\xaa\xbb" + encode_frame(b"\x04\x01") + encode_frame(b"\x1e") + reply(erpm=-4614.0)
    r = drv.tick(clock.advance(0.02))
    assert drv.counters.malformed_values == 1 and drv.counters.other_frames == 1
    assert drv.decoder.counters.garbage_bytes == 2
    diag = drv.diagnostics()
    assert diag["driver.malformed_values"] == 1 and diag["decoder.garbage_bytes"] == 2
    assert diag["link.connects"] == 1 and diag["watchdog.expiries"] == 0
    assert r.odometry is not None and r.odometry.speed_mps == pytest.approx(-1.0)


def test_reported_speed_sign(clock: Any, factory: Any) -> None:
    drv = make_driver(clock, factory, speed_sign=-1)
    drv.tick(clock())
    factory.current.rx += reply(erpm=-9228.0)
    odo = drv.tick(clock.advance(0.02)).odometry
    assert odo is not None and odo.speed_mps == pytest.approx(2.0)


def test_disconnect_and_reconnect(clock: Any, factory: Any) -> None:
    drv = make_driver(clock, factory)
    drv.tick(clock())
    first = factory.current
    first.rx += reply()[:10]  # half a frame, then the cable is pulled
    first.fail_write = True
    factory.present = False
    r = drv.tick(clock.advance(0.02))
    assert r.link is LinkState.DISCONNECTED and r.status == "disconnected"
    assert r.frames_written == () and drv.counters.write_failures == 1
    for _ in range(20):
        drv.on_command(1.0, 0.0, clock())
        r = drv.tick(clock.advance(0.02))
        assert r.frames_written == ()
    factory.present = True
    clock.advance(3.0)
    drv.on_command(1.0, 0.0, clock())
    r = drv.tick(clock())
    assert r.link is LinkState.CONNECTED and sent(r)[0] == (CommandId.SET_RPM, 4614.0)
    assert drv.decoder.buffered == 0  # the half frame of the old port was dropped
    factory.current.rx += reply(erpm=4614.0)
    assert drv.tick(clock.advance(0.02)).odometry is not None
