"""Typed publishers and subscriptions over a raw publisher / subscriber (no zenoh).

A ``TypedPublisher`` stamps sequence numbers, encodes records and hands the bytes to the raw
publisher below it; a ``Subscription`` / ``ChannelSubscription`` decodes and validates the
raw samples its raw subscriber delivers. What they need of the layer below is written as
protocols (``RawPublisher``, ``RawSubscriber``, ``RawSample``): in a process that layer is a
Zenoh session (``shared.bus.session.Bus`` declares ``zenoh.Publisher`` / ``zenoh.Subscriber``
objects, which fit them), in a test it is the in-process fake (``shared.bus.fake.FakeBus``).
Decoding, validation, counting and hand-over are all here and import no zenoh.
"""

from __future__ import annotations

import collections
import threading
import time
from collections.abc import Callable
from typing import Any, Generic, Protocol, TypeVar, cast

from shared.bus.counters import ChannelStats, DropCounter, FaultCounter, SeqTracker
from shared.bus.slots import DropOldestQueue, LatestSlot
from shared.messages import Message, MessageError, decode, decode_any

M = TypeVar("M", bound=Message)

#: Poll period of ``wait_matching`` [s].
_POLL_S = 0.005


# --------------------------------------------------------------------------- the layer below
class RawPublisher(Protocol):
    """What a ``TypedPublisher`` needs of the publisher below it (a ``zenoh.Publisher``)."""

    def put(self, payload: bytes, /) -> None:
        """Send one encoded record."""
        ...

    def undeclare(self) -> None:
        """Stop publishing."""
        ...


class MatchingStatus(Protocol):
    """Whether subscribers match a publisher's key (``zenoh.MatchingStatus``)."""

    @property
    def matching(self) -> bool:
        """True while at least one subscriber matches."""
        ...


class MatchingPublisher(RawPublisher, Protocol):
    """A raw publisher that also reports matching subscribers (a ``zenoh.Publisher``);
    ``TypedPublisher.matching`` and ``wait_matching`` need one."""

    @property
    def matching_status(self) -> MatchingStatus:
        """The current matching status."""
        ...


class RawSubscriber(Protocol):
    """What a subscription needs of the subscriber below it (a ``zenoh.Subscriber``)."""

    def undeclare(self) -> None:
        """Stop receiving."""
        ...


class RawPayload(Protocol):
    """The payload of a sample (a ``zenoh.ZBytes``)."""

    def to_bytes(self) -> bytes:
        """The payload's bytes."""
        ...


class RawSample(Protocol):
    """What a subscription reads of one received sample (a ``zenoh.Sample``)."""

    @property
    def key_expr(self) -> object:
        """The key it was published on (``str()`` gives the key)."""
        ...

    @property
    def kind(self) -> object:
        """Put or delete (``zenoh.SampleKind``; see ``is_put``)."""
        ...

    @property
    def payload(self) -> RawPayload:
        """The payload."""
        ...


def is_put(kind: object) -> bool:
    """True when a sample's `kind` is a put: ``zenoh.SampleKind.PUT``, recognised by its
    name (``str()`` is ``SampleKind.PUT``) so that this module needs no zenoh; any other
    kind (``SampleKind.DELETE``) is not a record."""
    return str(kind).rpartition(".")[2].upper() == "PUT"


def wait_matching(publisher: TypedPublisher[Any] | MatchingPublisher, timeout_s: float) -> bool:
    """Wait up to `timeout_s` [s] until a subscriber matches `publisher` (a typed publisher
    over a ``MatchingPublisher``, or one such raw publisher); True if one does."""
    raw = cast(
        MatchingPublisher, publisher.raw if isinstance(publisher, TypedPublisher) else publisher
    )
    deadline = time.monotonic() + timeout_s
    while True:
        if raw.matching_status.matching:
            return True
        if time.monotonic() >= deadline:
            return False
        time.sleep(_POLL_S)


