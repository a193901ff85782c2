"""Zenoh helpers for the service shells (the only shared module that imports zenoh).

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

Rules this module enforces (see ``/work/shared/docs/zenoh-rerun-notes.md``):

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

import collections
import contextlib
import logging
import re
import threading
import time
from collections.abc import Callable, Iterable, Iterator
from typing import Any, Generic, NamedTuple, TypeVar

import zenoh

from shared.config.bus import BusSettings, Mode
from shared.keys import Keys, check_chunk
from shared.messages import LogLevelName, Message, MessageError, decode, decode_any

log = logging.getLogger("racestack.bus")

M = TypeVar("M", bound=Message)
T = TypeVar("T")

#: The Zenoh encoding of every racestack payload.
MSGPACK_ENCODING = "application/msgpack"
#: Default interval between two summary log lines of one (key, reason) burst [s].
DROP_SUMMARY_INTERVAL_S = 5.0
#: Poll period of the matching / liveliness waits [s].
_POLL_S = 0.005


# --------------------------------------------------------------------------- drop counting
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


# --------------------------------------------------------------------------- hand-over
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


# --------------------------------------------------------------------------- sessions
def zenoh_config(
    settings: BusSettings,
    *,
    listen_default: bool,
    service: str | None = None,
    mode: Mode | None = None,
) -> zenoh.Config:
    """The ``zenoh.Config`` of one process (see ``BusSettings.session_plan``).

    In the secure profile (``security = "mtls"``) ``$RACESTACK_CERTS_DIR`` overrides
    ``[bus] certs_dir``, and a missing certificate file is a ``ConfigError`` naming it.
    """
    import os

    from shared.config import ConfigError
    from shared.security.identities import CERTS_DIR_ENV

    plan = settings.session_plan(
        listen_default=listen_default,
        service=service,
        mode=mode,
        certs_dir=os.environ.get(CERTS_DIR_ENV) or None,
    )
    if plan.tls is not None and plan.tls.missing():
        raise ConfigError(
            f"{service}: secure profile: missing {', '.join(plan.tls.missing())} "
            "(make them with: racestack certs --out DIR, and set [bus] certs_dir)"
        )
    cfg = zenoh.Config()
    for path, value in plan.zenoh_entries().items():
        cfg.insert_json5(path, value)
    return cfg


def enable_zenoh_log(directives: str) -> None:
    """Turn on Zenoh's own log (Rust ``tracing``, written to this process's stderr) with
    `directives` (``RUST_LOG`` syntax; a ``RUST_LOG`` in the environment wins). Once per
    process; the router uses it to count access-control denials."""
    zenoh.init_log_from_env_or(directives)


def open_session(
    settings: BusSettings,
    *,
    listen_default: bool,
    service: str | None = None,
    mode: Mode | None = None,
) -> zenoh.Session:
    """Open a Zenoh session: multicast scouting off, explicit endpoints.

    Args:
        settings: the ``[bus]`` settings.
        listen_default: True for the hub (the simulator or the launcher's router), which
            listens on the well-known endpoint; False for every other service.
        service: the service name (applies its ``[bus.services.<name>]`` override).
        mode: the service's built-in Zenoh mode (None: ``settings.mode``).

    The caller must close the session (``Bus`` does). Never fork after this call.

    Raises:
        BusOpenError: Zenoh refused (e.g. an endpoint to listen on is in use), one line.
    """
    config = zenoh_config(settings, listen_default=listen_default, service=service, mode=mode)
    try:
        return zenoh.open(config)
    except zenoh.ZError as exc:
        raise BusOpenError(str(exc)) from exc


class BusOpenError(RuntimeError):
    """A Zenoh session could not be opened; ``str()`` is one line saying why and what to do.

    Attributes:
        endpoint: the endpoint Zenoh named (e.g. ``tcp/127.0.0.1:7447``), or None.
        in_use: True when that endpoint's port is already taken by another process.
    """

    def __init__(self, zenoh_text: str) -> None:
        found = re.search(r"bound to (\S+?):? \[", zenoh_text)
        self.endpoint: str | None = found.group(1) if found else None
        self.in_use = "Address already in use" in zenoh_text
        if self.in_use:
            where = self.endpoint or "the hub endpoint"
            line = (
                f"cannot listen on {where}: the port is already in use (is a router or "
                "another racestack up still running?); stop it, or set another port in "
                "[bus] listen"
            )
        else:  # Zenoh's own text without the Rust source locations
            line = "cannot open the Zenoh session: " + re.sub(r" at /\S+\.rs:\d+\.?", "",
                                                               zenoh_text).strip()
        super().__init__(" ".join(line.split()))


def wait_matching(publisher: TypedPublisher[Any] | zenoh.Publisher, timeout_s: float) -> bool:
    """Wait up to `timeout_s` [s] until a subscriber matches `publisher`; True if one does."""
    raw = publisher.raw if isinstance(publisher, TypedPublisher) else publisher
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
        raw: the declared zenoh.Publisher.
        key: its key.
        msg_type: the message class published there.
        faults: where ``try_put`` counts records that fail validation (the bus's
            ``faults``; None: a counter of this publisher's own).
    """

    def __init__(
        self,
        raw: zenoh.Publisher,
        key: str,
        msg_type: type[M],
        faults: FaultCounter | None = None,
    ) -> None:
        self.raw = raw  #: the underlying zenoh.Publisher
        self.key = key
        self.msg_type = msg_type
        self.faults = faults if faults is not None else FaultCounter()
        self._lock = threading.Lock()
        self._next_seq = 0

    def put(self, record: M) -> M:
        """Publish `record` with the next sequence number; returns the stamped record.

        Raises:
            TypeError: `record` is not of this publisher's message type.
            zenoh.ZError: the session is closed.
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
            zenoh.ZError: the session is closed.
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
        return bool(self.raw.matching_status.matching)

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
        self._last_seq: dict[str, int] = {}
        self.received = 0
        self.seq_gaps = 0
        self.raw: zenoh.Subscriber[Any] | None = None

    # -- Zenoh thread ------------------------------------------------------------
    def on_sample(self, sample: zenoh.Sample) -> None:
        """The Zenoh callback: decode, validate, hand over. Never raises."""
        got = _decode_sample(sample, self.key, self.msg_type, self._drops)
        if got is None:
            return
        try:
            self._deliver(*got)  # type: ignore[arg-type]
        except Exception as exc:  # never into Zenoh's thread
            _record_internal(self._drops, got[0], exc)

    def _deliver(self, key: str, msg: M) -> None:
        gaps = _count_seq(self._last_seq, key, msg)
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
    sample: zenoh.Sample,
    key: str,
    msg_type: type[M] | None,
    drops: DropCounter,
) -> tuple[str, M] | None:
    """(key, record) of a sample, or None after counting why it was dropped. Never raises."""
    try:
        key = str(sample.key_expr)
        if sample.kind != zenoh.SampleKind.PUT:
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


def _count_seq(last_seq: dict[str, int], key: str, msg: Message) -> int:
    """Records missed on `key` before `msg`, by sequence number (and remember it)."""
    last = last_seq.get(key)
    last_seq[key] = msg.seq
    if last is not None and msg.seq > last + 1:
        return msg.seq - last - 1
    return 0


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
        self.raw: zenoh.Subscriber[Any] | None = None
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
        self._last_seq: dict[str, int] = {}
        self._arrived = 0
        self._rejected = 0
        self._overwritten = 0
        self._stale = 0
        self.received = 0
        self.seq_gaps = 0

    # -- Zenoh thread ------------------------------------------------------------
    def on_sample(self, sample: zenoh.Sample) -> None:
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
            self.seq_gaps += _count_seq(self._last_seq, self.key, msg)
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


# --------------------------------------------------------------------------- the bus
class Bus:
    """One service's Zenoh session, its liveliness token and typed pub/sub helpers.

    The session opens in the constructor and is closed by ``close()`` / ``__exit__``
    (always, also on exceptions). Use as ``with Bus(settings, "planner") as bus: ...``.
    """

    def __init__(
        self,
        settings: BusSettings,
        service: str,
        *,
        listen_default: bool = False,
        mode: Mode | None = None,
        announce: bool = True,
        drops: DropCounter | None = None,
        faults: FaultCounter | None = None,
    ) -> None:
        """Open the session and (if `announce`) declare this service's liveliness token.

        Args:
            settings: the ``[bus]`` settings (car name, endpoints, overrides).
            service: this service's name (``[A-Za-z0-9_-]+``), used for its override
                and its liveliness token ``racestack/<car>/alive/<service>``.
            listen_default: True for the hub (listens on the well-known endpoint).
            mode: the service's built-in Zenoh mode (None: ``settings.mode``).
            announce: declare the liveliness token now.
            drops: a shared drop counter (default: a new one, ``self.drops``).
            faults: a shared counter of this service's own faults (default: a new one,
                ``self.faults``): records of its own that failed validation.
        """
        self.service = check_chunk(service, "service name")
        self.settings = settings
        self.keys = Keys(settings.car)
        self.drops = drops or DropCounter()
        self.faults = faults or FaultCounter()
        #: valid records dropped before their consumer took them: (key, reason), reason
        #: "overwritten" / "stale" (a channel) or "queue_full" (a subscription's queue)
        self.displaced = DropCounter()
        self._channels: list[ChannelSubscription[Any]] = []
        self._lock = threading.Lock()
        self._closed = False
        self._tokens: list[zenoh.LivelinessToken] = []
        self._alive: set[str] = set()
        self._alive_cond = threading.Condition()
        self._alive_sub: zenoh.Subscriber[Any] | None = None
        self.session = open_session(
            settings, listen_default=listen_default, service=service, mode=mode
        )
        try:
            if announce:
                self.declare_alive(service)
        except BaseException:
            self.close()
            raise

    def __enter__(self) -> Bus:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    @property
    def closed(self) -> bool:
        """True once ``close`` ran."""
        return self._closed

    def close(self) -> None:
        """Flush drop summaries and close the session (idempotent, never raises)."""
        with self._lock:
            if self._closed:
                return
            self._closed = True
        try:
            self.drops.flush()
            self.faults.flush()
            self.displaced.flush()
        except Exception:  # pragma: no cover
            log.exception("flushing drop summaries failed")
        try:
            self.session.close()
        except Exception:
            log.exception("closing the Zenoh session failed")
        for chan in self._channels:  # their consumers' recv returns None
            chan.close()

    # -- publish / subscribe ----------------------------------------------------------
    def publisher(
        self,
        key: str,
        msg_type: type[M],
        *,
        reliable: bool | None = None,
        priority: zenoh.Priority | None = None,
        express: bool = False,
    ) -> TypedPublisher[M]:
        """Declare a typed publisher on `key`.

        Args:
            key: the full key (``bus.keys.drive_cmd``...).
            msg_type: the message class published there.
            reliable: True: congestion control BLOCK (commands, events; never lost
                locally); False: DROP (high-rate data where only the newest matters);
                None: the message type's default ``msg_type.RELIABLE``.
            priority: Zenoh priority (None: Zenoh's default, DATA).
            express: send at once without batching.
        """
        if reliable is None:
            reliable = msg_type.RELIABLE
        raw = self.session.declare_publisher(
            key,
            encoding=zenoh.Encoding(MSGPACK_ENCODING),
            congestion_control=(
                zenoh.CongestionControl.BLOCK if reliable else zenoh.CongestionControl.DROP
            ),
            priority=priority,
            express=express,
        )
        return TypedPublisher(raw, key, msg_type, self.faults)

    def subscribe(
        self,
        key: str,
        msg_type: type[M] | None,
        callback: Callable[[M], None] | None = None,
        *,
        queue_size: int = 0,
    ) -> Subscription[M]:
        """Subscribe to `key` (wildcards allowed) with decoding and validation.

        Args:
            key: key expression.
            msg_type: the expected message class (others are dropped as "wrong_type");
                None accepts any known message (``decode_any``), e.g. for telemetry.
            callback: called with every valid record ON THE ZENOH THREAD: it must return
                quickly and never block (exceptions are caught and counted as
                "callback_error"). Prefer the latest slot or the queue.
            queue_size: > 0 also keeps the last `queue_size` records in a FIFO that
                drops the oldest (``get`` / ``drain``), counted in ``displaced`` as
                "queue_full" (and so reported by ``DropReporter``).
        """
        sub: Subscription[M] = Subscription(
            key, msg_type, self.drops, callback, queue_size, displaced=self.displaced
        )
        sub.raw = self.session.declare_subscriber(key, sub.on_sample)
        return sub

    def subscribe_channel(
        self, key: str, msg_type: type[M], *, capacity: int = 1, max_age_s: float | None = None
    ) -> ChannelSubscription[M]:
        """Subscribe to `key` for a consumer thread that blocks in ``recv`` (see
        ``ChannelSubscription``): samples are validated on arrival, the channel keeps the
        newest `capacity` valid records and (if `max_age_s` [s] is given) drops the ones
        older than that when taken; every loss is counted (``stats()``)."""
        chan: ChannelSubscription[M] = ChannelSubscription(
            key, msg_type, self.drops, capacity, displaced=self.displaced, max_age_s=max_age_s
        )
        chan.raw = self.session.declare_subscriber(key, chan.on_sample)
        with self._lock:
            self._channels.append(chan)
        return chan

    def put_raw(self, key: str, payload: bytes) -> None:
        """Publish raw bytes on `key`, bypassing the contract (tests and tools only)."""
        self.session.put(
            key,
            payload,
            encoding=zenoh.Encoding(MSGPACK_ENCODING),
            congestion_control=zenoh.CongestionControl.BLOCK,
        )

    # -- liveliness ------------------------------------------------------------------
    def declare_alive(self, service: str) -> zenoh.LivelinessToken:
        """Declare the liveliness token of `service`; it lives until the session closes."""
        token = self.session.liveliness().declare_token(self.keys.alive(service))
        self._tokens.append(token)
        return token

    def _watch_alive(self) -> None:
        with self._lock:
            if self._alive_sub is not None:
                return
            self._alive_sub = self.session.liveliness().declare_subscriber(
                self.keys.alive_any, self._on_alive, history=True
            )

    def _on_alive(self, sample: zenoh.Sample) -> None:
        try:
            name = self.keys.service_of_alive_key(str(sample.key_expr))
            if name is None:
                return
            with self._alive_cond:
                if sample.kind == zenoh.SampleKind.PUT:
                    self._alive.add(name)
                else:
                    self._alive.discard(name)
                self._alive_cond.notify_all()
        except Exception as exc:  # never into Zenoh's thread
            log.warning("liveliness callback failed: %s", exc)

    def alive(self) -> frozenset[str]:
        """Names of the services of this car whose liveliness token is currently seen.

        The first call starts watching (tokens already declared are reported shortly
        after, not necessarily before this first call returns).
        """
        self._watch_alive()
        with self._alive_cond:
            return frozenset(self._alive)

    def wait_alive(self, services: Iterable[str], timeout_s: float) -> bool:
        """Wait up to `timeout_s` [s] until every service in `services` is alive."""
        wanted = {check_chunk(s, "service name") for s in services}
        self._watch_alive()
        with self._alive_cond:
            return self._alive_cond.wait_for(
                lambda: wanted <= self._alive, timeout=max(0.0, timeout_s)
            )

    def missing_alive(self, services: Iterable[str]) -> set[str]:
        """The services of `services` whose token is not seen now."""
        return set(services) - self.alive()


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
        bus: Bus,
        service: str,
        period_s: float = 1.0,
        clock: Callable[[], float] = time.monotonic,
        publisher: TypedPublisher[Any] | None = None,
        wall_clock: Callable[[], float] = time.time,
    ) -> None:
        """`clock`: when reports are due [s]; `wall_clock`: the records' stamps [s];
        `publisher`: the service's own ``events/log`` publisher, so one sequence of
        numbers covers all its log records (None: declare one)."""
        from shared.messages import LogEvent

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
