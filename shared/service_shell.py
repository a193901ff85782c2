"""The common shell of every service process: arguments, config, logging, clean stop.

``run_service(name, argv, body)`` parses ``--config FILE`` (plus the service's own options),
loads and validates the one configuration, applies the process's own ``[processes.NAME]``
scheduling (``shared.priority``: nice, CPUs, real-time priority; what it may not set is one
warning line), installs SIGINT/SIGTERM handlers that set a stop
event, and calls ``body(config, args, stop)``. A configuration or track error is one clear
line and exit code 2; the body must return when ``stop`` is set (closing its Zenoh session).

A bad start is one line on stderr and exit code 2, never a traceback: a usage
error (``OneLineArgumentParser``), an ``--out`` folder that cannot be written (checked
before anything starts; a folder made for the check is removed again), a session Zenoh
refuses to open (``BusOpenError``: e.g. the hub port already in use), an optional extra
not installed (``shared.extras.MissingExtraError``). A hub that cannot be
reached is no error: Zenoh keeps retrying and the service waits, but ``HubWatch`` says
once, after ``HUB_WAIT_S``, that nothing listens at the hub's endpoint and what to do.
"""

from __future__ import annotations

import argparse
import logging
import re
import signal
import socket
import sys
import threading
from collections.abc import Callable, Sequence
from pathlib import Path

from shared.bus import BusOpenError, FaultCounter
from shared.config import BusSettings, ConfigError, RacestackConfig, load_config
from shared.config.bus import parse_endpoint
from shared.extras import MissingExtraError
from shared.messages import MessageError
from shared.outdir import missing_dirs, remove_empty_dirs, writable_dir_problem
from shared.priority import apply_priority
from shared.track import TrackError

Body = Callable[[RacestackConfig, argparse.Namespace, threading.Event], int]
AddArgs = Callable[[argparse.ArgumentParser], None]

#: Pause before a worker loop is re-entered after a fault of its own [s] (bounds the rate
#: of a loop that would fail at once on every entry).
WORKER_RESTART_PAUSE_S = 0.001
#: How long a service may take to reach the hub before it says, once, that it cannot [s].
HUB_WAIT_S = 3.0
#: Between two probes of the hub while it is unreachable [s].
HUB_PROBE_PERIOD_S = 1.0


class OneLineArgumentParser(argparse.ArgumentParser):
    """An argument parser whose usage errors are one line on stderr (exit code 2)."""

    def error(self, message: str):  # type: ignore[override]
        """Print ``PROG: error: MESSAGE (see PROG --help)`` and exit 2."""
        self.exit(2, f"{self.prog}: error: {message} (see {self.prog} --help)\n")


def plain_help(doc: str | None) -> str | None:
    """The first paragraph of a docstring as one help sentence, without RST markup
    (double backticks removed, lines joined)."""
    if not doc:
        return doc
    para = re.split(r"\n\s*\n", doc.strip(), maxsplit=1)[0]
    return " ".join(para.replace("``", "").split())


def _count_text(value: int) -> str | None:
    return None if value >= 1 else f"must be a whole number >= 1, got {value}"


def positive_int(text: str) -> int:
    """An argparse ``type``: a whole number >= 1 (e.g. a lap count). Its message is the
    one of ``count_problem``: ``argument --laps: must be a whole number >= 1, got 0``."""
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a whole number") from None
    problem = _count_text(value)
    if problem:
        raise argparse.ArgumentTypeError(problem)
    return value


def count_problem(option: str, value: int) -> str | None:
    """The one wording of a count option below 1 (``--laps 0``), as argparse says it of a
    ``positive_int`` option: ``argument --laps: must be a whole number >= 1, got 0``; None
    when `value` is fine. For callers that pass a parsed value on (``run_up``, the bench's
    ``main(args=...)``)."""
    problem = _count_text(value)
    return None if problem is None else f"argument {option}: {problem}"


