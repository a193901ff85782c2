"""A small rate limiter for log and event lines (pure: the caller passes the time).

``RateLimiter(interval_s)`` lets one event through per ``interval_s`` seconds (the first at
once) and counts those it holds back, so the next line can say how many were suppressed::

    limit = RateLimiter(5.0)
    allowed, suppressed = limit.allow(now)
    if allowed:
        log.warning("port lost (%d more since the last report)", suppressed)

Not thread-safe; one thread (or the caller's lock) per limiter. For several kinds of events
use one limiter per kind (e.g. a ``dict[str, RateLimiter]``).
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
