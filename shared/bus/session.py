"""The Zenoh session of a service (the only modules that import zenoh: ``session*.py``).

``Bus`` wraps one ``zenoh.Session``: it opens it (multicast scouting off, explicit endpoints:
``zenoh_config`` / ``open_session``), declares the service's liveliness token, and declares
the raw Zenoh publishers and subscribers below the typed ones of ``shared.bus.pubsub``
(congestion control, priority, the msgpack encoding). Decoding, validation, counting and
hand-over are in the pure modules of the package; this module only adapts Zenoh to them.
``BusOpenError`` says in one line why a session could not be opened; ``enable_zenoh_log``
turns on Zenoh's own log.
"""

from __future__ import annotations

import logging
import re
import threading
from collections.abc import Callable, Iterable
from typing import Any, TypeVar

import zenoh

from shared.bus.counters import DropCounter, FaultCounter
from shared.bus.pubsub import ChannelSubscription, Subscription, TypedPublisher
from shared.config.bus import BusSettings, Mode
from shared.keys import Keys, check_chunk
from shared.messages import Message

log = logging.getLogger("racestack.bus")

M = TypeVar("M", bound=Message)

#: The Zenoh encoding of every racestack payload.
MSGPACK_ENCODING = "application/msgpack"


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
