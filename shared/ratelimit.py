"""A small rate limiter for log and event lines (pure: the caller passes the time).

``RateLimiter(interval_s)`` lets one event through per ``interval_s`` seconds (the first at
once) and counts those it holds back, so the next line can say how many were suppressed::

    limit = RateLimiter(5.0)
    allowed, suppressed = limit.allow(now)
    if allowed:
        log.warning("port lost (%d more since the last report)", suppressed)

Not thread-safe; one thread (or the caller's lock) per limiter. For several kinds of events
use one limiter per kind (e.g. a ``dict[str, RateLimiter]``; ``shared.service.Service.say``
keeps one per kind). Built on it: ``EpisodeLimiter`` (start/end pairs such as a port lost and
back) and ``GrowthLimiter`` (a growing total reported at most once per interval).
"""

from __future__ import annotations

import math


class RateLimiter:
    """At most one event per ``interval_s`` [s]; counts the events it suppressed.

    Attributes:
        interval_s: shortest time [s] between two allowed events (0: every event allowed).
        last_s: time [s] of the last allowed event (-inf before the first).
        suppressed: events suppressed since the last allowed one.
    """

    def __init__(self, interval_s: float) -> None:
        """Create a limiter; ``interval_s`` [s] must be finite and >= 0."""
        if not (math.isfinite(interval_s) and interval_s >= 0.0):
            raise ValueError(f"interval_s must be finite and >= 0, got {interval_s!r}")
        self.interval_s = interval_s
        self.last_s = -math.inf
        self.suppressed = 0

    def allow(self, now: float) -> tuple[bool, int]:
        """One event at ``now`` [s]: ``(allowed, suppressed before it)``.

        Allowed when ``interval_s`` has passed since the last allowed event; the count of the
        events suppressed since then is returned and reset. Otherwise ``(False, 0)`` and the
        event is counted as suppressed.
        """
        if now - self.last_s >= self.interval_s:
            self.last_s = now
            n, self.suppressed = self.suppressed, 0
            return True, n
        self.suppressed += 1
        return False, 0

    def ready(self, now: float) -> bool:
        """Whether an event at ``now`` [s] would be allowed (changes nothing)."""
        return now - self.last_s >= self.interval_s


class EpisodeLimiter:
    """Rate limit of start/end event pairs (a port lost / back, braking / resumed).

    A start is reported when ``interval_s`` [s] passed since the last reported start (a
    ``RateLimiter``), else it is suppressed and counted; its end is reported only if its
    start was, so the last reported line always tells the current state.
    """

    def __init__(self, interval_s: float) -> None:
        """Create the limiter; ``interval_s`` [s] between two reported starts."""
        self._limit = RateLimiter(interval_s)
        self._open_reported = False

    @property
    def suppressed(self) -> int:
        """Starts suppressed since the last reported one."""
        return self._limit.suppressed

    def start(self, now: float) -> int | None:
        """A start at ``now`` [s]: the number of suppressed starts before it if it is to be
        reported (they are then cleared), or None when this one is suppressed."""
        allowed, suppressed = self._limit.allow(now)
        self._open_reported = allowed
        return suppressed if allowed else None

    def end(self) -> bool:
        """The matching end: True if it is to be reported."""
        reported, self._open_reported = self._open_reported, False
        return reported


class GrowthLimiter:
    """Reports a growing total at most every ``interval_s`` [s] (the first growth at once)."""

    def __init__(self, interval_s: float) -> None:
        """Create the limiter; ``interval_s`` [s] between two reports (a ``RateLimiter``)."""
        self._limit = RateLimiter(interval_s)
        self.reported = 0  #: the total of the last report

    def check(self, total: int, now: float) -> bool:
        """True when ``total`` grew since the last report and the interval has passed."""
        if total > self.reported and self._limit.ready(now):
            self._limit.allow(now)
            self.reported = total
            return True
        return False
