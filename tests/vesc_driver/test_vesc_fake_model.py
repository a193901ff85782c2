"""The fake VESC's device model without a pty: bytes in, motor state and replies out."""

from __future__ import annotations

from dataclasses import replace

import pytest

from shared.vesc.decoder import FrameDecoder
from shared.vesc.fake import (
    DEFAULT_VALUES,
    FakeMotorState,
    FakeVescModel,
    default_reply_values,
)
from shared.vesc.protocol import (
    CommandId,
    encode_alive,
    encode_get_values,
    encode_set_current_brake,
    encode_set_rpm,
    encode_set_servo_pos,
)
from shared.vesc.values import VescValues, parse_values


def replies(data: bytes) -> list[VescValues | None]:
    return [parse_values(f.payload) for f in FrameDecoder().feed(data)]


def test_commands_set_the_motor_state_and_get_values_is_answered() -> None:
    m = FakeVescModel()
    wire = encode_set_rpm(9228) + encode_set_servo_pos(0.409) + encode_alive()
    out = m.feed(wire[:5], 1.0) + m.feed(wire[5:] + encode_get_values(), 1.0)  # any chunking
    st = m.state
    assert (st.mode, st.last_erpm, st.last_erpm_s, st.last_servo) == ("rpm", 9228.0, 1.0, 0.409)
    assert st.last_alive_s == 1.0 and not st.firmware_timed_out
    (values,) = replies(out)
    assert values is not None and values.erpm == 9228.0 and values.v_in_v == pytest.approx(16.8)
    assert [e.command for e in m.events()] == [
        CommandId.SET_RPM,
        CommandId.SET_SERVO_POS,
        CommandId.ALIVE,
        CommandId.GET_VALUES,
    ]
    assert m.values_requests == 1 and m.replies_sent == 1


def test_each_reply_reflects_the_frames_before_its_request() -> None:
    m = FakeVescModel()
    out = m.feed(
        encode_set_rpm(4614)
        + encode_get_values()
        + encode_set_current_brake(20.0)
        + encode_get_values(),
        0.0,
    )
    first, second = replies(out)
    assert first is not None and first.erpm == 4614.0 and first.avg_motor_current_a == 0.0
    assert second is not None and second.erpm == 0.0 and second.avg_motor_current_a == -20.0


def test_firmware_timeout_releases_and_servo_does_not_reset_it() -> None:
    m = FakeVescModel(timeout_s=0.2)
    m.feed(encode_set_rpm(1000), 0.0)
    m.feed(encode_set_servo_pos(0.5), 0.15)  # does not count
    assert not m.check_timeout(0.2)
    assert m.check_timeout(0.21) and m.state.mode == "released"
    assert not m.check_timeout(0.3)  # once
    (values,) = replies(m.feed(encode_get_values(), 0.3))
    assert values is not None and values.firmware_timeout is True and values.erpm == 0.0
    m.feed(encode_alive(), 0.4)
    assert not m.state.firmware_timed_out and m.state.firmware_timeouts == 1


def test_reply_hook_replaces_the_reply_and_sees_the_state() -> None:
    seen: list[FakeMotorState] = []

    def hook(state: FakeMotorState, reply: VescValues) -> VescValues:
        seen.append(state)
        return replace(reply, erpm=1234.0)

    m = FakeVescModel(reply_values=hook, reply_length=30)
    m.feed(encode_set_rpm(9228), 0.0)
    (values,) = replies(m.feed(encode_get_values(), 0.0))
    assert values is not None and values.erpm == 1234.0
    assert values.v_in_v == pytest.approx(16.8) and values.amp_hours is None  # 30 bytes
    assert seen and seen[-1].last_erpm == 9228.0


def test_replies_disabled_and_event_limit() -> None:
    m = FakeVescModel(max_events=0)
    m.replies_enabled = False
    assert m.feed(encode_get_values() + encode_alive(), 0.0) == b""
    assert m.values_requests == 1 and m.replies_sent == 0 and m.events() == []


def test_default_reply_values_sets_only_the_live_fields() -> None:
    st = FakeMotorState(mode="brake", last_brake_a=12.5, firmware_timed_out=True)
    v = default_reply_values(replace(DEFAULT_VALUES, status_flags=0x02), st)
    assert v.erpm == 0.0 and v.avg_motor_current_a == -12.5 and v.status_flags == 0x03
    assert replace(v, erpm=0.0, avg_motor_current_a=0.0, status_flags=0) == DEFAULT_VALUES
