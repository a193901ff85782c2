"""``shared.ratelimit.RateLimiter``, the one rate limiter of the VESC service's events."""

from __future__ import annotations

import math

import pytest

from shared.ratelimit import RateLimiter


def test_first_event_at_once_then_one_per_interval_with_the_suppressed_count() -> None:
    lim = RateLimiter(1.0)
    assert lim.ready(0.0)
    assert lim.allow(0.0) == (True, 0)
    assert not lim.ready(0.5)
    assert lim.allow(0.5) == (False, 0)
    assert lim.allow(0.9) == (False, 0)
    assert lim.suppressed == 2
    assert lim.allow(1.0) == (True, 2)  # exactly one interval later: allowed
    assert lim.suppressed == 0 and lim.last_s == 1.0
    assert lim.allow(2.5) == (True, 0)


def test_zero_interval_allows_everything_and_bad_intervals_raise() -> None:
    lim = RateLimiter(0.0)
    assert all(lim.allow(0.0)[0] for _ in range(3))
    for bad in (-1.0, math.nan, math.inf):
        with pytest.raises(ValueError):
            RateLimiter(bad)
