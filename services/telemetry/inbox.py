"""The hand-over between Zenoh's callback threads and the one thread that logs to Rerun.

``Inbox.put`` runs on a Zenoh thread: it only appends under a lock and returns (it never
waits for the logging thread). Data messages go to a bounded FIFO that drops the OLDEST
message when full and counts the drop per key (and, with ``max_age_s``, drops data that
waited longer than that: a logging thread that fell behind catches up instead of lagging);
lap, log and simulator-control events go to a
separate FIFO that is never trimmed by that policy (only a safety cap far above any real
event rate protects the memory; overflowing it is counted too). ``get_batch`` returns the
messages of both in arrival order.
"""

from __future__ import annotations

import collections
import heapq
import itertools
import threading
import time
from collections.abc import Callable
from typing import NamedTuple

from shared.keys import EVENTS_LOG, LAP, SIM_CONTROL, TELEPORT
from shared.messages import Message

#: Keys whose messages are events (never dropped by the queue policy).
EVENT_SUFFIXES: frozenset[str] = frozenset({LAP, EVENTS_LOG, SIM_CONTROL, TELEPORT})


class Item(NamedTuple):
    """One received message: arrival index, key suffix, record, arrival wall time [s]."""

    order: int
    suffix: str
    msg: Message
    recv_wall_s: float


class Inbox:
    """Two FIFOs (data: bounded, drop-oldest; events: effectively unbounded).

    Args:
        maxlen: capacity of the data FIFO [messages].
        event_max: safety cap of the event FIFO [messages].
        event_suffixes: key suffixes treated as events.
        clock: wall clock [s] used to stamp arrivals.
        max_age_s: data messages older than this at ``get_batch`` are dropped and counted
            (None: never by age).
    """

    def __init__(
        self,
        maxlen: int,
        event_max: int = 100_000,
        event_suffixes: frozenset[str] = EVENT_SUFFIXES,
        clock: Callable[[], float] = time.time,
        max_age_s: float | None = None,
    ) -> None:
        if maxlen < 1 or event_max < 1:
            raise ValueError("queue sizes must be >= 1")
        if max_age_s is not None and max_age_s <= 0.0:
            raise ValueError("max_age_s must be > 0")
        self._max_age_s = max_age_s
        self._cond = threading.Condition()
        self._data: collections.deque[Item] = collections.deque()
        self._events: collections.deque[Item] = collections.deque()
        self._maxlen = maxlen
        self._event_max = event_max
        self._event_suffixes = event_suffixes
        self._clock = clock
        self._counter = itertools.count()
        self._dropped: collections.Counter[str] = collections.Counter()
        self._received: collections.Counter[str] = collections.Counter()

    def put(self, suffix: str, msg: Message) -> None:
        """Enqueue `msg` received on key `suffix` (called on a Zenoh thread; never blocks)."""
        now = self._clock()
        with self._cond:
            item = Item(next(self._counter), suffix, msg, now)
            self._received[suffix] += 1
            if suffix in self._event_suffixes:
                if len(self._events) >= self._event_max:
                    old = self._events.popleft()
                    self._dropped[old.suffix] += 1
                self._events.append(item)
            else:
                if len(self._data) >= self._maxlen:
                    old = self._data.popleft()
                    self._dropped[old.suffix] += 1
                self._data.append(item)
            self._cond.notify()

    def get_batch(self, timeout_s: float, max_items: int = 512) -> list[Item]:
        """Every queued event and up to `max_items` data messages, in arrival order.

        Waits up to `timeout_s` [s] when both FIFOs are empty; returns [] on timeout.
        """
        with self._cond:
            if not self._data and not self._events:
                self._cond.wait(timeout=max(0.0, timeout_s))
            events = list(self._events)
            self._events.clear()
            if self._max_age_s is not None and self._data:
                oldest = self._clock() - self._max_age_s
                while self._data and self._data[0].recv_wall_s < oldest:
                    self._dropped[self._data.popleft().suffix] += 1
            n = min(max_items, len(self._data))
            data = [self._data.popleft() for _ in range(n)]
        if not events:
            return data
        if not data:
            return events
        return list(heapq.merge(events, data))

    def drain(self) -> list[Item]:
        """Everything queued, in arrival order (the inbox is left empty)."""
        out: list[Item] = []
        while True:
            batch = self.get_batch(0.0, max_items=1 << 30)
            if not batch:
                return out
            out.extend(batch)

    def dropped(self) -> dict[str, int]:
        """Messages dropped by the queue policy so far, per key suffix."""
        with self._cond:
            return dict(self._dropped)

    def received(self) -> dict[str, int]:
        """Messages handed to the inbox so far, per key suffix."""
        with self._cond:
            return dict(self._received)

    def __len__(self) -> int:
        with self._cond:
            return len(self._data) + len(self._events)
