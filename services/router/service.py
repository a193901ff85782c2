"""The hub: a Zenoh router listening on ``[bus] listen`` (default ``tcp/127.0.0.1:7447``).

``racestack up`` hosts this router in its own process; run it alone
(``python -m services.router``) when starting services one by one, or use a ``zenohd`` on the
same endpoint (docker compose).
"""

from __future__ import annotations

from shared.bus import Bus
from shared.service import Service


class Router(Service):
    """Holds a router session open and logs which services come and go."""

    NAME = "router"
    LISTEN_DEFAULT = True
    MODE = "router"
    PERIOD_S = 0.5

    def __init__(self, bus: Bus) -> None:
        super().__init__(bus)
        self.seen: frozenset[str] = frozenset()
        self.log.info("router listening on %s", ", ".join(bus.settings.listen))

    def tick(self) -> None:
        """Log the set of live services when it changed."""
        alive = self.bus.alive()
        if alive != self.seen:
            self.log.info("services alive: %s", ", ".join(sorted(alive)) or "none")
            self.seen = alive


main = Router.main
