"""The bus: typed publishers and subscriptions over Zenoh, for the service shells.

A service shell opens one ``Bus`` for its lifetime (through the service base,
``shared.service.Service``), declares typed publishers and subscriptions, and runs its own
loop; the maths never sees Zenoh or raw bytes::

    with Bus(cfg.bus, "planner") as bus:              # closes the session, always
        cmd_pub = bus.publisher(bus.keys.drive_cmd, DriveCmd)
        state = bus.subscribe(bus.keys.state, State)  # latest-value slot
        bus.wait_alive(["simulator"], timeout_s=10.0)
        while running:
            s = state.wait(timeout_s=0.1)              # newest State not yet taken, or None
            if s is not None:
                cmd_pub.put(DriveCmd(stamp_s=s.stamp_s, speed_mps=..., steering_rad=...))

The modules (only ``session*.py`` import zenoh; the others are pure and work without it):

* ``counters``: ``DropCounter``, ``FaultCounter``, ``ChannelStats``, ``SeqTracker``;
* ``slots``: ``LatestSlot``, ``DropOldestQueue`` (thread-safe hand-over);
* ``pubsub``: ``TypedPublisher``, ``Subscription``, ``ChannelSubscription``,
  ``wait_matching``, written against the protocols ``RawPublisher`` / ``RawSubscriber`` /
  ``RawSample`` of the layer below;
* ``reporter``: ``DropReporter``;
* ``fake``: ``FakeBus``, the bus in process for tests (import ``shared.bus.fake``);
* ``session``: ``Bus`` (one Zenoh session), ``zenoh_config``, ``open_session``,
  ``BusOpenError``, ``enable_zenoh_log``, ``MSGPACK_ENCODING``.

Every public name is importable from ``shared.bus``; the pure ones are imported with the
package, the session's on first use (module ``__getattr__``), so that importing
``shared.bus.counters`` or ``shared.bus.fake`` never imports zenoh.

Rules the package enforces (see ``/work/shared/docs/zenoh-rerun-notes.md``):

* Multicast scouting is off, endpoints are explicit (``shared.config.bus``).
* Reliable message types (commands, events) are published with ``CongestionControl.BLOCK``,
  high-rate data with ``DROP`` (``Message.RELIABLE``; overridable per publisher).
* Subscriber callbacks run on a Zenoh thread: they decode, validate and hand the record
  to a thread-safe latest-value slot and/or a bounded queue that drops the oldest. Invalid
  payloads are dropped and counted per key and reason (``DropCounter``), logged once per
  burst; no exception ever escapes into Zenoh's thread.
* A latency-critical input (the bridge's poses, the planner's states) is a
  ``ChannelSubscription`` instead: the Zenoh callback decodes and validates each sample, so
  garbage is rejected before it can enter the small ring (capacity 1 by default) and never
  pushes out a valid record; the consumer's own thread blocks in ``recv`` (GIL released).
  Every sample is accounted for: ``stats()`` gives received = valid + rejected + dropped
  (overwritten by a newer valid record, or stale) + pending. (Issue 15: when the ring held
  raw samples and decoding ran in ``recv``, garbage at 1000 Hz displaced valid poses.)
* ``Bus.close`` (and ``__exit__``) always closes the session: a process with a callback
  subscriber never exits while its session is open; a thread in ``recv`` returns None.
* A service never dies of its own invalid record: ``TypedPublisher.try_put(**fields)`` builds
  and publishes a record, and one that fails validation is not sent but counted per key and
  reason in ``Bus.faults`` (a ``FaultCounter``, logged once per burst);
  ``FaultCounter.guard(key)`` does the same around code that builds records itself.
  ``DropReporter`` publishes the growth of these counters and of ``Bus.displaced`` (valid
  records a channel dropped) on ``events/log``.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

from shared.bus.counters import (
    DROP_SUMMARY_INTERVAL_S,
    ChannelStats,
    DropCounter,
    FaultCounter,
    SeqTracker,
)
from shared.bus.pubsub import (
    ChannelSubscription,
    MatchingPublisher,
    RawPublisher,
    RawSample,
    RawSubscriber,
    Subscription,
    TypedPublisher,
    is_put,
    wait_matching,
)
from shared.bus.reporter import DropReporter, ReportedBus
from shared.bus.slots import DropOldestQueue, LatestSlot

if TYPE_CHECKING:
    from shared.bus.session import (
        MSGPACK_ENCODING,
        Bus,
        BusOpenError,
        enable_zenoh_log,
        open_session,
        zenoh_config,
    )

#: The names of ``shared.bus.session`` re-exported here, imported on first use (zenoh).
_SESSION_NAMES = frozenset(
    {"MSGPACK_ENCODING", "Bus", "BusOpenError", "enable_zenoh_log", "open_session", "zenoh_config"}
)

__all__ = [
    "DROP_SUMMARY_INTERVAL_S",
    "MSGPACK_ENCODING",
    "Bus",
    "BusOpenError",
    "ChannelStats",
    "ChannelSubscription",
    "DropCounter",
    "DropOldestQueue",
    "DropReporter",
    "FaultCounter",
    "LatestSlot",
    "MatchingPublisher",
    "RawPublisher",
    "RawSample",
    "RawSubscriber",
    "ReportedBus",
    "SeqTracker",
    "Subscription",
    "TypedPublisher",
    "enable_zenoh_log",
    "is_put",
    "open_session",
    "wait_matching",
    "zenoh_config",
]


def __getattr__(name: str) -> Any:
    """A name of ``shared.bus.session`` (imports zenoh on first use); AttributeError else."""
    if name in _SESSION_NAMES:
        value = getattr(importlib.import_module("shared.bus.session"), name)
        globals()[name] = value
        return value
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted({*globals(), *_SESSION_NAMES})