# --------------------------------------------------------------------------- publish
class TypedPublisher(Generic[M]):
    """Publishes records of one message type on one key, stamping sequence numbers.

    Args:
        raw: the raw publisher below (a declared ``zenoh.Publisher`` in a session, a
            recorder in the fake bus); ``matching`` and ``wait_matching`` need a
            ``MatchingPublisher``.
        key: its key.
        msg_type: the message class published there.
        faults: where ``try_put`` counts records that fail validation (the bus's
            ``faults``; None: a counter of this publisher's own).
    """

    def __init__(
        self,
        raw: RawPublisher,
        key: str,
        msg_type: type[M],
        faults: FaultCounter | None = None,
    ) -> None:
        self.raw = raw  #: the raw publisher below (a zenoh.Publisher in a session)
        self.key = key
        self.msg_type = msg_type
        self.faults = faults if faults is not None else FaultCounter()
        self._lock = threading.Lock()
        self._next_seq = 0

    def put(self, record: M) -> M:
        """Publish `record` with the next sequence number; returns the stamped record.

        Raises:
            TypeError: `record` is not of this publisher's message type.
            zenoh.ZError: (a session's publisher) the session is closed.
        """
        if type(record) is not self.msg_type:
            raise TypeError(
                f"publisher of {self.msg_type.__name__} on {self.key} got {type(record).__name__}"
            )
        with self._lock:
            seq = self._next_seq
            self._next_seq += 1
        self.raw.put(record.encode(seq))  # sent first; the stamped copy is for the caller
        return record.with_seq(seq)

    def try_put(self, **fields: Any) -> M | None:
        """Build a record of this publisher's type from `fields` (keyword arguments of its
        constructor, ``seq`` excluded) and publish it; returns the stamped record.

        A record that fails validation (``MessageError``: NaN, a value out of range, ...) is
        not sent: it is counted in ``faults`` on this key with the error's reason (logged
        once per burst; ``DropReporter`` reports it on ``events/log``) and None is returned,
        so a bad value of the service's own never ends its loop. Wrong field names still
        raise ``TypeError`` (a programming error, not a value).

        Raises:
            zenoh.ZError: (a session's publisher) the session is closed.
        """
        try:
            record = self.msg_type(**fields)
        except MessageError as exc:
            self.faults.record(self.key, exc.reason, exc.detail)
            return None
        return self.put(record)

    @property
    def next_seq(self) -> int:
        """The sequence number the next ``put`` will use."""
        with self._lock:
            return self._next_seq

    @property
    def matching(self) -> bool:
        """True while at least one subscriber matches this key."""
        return bool(cast(MatchingPublisher, self.raw).matching_status.matching)

    def wait_matching(self, timeout_s: float) -> bool:
        """Wait up to `timeout_s` [s] for a matching subscriber (see ``wait_matching``)."""
        return wait_matching(self, timeout_s)

    def undeclare(self) -> None:
        """Stop publishing (the session stays open)."""
        self.raw.undeclare()


