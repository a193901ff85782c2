"""The bus's counts (no zenoh): drops and own faults per (key, reason), channel stats, seq gaps.

* ``DropCounter``: payloads dropped per (key, reason), thread-safe, logged once per burst
  (the first one at once, then one summary line at most every ``summary_interval_s``).
* ``FaultCounter``: a service's own faults per (key, reason) (records it built that failed
  validation; nothing invalid is sent), the same logging at error level; ``guard(key)``
  turns a ``MessageError`` raised in a block into one count.
* ``ChannelStats``: the counts of one ``ChannelSubscription``, which add up.
* ``SeqTracker``: records missed per key according to the sequence numbers.
"""

from __future__ import annotations

import collections
import contextlib
import logging
import threading
import time
from collections.abc import Callable, Iterator
from typing import Any, NamedTuple

from shared.messages import MessageError

log = logging.getLogger("racestack.bus")

#: Default interval between two summary log lines of one (key, reason) burst [s].
DROP_SUMMARY_INTERVAL_S = 5.0


class DropCounter:
    """Thread-safe count of dropped payloads per (key, reason), with rate-limited logging.

    The first drop of a (key, reason) pair is logged at once; later ones are summed and
    logged as one summary line at most every ``summary_interval_s`` seconds (when the
    next drop arrives after the interval, or on ``flush``).
    """

    #: Log line of the first event of a (key, reason) pair: key, reason, detail, interval [s].
    FIRST_LINE = (
        "dropped a message on %s: %s (%s); more of these are summarised at most every %.0f s"
    )
    #: Summary line: count, key, reason, seconds since the last line, latest detail.
    SUMMARY_LINE = "dropped %d more messages on %s: %s in the last %.1f s (latest: %s)"
    #: Level of both lines.
    LEVEL = logging.WARNING

    def __init__(
        self,
        *,
        summary_interval_s: float = DROP_SUMMARY_INTERVAL_S,
        logger: logging.Logger | None = None,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        self._interval = summary_interval_s
        self._log = logger or log
        self._clock = clock
        self._lock = threading.Lock()
        self._counts: collections.Counter[tuple[str, str]] = collections.Counter()
        # (key, reason) -> [time of the last log line, drops since then, latest detail]
        self._pending: dict[tuple[str, str], list[Any]] = {}

    def record(self, key: str, reason: str, detail: str = "") -> None:
        """Count one dropped payload on `key` for `reason` (and maybe log it)."""
        now = self._clock()
        line: tuple[str, tuple[Any, ...]] | None = None
        with self._lock:
            kr = (key, reason)
            self._counts[kr] += 1
            state = self._pending.get(kr)
            if state is None:
                self._pending[kr] = [now, 0, detail]
                line = (self.FIRST_LINE, (key, reason, detail, self._interval))
            else:
                state[1] += 1
                state[2] = detail
                if now - state[0] >= self._interval:
                    line = self._summary(kr, state, now)
        if line is not None:
            self._log.log(self.LEVEL, line[0], *line[1])

    def _summary(
        self, kr: tuple[str, str], state: list[Any], now: float
    ) -> tuple[str, tuple[Any, ...]]:
        args = (state[1], kr[0], kr[1], now - state[0], state[2])
        state[0], state[1] = now, 0
        return self.SUMMARY_LINE, args

    def flush(self) -> None:
        """Log the summary of every burst not yet reported (call at shutdown)."""
        now = self._clock()
        with self._lock:
            lines = [self._summary(kr, st, now) for kr, st in self._pending.items() if st[1]]
        for text, args in lines:
            self._log.log(self.LEVEL, text, *args)

    def count(self, key: str | None = None, reason: str | None = None) -> int:
        """Drops so far, filtered by key and/or reason (None: any)."""
        with self._lock:
            return sum(
                n
                for (k, r), n in self._counts.items()
                if (key is None or k == key) and (reason is None or r == reason)
            )

    @property
    def total(self) -> int:
        """All drops so far."""
        return self.count()

    def snapshot(self) -> dict[tuple[str, str], int]:
        """A copy of the counts: (key, reason) -> drops (for telemetry and tests)."""
        with self._lock:
            return dict(self._counts)


class FaultCounter(DropCounter):
    """A service's OWN faults per (key, reason), with the rate-limited logging of
    ``DropCounter`` (at error level).

    What it counts: records the service built that failed validation (``MessageError``; the
    reason is the error's, the key the one it was meant for; nothing invalid is ever sent),
    and other faults a service recovers from by itself (e.g. the simulator's car state
    leaving the contract, under a key of its choosing). ``DropReporter`` publishes its growth
    on ``events/log``.
    """

    FIRST_LINE = (
        "own fault on %s: %s (%s); nothing invalid was published and the service goes on; "
        "more of these are summarised at most every %.0f s"
    )
    SUMMARY_LINE = "%d more own faults on %s: %s in the last %.1f s (latest: %s)"
    LEVEL = logging.ERROR

    @contextlib.contextmanager
    def guard(self, key: str) -> Iterator[None]:
        """Count a ``MessageError`` raised in the block as a fault on `key` instead of
        letting it end the caller (the rest of the block is skipped)::

            with bus.faults.guard(bus.keys.state):
                state_pub.put(assemble_state(...))  # an invalid State: counted, not sent
        """
        try:
            yield
        except MessageError as exc:
            self.record(key, exc.reason, exc.detail)


class ChannelStats(NamedTuple):
    """The counts of one ``ChannelSubscription`` (a consistent snapshot).

    ``received == valid + rejected + dropped + pending`` always holds (``pending`` is 0
    once the consumer has taken everything).

    Attributes:
        received: samples that arrived on the key (every one, garbage included).
        valid: records handed to the consumer by ``recv`` / ``try_recv``.
        rejected: samples that failed decoding or validation (never entered the channel).
        dropped: valid records the consumer never got: ``overwritten + stale``.
        pending: valid records waiting in the channel now.
        overwritten: valid records pushed out of the full channel by a newer valid one.
        stale: valid records older than the channel's ``max_age_s`` when taken.
    """

    received: int
    valid: int
    rejected: int
    dropped: int
    pending: int
    overwritten: int
    stale: int


class SeqTracker:
    """The last sequence number seen per key, to count the records missed in between.

    One publisher per key is assumed: a sequence number at or below the last one (the
    publisher restarted) counts no gap and starts over from there. Not thread-safe: one
    caller (a subscription's Zenoh callback, or a channel's consumer).
    """

    def __init__(self) -> None:
        self._last: dict[str, int] = {}

    def gap(self, key: str, seq: int) -> int:
        """Records missed on `key` before the one numbered `seq` (and remember `seq`)."""
        last = self._last.get(key)
        self._last[key] = seq
        if last is not None and seq > last + 1:
            return seq - last - 1
        return 0
