"""The one service base: bus session, event log, drop and fault reports, watchdog, clocks.

Every racestack process (and the launcher, which hosts the router) is a ``Service`` subclass
that declares what it publishes and subscribes to AS DATA, and gets the plumbing from here::

    class BridgeService(Service):
        NAME = "localization_bridge"
        PORTS = (
            subscribes(POSE, Pose), subscribes(ODOM, Odom), subscribes(IMU, Imu),
            publishes(STATE, State), publishes(EVENTS_LOG, LogEvent),
        )

    main = BridgeService.main        # python -m services.localization_bridge

What the base owns:

* the bus session: ``open_bus`` opens it with the class's ``LISTEN_DEFAULT`` / ``MODE``;
  ``host`` runs the whole life (open, build, announce, serve, close, join); ``main`` is the
  command line (``shared.service_shell.run_service``: ``--config``, signals, exit codes);
* the declared ports: ``publisher(suffix)``, ``subscribe(suffix, ...)`` and
  ``subscribe_channel(suffix)`` give only what ``PORTS`` declares (with its message type), so
  the declarations cannot drift from the code; the contract tables of the docs are checked
  against them (``contract_rows``; tests/shared/test_contract_docs.py);
* the event log: ``say(level, text)`` logs here and publishes a ``LogEvent`` on
  ``events/log``; ``say(..., limit="kind")`` says a kind of event at most once per
  ``event_interval_s`` and counts the suppressed ones into the next line;
* drop reports and own-fault reports: a ``shared.bus.DropReporter`` publishes the growth of
  ``bus.drops`` (invalid payloads received) and ``bus.faults`` (records of its own that failed
  validation, and faults it recovered from) on ``events/log``;
* the watchdog: ``serve(stop)`` (the main thread, overridable) calls ``poll()`` every
  ``period_s``: the reports, the service's own ``tick()`` (its periodic checks; the
  planner's stale-state brake is a deadline worker instead) and a check of its ``Worker``
  threads (``start_worker``), whose crash ends it;
* the clocks: ``clock`` (monotonic [s]: periods, rate limits) and ``wall_clock`` ([s]: message
  stamps) are constructor arguments, so a test drives time by hand.

Life of a hosted service (``host``): the bus opens; the factory builds the service, which
declares its publishers and subscriptions; then its liveliness token ``alive/<NAME>`` is
declared (alive = subscribed: publishers may start); ``serve(stop)`` runs until ``stop``;
the bus closes (always), then ``close()`` (always), then the workers are joined (a crash is
re-raised).
"""

from __future__ import annotations

import argparse
import gc
import logging
import sys
import threading
import time
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass
from enum import StrEnum
from typing import Any, ClassVar, Self

from shared.bus import Bus, ChannelSubscription, DropReporter, Subscription, TypedPublisher
from shared.config import RacestackConfig
from shared.config.bus import BusSettings, Mode
from shared.keys import EVENTS_LOG, TOPIC_TYPES, check_chunk
from shared.messages import REGISTRY, LogLevelName, Message
from shared.messages.codec import MAX_STR_LEN
from shared.ratelimit import RateLimiter
from shared.service_shell import Worker, run_service

#: ``LogEvent.level`` -> ``logging`` level.
LOGGING_LEVELS: dict[str, int] = {
    LogLevelName.DEBUG: logging.DEBUG,
    LogLevelName.INFO: logging.INFO,
    LogLevelName.WARNING: logging.WARNING,
    LogLevelName.ERROR: logging.ERROR,
}


class Direction(StrEnum):
    """Which way a port carries messages, seen from the service."""

    PUBLISH = "publish"
    SUBSCRIBE = "subscribe"


@dataclass(frozen=True)
class Port:
    """One key a service publishes or subscribes to (a row of its declared contract).

    Attributes:
        suffix: the key below ``racestack/<car>/`` (a ``shared.keys`` constant).
        msg_type: the message class on that key (the one ``shared.keys.TOPIC_TYPES`` names).
        direction: publish or subscribe.
    """

    suffix: str
    msg_type: type[Message]
    direction: Direction

    def __post_init__(self) -> None:
        tag = TOPIC_TYPES.get(self.suffix)
        if tag is None:
            raise ValueError(f"unknown key suffix {self.suffix!r}; known: {sorted(TOPIC_TYPES)}")
        if REGISTRY[tag] is not self.msg_type:
            raise ValueError(
                f"{self.suffix} carries {REGISTRY[tag].__name__}, not {self.msg_type.__name__}"
            )