def hub_endpoints(settings: BusSettings, service: str) -> list[str]:
    """The TCP-based endpoints (``tcp/`` and, in the secure profile, ``tls/``) service
    `service` connects to, to reach the hub (empty for the hub itself or a service with
    only UDP endpoints)."""
    plan = settings.session_plan(listen_default=False, service=service)
    out = []
    for text in plan.connect:
        try:
            ep = parse_endpoint(text)
        except ValueError:
            continue
        if ep.proto in ("tcp", "tls"):  # both are TCP underneath: a connect probe works
            out.append(text)
    return out


def endpoint_reachable(endpoint: str, timeout_s: float = 0.5) -> bool:
    """True when something accepts a TCP connection at `endpoint` (``tcp/`` or
    ``tls/HOST:PORT``)."""
    ep = parse_endpoint(endpoint)
    try:
        with socket.create_connection((ep.host, ep.port), timeout=timeout_s):
            return True
    except OSError:
        return False


def unreachable_hub_line(name: str, endpoints: Sequence[str]) -> str:
    """The one line a service says when it cannot reach the hub at `endpoints`."""
    return (
        f"{name}: cannot reach the hub at {', '.join(endpoints)} (nothing listens there): "
        "start it (racestack up, or racestack run router) or fix [bus] connect in the "
        "configuration; still trying"
    )


class HubWatch:
    """Says once, on stderr, when the hub has not been reachable for ``HUB_WAIT_S``.

    A daemon thread probes the hub's TCP endpoints (a plain connect, no Zenoh) after
    `wait_s` and then every ``HUB_PROBE_PERIOD_S`` until one answers; Zenoh itself keeps
    retrying meanwhile, so the service goes on waiting (``racestack run SERVICE``). When the
    hub appears later, that is logged once.
    """

    def __init__(self, name: str, endpoints: Sequence[str], wait_s: float = HUB_WAIT_S,
                 stream=None) -> None:
        self.name = name
        self.endpoints = list(endpoints)
        self.wait_s = wait_s
        self.stream = stream
        self.said = False  #: True once the unreachable line was printed
        self._done = threading.Event()
        self._thread = threading.Thread(target=self._run, name="hub-watch", daemon=True)

    def start(self) -> HubWatch:
        """Start watching (nothing to do without endpoints); returns self."""
        if self.endpoints:
            self._thread.start()
        return self

    def stop(self) -> None:
        """Stop watching."""
        self._done.set()

    def _run(self) -> None:
        try:
            if self._done.wait(self.wait_s):
                return
            while not any(endpoint_reachable(e) for e in self.endpoints):
                if not self.said:
                    print(unreachable_hub_line(self.name, self.endpoints),
                          file=self.stream or sys.stderr, flush=True)
                    self.said = True
                if self._done.wait(HUB_PROBE_PERIOD_S):
                    return
            if self.said:
                logging.getLogger(f"services.{self.name}").info(
                    "hub reachable at %s", ", ".join(self.endpoints))
        except Exception:  # the watch is advice only: it never ends the service
            logging.getLogger(__name__).debug("hub watch failed", exc_info=True)