# --------------------------------------------------------------------------- subscribe
class Subscription(Generic[M]):
    """Decoded, validated records of one key, handed over without blocking Zenoh.

    Every valid record goes to the latest-value slot (``latest``, ``take``, ``wait``), to
    the bounded queue when ``queue_size > 0`` (``get``, ``drain``), and to the callback if
    one was given. Invalid payloads are counted in the bus's ``DropCounter``.

    Attributes:
        received: valid records received.
        seq_gaps: records missed according to the sequence numbers (one publisher per key).
    """

    def __init__(
        self,
        key: str,
        msg_type: type[M] | None,
        drops: DropCounter,
        callback: Callable[[M], None] | None = None,
        queue_size: int = 0,
        displaced: DropCounter | None = None,
    ) -> None:
        self.key = key
        self.msg_type = msg_type
        self._drops = drops
        self._displaced = displaced
        self._callback = callback
        self._slot: LatestSlot[M] = LatestSlot()
        self._queue: DropOldestQueue[M] | None = DropOldestQueue(queue_size) if queue_size else None
        self._seq = SeqTracker()
        self.received = 0
        self.seq_gaps = 0
        self.raw: RawSubscriber | None = None  #: the raw subscriber below, once declared

    # -- Zenoh thread ------------------------------------------------------------
    def on_sample(self, sample: RawSample) -> None:
        """The Zenoh callback: decode, validate, hand over. Never raises."""
        got = _decode_sample(sample, self.key, self.msg_type, self._drops)
        if got is None:
            return
        try:
            self._deliver(*got)  # type: ignore[arg-type]
        except Exception as exc:  # never into Zenoh's thread
            _record_internal(self._drops, got[0], exc)

    def _deliver(self, key: str, msg: M) -> None:
        gaps = self._seq.gap(key, msg.seq)
        self.seq_gaps += gaps
        self.received += 1
        self._slot.put(msg)
        if self._queue is not None and self._queue.put(msg) and self._displaced is not None:
            self._displaced.record(key, "queue_full", "the oldest queued record was dropped")
        if self._callback is not None:
            try:
                self._callback(msg)
            except Exception as exc:
                self._drops.record(key, "callback_error", f"{type(exc).__name__}: {exc}")

    # -- the caller's loop ---------------------------------------------------------
    def latest(self) -> M | None:
        """The newest record (taken or not), None if nothing arrived yet."""
        return self._slot.peek()

    def take(self) -> M | None:
        """The newest record if not taken yet (marks it taken), else None."""
        return self._slot.take()

    def wait(self, timeout_s: float) -> M | None:
        """Wait up to `timeout_s` [s] for a record not yet taken; take and return it."""
        return self._slot.wait(timeout_s)

    def get(self, timeout_s: float = 0.0) -> M | None:
        """The oldest queued record, waiting up to `timeout_s` [s] (needs queue_size > 0)."""
        if self._queue is None:
            raise RuntimeError(f"subscription to {self.key} has no queue (queue_size=0)")
        return self._queue.get(timeout_s)

    def drain(self) -> list[M]:
        """Every queued record, oldest first (needs queue_size > 0)."""
        if self._queue is None:
            raise RuntimeError(f"subscription to {self.key} has no queue (queue_size=0)")
        return self._queue.drain()

    @property
    def overflowed(self) -> int:
        """Records dropped from the full queue (oldest first)."""
        return self._queue.dropped if self._queue is not None else 0

    @property
    def dropped(self) -> int:
        """Invalid payloads dropped on this subscription's key."""
        return self._drops.count(self.key)

    def undeclare(self) -> None:
        """Stop receiving (the session stays open)."""
        if self.raw is not None:
            self.raw.undeclare()
            self.raw = None


def _decode_sample(
    sample: RawSample,
    key: str,
    msg_type: type[M] | None,
    drops: DropCounter,
) -> tuple[str, M] | None:
    """(key, record) of a sample, or None after counting why it was dropped. Never raises."""
    try:
        key = str(sample.key_expr)
        if not is_put(sample.kind):
            drops.record(key, "not_put", f"sample kind {sample.kind}")
            return None
        data = sample.payload.to_bytes()
        try:
            msg = decode(data, msg_type) if msg_type else decode_any(data)
        except MessageError as exc:
            drops.record(key, exc.reason, exc.detail)
            return None
        return key, msg  # type: ignore[return-value]
    except Exception as exc:  # never into Zenoh's thread, never into a service loop
        _record_internal(drops, key, exc)
        return None


def _record_internal(drops: DropCounter, key: str, exc: Exception) -> None:
    try:
        drops.record(key, "internal_error", f"{type(exc).__name__}: {exc}")
    except Exception:  # pragma: no cover - logging itself failed
        pass



