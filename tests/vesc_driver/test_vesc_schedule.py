"""The serial loop's schedule (pure): fixed ticks, watchdog expiry, command-triggered ticks."""

from __future__ import annotations

import pytest

from services.vesc_driver.schedule import (
    MIN_COMMAND_WRITE_GAP_S,
    NOT_DUE,
    TickReason,
    TickScheduler,
)


def test_fixed_rate_ticks_and_no_burst_after_a_stall() -> None:
    s = TickScheduler(0.02, 10.0)
    assert s.due(10.0, None, False) is TickReason.SCHEDULED
    s.ticked(10.0, TickReason.SCHEDULED)
    assert s.next_tick_s == pytest.approx(10.02)
    assert s.due(10.01, None, False) == NOT_DUE and not s.due(10.01, None, False)
    assert s.wake_at(None, False) == pytest.approx(10.02)
    # a stall of 0.1 s: one tick, then the phase restarts from now (no burst of 5)
    assert s.due(10.12, None, False) is TickReason.SCHEDULED
    s.ticked(10.12, TickReason.SCHEDULED)
    assert s.next_tick_s == pytest.approx(10.14)
    assert not s.due(10.13, None, False)


def test_expiry_tick_once_at_the_deadline() -> None:
    s = TickScheduler(0.02, 0.0)
    s.ticked(0.0, s.due(0.0, None, False))
    deadline = 0.015
    assert s.wake_at(deadline, False) == deadline  # earlier than the next fixed tick
    assert not s.due(0.014, deadline, False)
    assert s.due(0.015, deadline, False) is TickReason.EXPIRY
    s.ticked(0.015, TickReason.EXPIRY)
    assert s.next_tick_s == pytest.approx(0.02)  # the fixed phase is kept
    assert not s.due(0.016, deadline, False)  # only once per deadline
    assert s.wake_at(deadline, False) == pytest.approx(0.02)


def test_command_ticks_only_with_write_on_command_and_gap() -> None:
    off = TickScheduler(0.02, 0.0)
    off.ticked(0.0, off.due(0.0, None, False))
    assert not off.due(0.001, None, True)  # waits for the fixed tick
    assert off.wake_at(None, True) == pytest.approx(0.02)

    on = TickScheduler(0.02, 0.0, write_on_command=True)
    on.ticked(0.0, on.due(0.0, None, False))
    assert on.due(0.001, None, True) is TickReason.COMMAND
    on.ticked(0.001, TickReason.COMMAND)
    assert on.next_tick_s == pytest.approx(0.02)  # fixed phase untouched
    # the next command within the gap waits for the gap, not the fixed tick
    assert not on.due(0.002, None, True)
    assert on.wake_at(None, True) == pytest.approx(0.001 + MIN_COMMAND_WRITE_GAP_S)
    assert on.due(0.001 + MIN_COMMAND_WRITE_GAP_S, None, True) is TickReason.COMMAND
    assert not on.due(0.003, None, False)  # nothing pending: nothing due


def test_reasons_combine_and_a_fixed_tick_does_not_use_up_the_command_gap() -> None:
    s = TickScheduler(0.02, 0.0, write_on_command=True)
    reason = s.due(0.0, 0.0, True)
    assert reason == TickReason.SCHEDULED | TickReason.EXPIRY | TickReason.COMMAND
    s.ticked(0.0, reason)
    assert s.last_command_tick_s == float("-inf")
    assert s.due(0.001, None, True) is TickReason.COMMAND


def test_period_must_be_positive() -> None:
    for bad in (0.0, -1.0, float("nan")):
        with pytest.raises(ValueError):
            TickScheduler(bad, 0.0)