class Worker:
    """A service's latency-critical loop on its own thread, watched by the main thread.

    The main thread keeps signals, the stop event and the periodic chores (watchdogs, drop
    reports); the worker blocks on its input (``ChannelSubscription.recv``) and reacts at
    once. An exception in the worker sets `stop` and is re-raised in the main thread by
    ``check()`` / ``join()``, so a crash still ends the service with an error; after `stop`
    was set by someone else (shutdown: the bus is closing under the worker), it is only
    logged.

    A ``MessageError`` is no crash: received payloads are validated by the bus and never
    raise, so it comes from a record of the service's own that failed validation (a value
    it computed left the contract). It is counted in `faults` (key `fault_key`, the error's
    reason; pass ``bus.faults`` so ``DropReporter`` reports it on ``events/log``) and the
    loop is entered again for the next input: the loop must be re-entrant (block on its
    input, keep its state outside).

    Args:
        name: thread name.
        loop: the loop; returns when the service stops (e.g. its ``recv`` gives None).
        stop: the service's stop event.
        faults: where faults of its own are counted (None: a counter of its own, logged).
        fault_key: the key they are counted under (None: ``"worker/<name>"``).
    """

    def __init__(
        self,
        name: str,
        loop: Callable[[], None],
        stop: threading.Event,
        *,
        faults: FaultCounter | None = None,
        fault_key: str | None = None,
    ) -> None:
        self._loop = loop
        self._stop = stop
        self._error: BaseException | None = None
        self.faults = faults if faults is not None else FaultCounter()
        self.fault_key = fault_key or f"worker/{name}"
        self.restarts = 0  #: times the loop was re-entered after a fault of its own
        self._thread = threading.Thread(target=self._run, name=name, daemon=True)

    def _run(self) -> None:
        log = logging.getLogger(__name__)
        while True:
            try:
                self._loop()
                return
            except MessageError as exc:
                if self._stop.is_set():
                    log.debug("%s ended during shutdown: %r", self._thread.name, exc)
                    return
                self.faults.record(self.fault_key, exc.reason, exc.detail)
                self.restarts += 1
                if self._stop.wait(WORKER_RESTART_PAUSE_S):
                    return
            except BaseException as exc:
                if self._stop.is_set():
                    log.debug("%s ended during shutdown: %r", self._thread.name, exc)
                else:
                    self._error = exc
                    self._stop.set()
                return

    def start(self) -> Worker:
        """Start the thread; returns self."""
        self._thread.start()
        return self

    @property
    def alive(self) -> bool:
        """True while the loop runs."""
        return self._thread.is_alive()

    def check(self) -> None:
        """Re-raise the worker's exception, if it died of one."""
        if self._error is not None:
            raise self._error

    def join(self, timeout_s: float) -> bool:
        """Wait up to `timeout_s` [s] for the loop to end, then ``check()``; True if it ended."""
        self._thread.join(timeout_s)
        self.check()
        return not self._thread.is_alive()


def install_stop_handlers(stop: threading.Event) -> None:
    """SIGINT and SIGTERM set `stop` (main thread only); a second SIGINT exits at once."""

    def handler(signum: int, _frame: object) -> None:
        if stop.is_set() and signum == signal.SIGINT:
            raise KeyboardInterrupt
        stop.set()

    if threading.current_thread() is threading.main_thread():
        signal.signal(signal.SIGINT, handler)
        signal.signal(signal.SIGTERM, handler)


def run_service(
    name: str,
    argv: Sequence[str] | None,
    body: Body,
    add_args: AddArgs | None = None,
    description: str | None = None,
) -> int:
    """Run service `name`'s `body` under the common shell; returns the exit code."""
    ap = OneLineArgumentParser(prog=f"racestack run {name}", description=plain_help(description))
    ap.add_argument("--config", help="TOML configuration file (default: built-in defaults)")
    ap.add_argument("-v", "--verbose", action="store_true", help="debug logging")
    if add_args:
        add_args(ap)
    args = ap.parse_args(argv)
    logging.basicConfig(
        level=logging.DEBUG if args.verbose else logging.INFO,
        format=f"%(asctime)s {name} %(levelname)s %(name)s: %(message)s",
    )
    log = logging.getLogger(f"services.{name}")
    try:
        cfg = load_config(args.config)
    except ConfigError as exc:
        print(f"{name}: configuration error:\n{exc}", file=sys.stderr)
        return 2
    out = getattr(args, "out", None)  # a service's output folder: usable before it starts
    created = missing_dirs(Path(out)) if isinstance(out, str) and out else []
    if isinstance(out, str) and out:
        problem = writable_dir_problem(Path(out))
        if problem:
            remove_empty_dirs(created)
            print(f"{name}: error: {problem}; give --out a folder you can write",
                  file=sys.stderr)
            return 2
    priority = apply_priority(cfg.processes.of(name))  # before any thread: all inherit it
    for line in priority.warnings:
        log.warning("[processes.%s] %s", name, line)
    for line in priority.notes:
        log.info("[processes.%s] %s", name, line)
    stop = threading.Event()
    install_stop_handlers(stop)
    watch = HubWatch(name, hub_endpoints(cfg.bus, name)).start()
    try:
        return body(cfg, args, stop)
    except (ConfigError, TrackError, BusOpenError, MissingExtraError) as exc:
        remove_empty_dirs(created)
        print(f"{name}: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        log.info("interrupted")
        return 130
    finally:
        watch.stop()
