"""The common shell of every service process: arguments, config, logging, clean stop.

``run_service(name, argv, body)`` parses ``--config FILE`` (plus the service's own options),
loads and validates the one configuration, installs SIGINT/SIGTERM handlers that set a stop
event, and calls ``body(config, args, stop)``. A configuration or track error is one clear
line and exit code 2; the body must return when ``stop`` is set (closing its Zenoh session).
"""

from __future__ import annotations

import argparse
import logging
import signal
import sys
import threading
from collections.abc import Callable, Sequence

from shared.bus import FaultCounter
from shared.config import ConfigError, RacestackConfig, load_config
from shared.messages import MessageError
from shared.track import TrackError

Body = Callable[[RacestackConfig, argparse.Namespace, threading.Event], int]
AddArgs = Callable[[argparse.ArgumentParser], None]

#: Pause before a worker loop is re-entered after a fault of its own [s] (bounds the rate
#: of a loop that would fail at once on every entry).
WORKER_RESTART_PAUSE_S = 0.001


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
    ap = argparse.ArgumentParser(prog=f"racestack run {name}", description=description)
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
    stop = threading.Event()
    install_stop_handlers(stop)
    try:
        return body(cfg, args, stop)
    except (ConfigError, TrackError) as exc:
        print(f"{name}: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        log.info("interrupted")
        return 130