def publishes(suffix: str, msg_type: type[Message]) -> Port:
    """The port of a key the service publishes."""
    return Port(suffix, msg_type, Direction.PUBLISH)


def subscribes(suffix: str, msg_type: type[Message]) -> Port:
    """The port of a key the service subscribes to."""
    return Port(suffix, msg_type, Direction.SUBSCRIBE)


class Service:
    """The base of every service shell (see the module docstring).

    Class attributes (the declarations):
        NAME: the service name (``[A-Za-z0-9_-]+``): its liveliness token, log source and
            ``[bus.services.<NAME>]`` override.
        PORTS: what it publishes and subscribes to (``publishes`` / ``subscribes``).
        LISTEN_DEFAULT: True for the hub (listens on ``[bus] listen``).
        MODE: its built-in Zenoh mode (None: ``[bus] mode``).
        PERIOD_S: default period of the watchdog loop [s].
        REPORT_PERIOD_S: default shortest interval between two drop / fault reports [s].
        EVENT_INTERVAL_S: default interval of ``say(..., limit=...)`` [s].
        JOIN_TIMEOUT_S: wait for each worker thread at the end [s].

    Args:
        bus: the service's open bus (``open_bus``; tests pass a stand-in with ``keys``,
            ``drops``, ``faults``, ``publisher`` and ``subscribe``).
        clock: monotonic clock [s] of periods and rate limits.
        wall_clock: wall clock [s] of message stamps.
        period_s: watchdog period [s] (None: ``PERIOD_S``).
        report_period_s: drop / fault report interval [s] (None: ``REPORT_PERIOD_S``).
        event_interval_s: interval of rate-limited events [s] (None: ``EVENT_INTERVAL_S``).
    """

    NAME: ClassVar[str] = ""
    PORTS: ClassVar[tuple[Port, ...]] = ()
    LISTEN_DEFAULT: ClassVar[bool] = False
    MODE: ClassVar[Mode | None] = None
    PERIOD_S: ClassVar[float] = 0.2
    REPORT_PERIOD_S: ClassVar[float] = 1.0
    EVENT_INTERVAL_S: ClassVar[float] = 1.0
    JOIN_TIMEOUT_S: ClassVar[float] = 2.0

    def __init_subclass__(cls, **kwargs: Any) -> None:
        super().__init_subclass__(**kwargs)
        if cls.NAME:
            check_chunk(cls.NAME, "service name")
        seen = [(p.suffix, p.direction) for p in cls.PORTS]
        if len(set(seen)) != len(seen):
            raise TypeError(f"{cls.__name__}.PORTS declares a port twice: {seen}")

    def __init__(
        self,
        bus: Bus,
        *,
        clock: Callable[[], float] = time.monotonic,
        wall_clock: Callable[[], float] = time.time,
        period_s: float | None = None,
        report_period_s: float | None = None,
        event_interval_s: float | None = None,
    ) -> None:
        if not self.NAME:
            raise TypeError(f"{type(self).__name__} has no NAME")
        self.bus = bus
        self.keys = bus.keys
        self.clock = clock
        self.wall_clock = wall_clock
        self.period_s = self.PERIOD_S if period_s is None else period_s
        self.event_interval_s = self.EVENT_INTERVAL_S if event_interval_s is None else (
            event_interval_s
        )
        self.log = logging.getLogger(type(self).__module__)
        self.workers: list[Worker] = []
        self._ports = {(p.suffix, p.direction): p for p in self.PORTS}
        self._pubs: dict[str, TypedPublisher[Any]] = {}
        self._limits: dict[str, RateLimiter] = {}
        self._say_lock = threading.Lock()
        #: its ``events/log`` publisher (None when it does not declare one)
        self.log_pub: TypedPublisher[Any] | None = None
        #: reports drops and own faults on ``events/log`` (None without ``log_pub``)
        self.reporter: DropReporter | None = None
        if (EVENTS_LOG, Direction.PUBLISH) in self._ports:
            self.log_pub = self.publisher(EVENTS_LOG)
            self.reporter = DropReporter(
                bus,
                self.NAME,
                period_s=self.REPORT_PERIOD_S if report_period_s is None else report_period_s,
                clock=clock,
                publisher=self.log_pub,
                wall_clock=wall_clock,
            )

    # -- the declared ports --------------------------------------------------------------
    def _port(self, suffix: str, direction: Direction) -> Port:
        port = self._ports.get((suffix, direction))
        if port is None:
            raise ValueError(f"{self.NAME} does not declare {direction} {suffix!r} in PORTS")
        return port

    def publisher(self, suffix: str) -> TypedPublisher[Any]:
        """The publisher of a declared key (one per key: one sequence of numbers)."""
        port = self._port(suffix, Direction.PUBLISH)
        pub = self._pubs.get(suffix)
        if pub is None:
            pub = self._pubs[suffix] = self.bus.publisher(self.keys.key(suffix), port.msg_type)
        return pub

    def subscribe(
        self,
        suffix: str,
        callback: Callable[[Any], None] | None = None,
        *,
        queue_size: int = 0,
    ) -> Subscription[Any]:
        """Subscribe to a declared key (``Bus.subscribe``: latest slot, queue, callback)."""
        port = self._port(suffix, Direction.SUBSCRIBE)
        return self.bus.subscribe(
            self.keys.key(suffix), port.msg_type, callback, queue_size=queue_size
        )

    def subscribe_channel(self, suffix: str, *, capacity: int = 1) -> ChannelSubscription[Any]:
        """Subscribe to a declared key for a worker blocking in ``recv``
        (``Bus.subscribe_channel``)."""
        port = self._port(suffix, Direction.SUBSCRIBE)
        return self.bus.subscribe_channel(self.keys.key(suffix), port.msg_type, capacity=capacity)

    def announce(self) -> None:
        """Declare the liveliness token ``alive/<NAME>`` (once it is subscribed)."""
        self.bus.declare_alive(self.NAME)

    # -- the event log -------------------------------------------------------------------
    def say(self, level: str, text: str, *, limit: str | None = None) -> bool:
        """Log `text` here at `level` and publish it on ``events/log``; True if it was said.

        Args:
            level: a ``LogLevelName`` ("debug" | "info" | "warning" | "error").
            text: the line (cut to the contract's length).
            limit: a kind of event said at most once per ``event_interval_s`` (the first at
                once); one that is held back returns False, and the next line of that kind
                ends with ``(N more since the last report)``.

        Never raises for the bus: a record that fails validation is counted in
        ``bus.faults``; a session closing under it while stopping is only logged (debug).
        """
        if limit is not None:
            with self._say_lock:
                limiter = self._limits.get(limit)
                if limiter is None:
                    limiter = self._limits[limit] = RateLimiter(self.event_interval_s)
                allowed, suppressed = limiter.allow(self.clock())
            if not allowed:
                return False
            if suppressed:
                text = f"{text} ({suppressed} more since the last report)"
        self.log.log(LOGGING_LEVELS.get(level, logging.ERROR), "%s", text)
        if self.log_pub is not None:
            try:
                self.log_pub.try_put(
                    stamp_s=self.wall_clock(),
                    level=level,
                    source=self.NAME,
                    text=text[:MAX_STR_LEN],
                )
            except Exception as exc:  # the session closed while stopping: the local log has it
                self.log.debug("could not publish a log event: %s", exc)
        return True

    def report(self) -> bool:
        """Publish the growth of the drop and own-fault counts if due; True if published."""
        return self.reporter.poll() if self.reporter is not None else False

    # -- threads and the watchdog ----------------------------------------------------------
    def start_worker(
        self,
        name: str,
        loop: Callable[[], None],
        stop: threading.Event,
        *,
        fault_key: str | None = None,
    ) -> Worker:
        """Run `loop` on a watched thread (``shared.service_shell.Worker``): its faults of
        its own are counted in ``bus.faults`` under `fault_key` and the loop re-entered; a
        crash sets `stop` and is re-raised by the watchdog or at the end."""
        worker = Worker(name, loop, stop, faults=self.bus.faults, fault_key=fault_key).start()
        self.workers.append(worker)
        return worker

    def tick(self) -> None:
        """The service's own periodic chore, called by ``poll`` (default: none)."""

    def check_workers(self) -> None:
        """Re-raise the exception a worker died of, if one did."""
        for worker in self.workers:
            worker.check()

    def poll(self) -> None:
        """One watchdog round: reports, ``tick()``, and a worker crash re-raised."""
        self.report()
        self.tick()
        self.check_workers()

    def serve(self, stop: threading.Event) -> int:
        """The main thread until `stop` is set: ``poll()`` every ``period_s``; the exit code
        (a worker's crash, which also sets `stop`, is re-raised)."""
        while not stop.wait(self.period_s):
            self.poll()
        self.check_workers()
        return 0

    def close(self) -> None:
        """Release what the service holds besides the bus (called after the bus closed)."""

    def join_workers(self) -> None:
        """Wait for the workers (the closed bus ends their ``recv``); re-raise a crash."""
        for worker in self.workers:
            worker.join(self.JOIN_TIMEOUT_S)

    # -- the process ---------------------------------------------------------------------
    @classmethod
    def open_bus(cls, settings: BusSettings) -> Bus:
        """Open this service's bus session (its liveliness token comes with ``announce``)."""
        return Bus(
            settings, cls.NAME, listen_default=cls.LISTEN_DEFAULT, mode=cls.MODE, announce=False
        )

    @classmethod
    def host(
        cls, settings: BusSettings, stop: threading.Event, factory: Callable[[Bus], Self]
    ) -> int:
        """The whole life of one service on its own bus (see the module docstring)."""
        svc: Self | None = None
        try:
            with cls.open_bus(settings) as bus:
                svc = factory(bus)
                # what was built lives as long as the process: out of the collector's sight,
                # so its full collections do not walk it on a critical thread (issue 25)
                gc.collect()
                gc.freeze()
                svc.announce()
                code = svc.serve(stop)
                svc.log.info("stopping")
        finally:
            if svc is not None:
                svc.close()
        assert svc is not None  # the factory raised otherwise
        svc.join_workers()
        return code

    @classmethod
    def create(cls, cfg: RacestackConfig, args: argparse.Namespace, bus: Bus) -> Self:
        """Build the service on its open bus (default: ``cls(bus)``)."""
        return cls(bus)

    @classmethod
    def body(cls, cfg: RacestackConfig, args: argparse.Namespace, stop: threading.Event) -> int:
        """The body ``run_service`` calls: ``host`` with ``create``."""
        return cls.host(cfg.bus, stop, lambda bus: cls.create(cfg, args, bus))

    @staticmethod
    def add_args(ap: argparse.ArgumentParser) -> None:
        """The service's own command-line options (default: none)."""

    @classmethod
    def main(cls, argv: Sequence[str] | None = None) -> int:
        """``python -m services.<NAME>``: parse, load the configuration, ``body``; exit code."""
        doc = sys.modules[cls.__module__].__doc__ or cls.NAME
        return run_service(cls.NAME, argv, cls.body, cls.add_args, description=doc)


# --------------------------------------------------------------------------- the contract
@dataclass(frozen=True)
class ContractRow:
    """Who publishes and who subscribes to one key, from the services' declarations.

    Attributes:
        suffix: the key below ``racestack/<car>/``.
        msg_type: its message class.
        publishers, subscribers: names of the services declaring it, sorted.
    """

    suffix: str
    msg_type: type[Message]
    publishers: tuple[str, ...]
    subscribers: tuple[str, ...]


def contract_rows(services: Iterable[type[Service]]) -> dict[str, ContractRow]:
    """The contract table of `services`' declarations: one row per key of
    ``shared.keys.TOPIC_TYPES``, in that order (keys nobody declares have empty columns)."""
    declared = {(p.suffix, p.direction, s.NAME) for s in services for p in s.PORTS}

    def names(suffix: str, direction: Direction) -> tuple[str, ...]:
        return tuple(sorted(n for k, d, n in declared if k == suffix and d is direction))

    return {
        suffix: ContractRow(
            suffix,
            REGISTRY[tag],
            names(suffix, Direction.PUBLISH),
            names(suffix, Direction.SUBSCRIBE),
        )
        for suffix, tag in TOPIC_TYPES.items()
    }
