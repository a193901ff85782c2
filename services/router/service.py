"""The hub: a Zenoh router listening on ``[bus] listen`` (default ``tcp/127.0.0.1:7447``).

``racestack up`` hosts this router in its own process; run it alone
(``python -m services.router``) when starting services one by one, or use a ``zenohd`` on the
same endpoint (docker compose).
"""

from __future__ import annotations

import argparse
import logging
import threading
from collections.abc import Sequence

from shared.bus import Bus
from shared.config import RacestackConfig
from shared.service_shell import run_service

log = logging.getLogger(__name__)
SERVICE = "router"


def run(cfg: RacestackConfig, args: argparse.Namespace, stop: threading.Event) -> int:
    """Hold a router session open until stopped."""
    with Bus(cfg.bus, SERVICE, listen_default=True, mode="router") as bus:
        log.info("router listening on %s", ", ".join(cfg.bus.listen))
        seen: frozenset[str] = frozenset()
        while not stop.wait(0.5):
            alive = bus.alive()
            if alive != seen:
                log.info("services alive: %s", ", ".join(sorted(alive)) or "none")
                seen = alive
    return 0


def main(argv: Sequence[str] | None = None) -> int:
    """``python -m services.router``."""
    return run_service(SERVICE, argv, run, description=__doc__.splitlines()[0])
