"""The pure command watchdog."""

from __future__ import annotations

import pytest

from services.vesc_driver.watchdog import CommandWatchdog, WatchdogState


def test_states_and_expiry_count() -> None:
    wd = CommandWatchdog(0.1)
    assert wd.state(0.0) is WatchdogState.NO_COMMAND and wd.deadline() is None
    wd.feed(1.0)
    assert wd.is_fresh(1.0) and wd.is_fresh(1.099)
    assert wd.deadline() == pytest.approx(1.1)
    assert wd.state(1.1) is WatchdogState.EXPIRED
    assert wd.state(5.0) is WatchdogState.EXPIRED
    assert wd.expiries == 1  # counted once per expiry
    wd.feed(5.0)
    assert wd.state(5.05) is WatchdogState.FRESH
    assert wd.state(5.2) is WatchdogState.EXPIRED and wd.expiries == 2


def test_rejects_bad_timeout() -> None:
    for bad in (0.0, -1.0, float("nan")):
        with pytest.raises(ValueError):
            CommandWatchdog(bad)
