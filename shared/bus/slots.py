"""Thread-safe hand-over between a Zenoh callback and a service's loop (no zenoh).

* ``LatestSlot``: the newest value; the writer never waits for a reader.
* ``DropOldestQueue``: a bounded FIFO whose put on a full queue drops the oldest item.
"""

from __future__ import annotations

import collections
import threading
from typing import Generic, TypeVar

T = TypeVar("T")


class LatestSlot(Generic[T]):
    """A thread-safe slot holding the newest value; readers never block the writer."""

    def __init__(self) -> None:
        self._cond = threading.Condition()
        self._value: T | None = None
        self._fresh = False
        self.overwritten = 0  #: values replaced before anyone took them

    def put(self, value: T) -> None:
        """Store `value` as the newest (called from the Zenoh thread)."""
        with self._cond:
            if self._fresh:
                self.overwritten += 1
            self._value, self._fresh = value, True
            self._cond.notify_all()

    def peek(self) -> T | None:
        """The newest value (taken or not), None if nothing arrived yet."""
        with self._cond:
            return self._value

    def take(self) -> T | None:
        """The newest value if it was not taken yet (marks it taken), else None."""
        with self._cond:
            if not self._fresh:
                return None
            self._fresh = False
            return self._value

    def wait(self, timeout_s: float) -> T | None:
        """Wait up to `timeout_s` [s] for a value not yet taken, take and return it."""
        with self._cond:
            if not self._cond.wait_for(lambda: self._fresh, timeout=max(0.0, timeout_s)):
                return None
            self._fresh = False
            return self._value


class DropOldestQueue(Generic[T]):
    """A bounded thread-safe FIFO: a put on a full queue drops the oldest item."""

    def __init__(self, maxlen: int) -> None:
        if maxlen < 1:
            raise ValueError("maxlen must be >= 1")
        self._cond = threading.Condition()
        self._items: collections.deque[T] = collections.deque(maxlen=maxlen)
        self.dropped = 0  #: items dropped because the queue was full

    def put(self, item: T) -> bool:
        """Append `item`, dropping the oldest one if full; True when one was dropped."""
        with self._cond:
            full = len(self._items) == self._items.maxlen
            if full:
                self.dropped += 1
            self._items.append(item)
            self._cond.notify_all()
        return full

    def get(self, timeout_s: float = 0.0) -> T | None:
        """The oldest item, waiting up to `timeout_s` [s]; None if still empty."""
        with self._cond:
            if not self._cond.wait_for(lambda: bool(self._items), timeout=max(0.0, timeout_s)):
                return None
            return self._items.popleft()

    def drain(self) -> list[T]:
        """Every queued item, oldest first (the queue is left empty)."""
        with self._cond:
            items = list(self._items)
            self._items.clear()
            return items

    def __len__(self) -> int:
        with self._cond:
            return len(self._items)
