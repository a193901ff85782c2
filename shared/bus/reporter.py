"""The drop reporter (no zenoh): a service's drop and own-fault counts on ``events/log``.

``DropReporter`` reads the counters of any bus that has them (``ReportedBus``: the session's
``Bus`` or the in-process ``FakeBus``) and publishes their growth as ``LogEvent`` records
through a ``TypedPublisher``.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import Any, Protocol, TypeVar

from shared.bus.counters import DropCounter, FaultCounter
from shared.bus.pubsub import TypedPublisher
from shared.keys import Keys
from shared.messages import LogEvent, LogLevelName, Message

M = TypeVar("M", bound=Message)


class ReportedBus(Protocol):
    """What ``DropReporter`` needs of a bus (``shared.bus.session.Bus``, ``FakeBus``).

    A ``displaced`` ``DropCounter`` (valid records a subscription dropped) is reported too
    when the bus has one.
    """

    @property
    def keys(self) -> Keys:
        """The car's keys (``events_log``)."""
        ...

    @property
    def drops(self) -> DropCounter:
        """Invalid payloads received, per (key, reason)."""
        ...

    @property
    def faults(self) -> FaultCounter:
        """The service's own faults, per (key, reason)."""
        ...

    def publisher(self, key: str, msg_type: type[M]) -> TypedPublisher[M]:
        """A typed publisher on `key`."""
        ...


class DropReporter:
    """Publishes a service's rejected-message and own-fault counts on ``events/log``.

    Call ``poll()`` from the service's loop; at most once per ``period_s`` it compares the
    bus's ``DropCounter`` and ``FaultCounter`` with the last report and publishes, for each
    that grew, one ``LogEvent``: a warning such as ``rejected 3 messages (total 7):
    racestack/car0/state not_msgpack x3`` for invalid payloads received, an error such as
    ``own faults: 2 (total 2), not published: racestack/car0/sim/truth out_of_range x2``
    for records of its own that failed validation (and other faults it recovered from), and
    ``dropped 5 valid messages (total 9): racestack/car0/vehicle/pose overwritten x5`` for
    valid records a channel subscription never handed to its consumer (``Bus.displaced``:
    pushed out by a newer one, at info level, since a newest-value channel is made for it;
    stale or queue-full drops, a warning). This makes the counts visible
    to telemetry, tests and operators.
    """

    def __init__(
        self,
        bus: ReportedBus,
        service: str,
        period_s: float = 1.0,
        clock: Callable[[], float] = time.monotonic,
        publisher: TypedPublisher[Any] | None = None,
        wall_clock: Callable[[], float] = time.time,
    ) -> None:
        """`clock`: when reports are due [s]; `wall_clock`: the records' stamps [s];
        `publisher`: the service's own ``events/log`` publisher, so one sequence of
        numbers covers all its log records (None: declare one)."""
        self._bus = bus
        self._service = service
        self._period = period_s
        self._clock = clock
        self._wall = wall_clock
        self._pub = publisher or bus.publisher(bus.keys.events_log, LogEvent)
        self._event = LogEvent
        self._last: dict[tuple[str, str], int] = {}
        self._last_faults: dict[tuple[str, str], int] = {}
        self._last_displaced: dict[tuple[str, str], int] = {}
        self._next = 0.0
        self.reports = 0  #: LogEvents published (both kinds)

    @staticmethod
    def _growth(
        snap: dict[tuple[str, str], int], last: dict[tuple[str, str], int]
    ) -> tuple[int, str]:
        new = {kr: n - last.get(kr, 0) for kr, n in snap.items() if n > last.get(kr, 0)}
        return sum(new.values()), ", ".join(f"{k} {r} x{n}" for (k, r), n in sorted(new.items()))

    def _publish(self, level: str, text: str) -> None:
        self._pub.put(
            self._event(stamp_s=self._wall(), level=level, source=self._service, text=text[:900])
        )
        self.reports += 1

    def poll(self) -> bool:
        """Report new drops and own faults if due; True when a report was published."""
        now = self._clock()
        if now < self._next:
            return False
        self._next = now + self._period
        published = False
        snap = self._bus.drops.snapshot()
        n, parts = self._growth(snap, self._last)
        if n:
            self._last = snap
            total = sum(snap.values())
            self._publish(LogLevelName.WARNING, f"rejected {n} messages (total {total}): {parts}")
            published = True
        faults = self._bus.faults.snapshot()
        n, parts = self._growth(faults, self._last_faults)
        if n:
            self._last_faults = faults
            self._publish(
                LogLevelName.ERROR,
                f"own faults: {n} (total {sum(faults.values())}), not published: {parts}",
            )
            published = True
        displaced = self._bus.displaced.snapshot() if hasattr(self._bus, "displaced") else {}
        last_displaced = self._last_displaced
        n, parts = self._growth(displaced, last_displaced)
        if n:
            self._last_displaced = displaced
            total = sum(displaced.values())
            grew = {r for (k, r), c in displaced.items() if c > last_displaced.get((k, r), 0)}
            # a newest-value channel replacing a value its consumer had no time for is the
            # design (counted, said at info); stale or lost-from-a-queue records are not
            level = LogLevelName.INFO if grew <= {"overwritten"} else LogLevelName.WARNING
            self._publish(level, f"dropped {n} valid messages (total {total}): {parts}")
            published = True
        return published