class ChannelSubscription(Generic[M]):
    """Records of one key for a consumer thread that blocks in ``recv``.

    For a service's latency-critical input. Every sample is decoded and validated ON ZENOH'S
    THREAD (a short callback that never blocks), so garbage is counted as rejected and never
    enters the channel: a flood of invalid payloads cannot push out a valid record. Valid
    records go into a ring of the newest ``capacity``; a valid record pushed out by a newer
    one is counted as overwritten, one older than ``max_age_s`` when taken (by its
    ``stamp_s`` against ``wall_clock``) as stale. Rejections are also counted per key and
    reason in the bus's ``DropCounter``; overwritten and stale records in its ``displaced``
    counter (``DropReporter`` reports all three on ``events/log``). ``stats()`` gives the
    counts, which add up (``ChannelStats``). One consumer thread only; stop it by closing
    the ``Bus`` (``recv`` then returns None).

    Attributes:
        received: valid records handed to the consumer (``stats().valid``).
        seq_gaps: records missed according to the sequence numbers of those handed over
            (one publisher per key): transport losses and overwritten records show here.
    """

    def __init__(
        self,
        key: str,
        msg_type: type[M],
        drops: DropCounter,
        capacity: int = 1,
        *,
        displaced: DropCounter | None = None,
        max_age_s: float | None = None,
        wall_clock: Callable[[], float] = time.time,
    ) -> None:
        if capacity < 1:
            raise ValueError("capacity must be >= 1")
        self.raw: RawSubscriber | None = None  #: the raw subscriber below, once declared
        self.key = key
        self.msg_type = msg_type
        self.capacity = capacity
        self.max_age_s = max_age_s
        self._drops = drops
        self._displaced = displaced if displaced is not None else DropCounter()
        self._wall = wall_clock
        self._cond = threading.Condition()
        self._ring: collections.deque[M] = collections.deque()
        self._closed = False
        self._seq = SeqTracker()
        self._arrived = 0
        self._rejected = 0
        self._overwritten = 0
        self._stale = 0
        self.received = 0
        self.seq_gaps = 0

    # -- Zenoh thread ------------------------------------------------------------
    def on_sample(self, sample: RawSample) -> None:
        """The Zenoh callback: decode and validate, then into the ring. Never raises."""
        try:
            got = _decode_sample(sample, self.key, self.msg_type, self._drops)
            self.offer(got[1] if got is not None else None)
        except Exception as exc:  # never into Zenoh's thread
            _record_internal(self._drops, self.key, exc)

    def offer(self, record: M | None) -> None:
        """Count one arrived sample: `record` is its valid record, None if it was rejected
        (already counted by reason in the bus's ``DropCounter``)."""
        pushed_out = False
        with self._cond:
            self._arrived += 1
            if record is None:
                self._rejected += 1
                return
            if len(self._ring) >= self.capacity:
                self._ring.popleft()
                self._overwritten += 1
                pushed_out = True
            self._ring.append(record)
            self._cond.notify()
        if pushed_out:
            self._displaced.record(self.key, "overwritten", "a newer valid record came first")

    def close(self) -> None:
        """End every ``recv`` (what is queued is still taken first). Idempotent."""
        with self._cond:
            self._closed = True
            self._cond.notify_all()

    # -- the consumer's thread -----------------------------------------------------
    def _take(self) -> M | None:
        """The oldest queued record that is not stale (call holding ``_cond``)."""
        while self._ring:
            msg = self._ring.popleft()
            if self.max_age_s is not None and self._wall() - msg.stamp_s > self.max_age_s:
                self._stale += 1
                self._displaced.record(self.key, "stale", f"older than {self.max_age_s} s")
                continue
            self.seq_gaps += self._seq.gap(self.key, msg.seq)
            self.received += 1
            return msg
        return None

    def recv(self, timeout_s: float | None = None) -> M | None:
        """The next valid record, waiting up to `timeout_s` [s] (None: as long as it
        takes); None on timeout or once the bus is closed and the channel is empty."""
        deadline = None if timeout_s is None else time.monotonic() + max(0.0, timeout_s)
        with self._cond:
            while True:
                msg = self._take()
                if msg is not None or self._closed:
                    return msg
                if deadline is None:
                    self._cond.wait()
                else:
                    left = deadline - time.monotonic()
                    if left <= 0.0:
                        return None
                    self._cond.wait(left)

    def try_recv(self) -> M | None:
        """The next valid record if one is queued, else None (never waits)."""
        with self._cond:
            return self._take()

    def stats(self) -> ChannelStats:
        """The counts now (see ``ChannelStats``; they add up)."""
        with self._cond:
            dropped = self._overwritten + self._stale
            return ChannelStats(self._arrived, self.received, self._rejected, dropped,
                                len(self._ring), self._overwritten, self._stale)

    @property
    def dropped(self) -> int:
        """Invalid payloads dropped on this subscription's key (the bus's count)."""
        return self._drops.count(self.key)

    def undeclare(self) -> None:
        """Stop receiving and end ``recv`` (the session stays open)."""
        self.close()
        if self.raw is not None:
            self.raw.undeclare()
            self.raw = None


