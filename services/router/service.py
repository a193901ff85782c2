"""The hub: a Zenoh router listening on ``[bus] listen`` (default ``tcp/127.0.0.1:7447``).

``racestack up`` hosts this router in its own process in the plain profile; run it alone
(``python -m services.router``) when starting services one by one, or use a ``zenohd`` on the
same endpoint (docker compose).

In the secure profile (``[bus] security = "mtls"``) this process is the only hub: it listens
on TLS with client certificates and carries the access rules (``shared.security.acl``); the
launcher starts it first. Zenoh denies silently, so the router turns on Zenoh's
access-control trace, reads it from its own stdout (``logtap.StdoutTap``) and reports the
denials on ``events/log`` at most every ``REPORT_PERIOD_S`` (warning: ``denied 40 messages
(total 40): telemetry Put (ingress) racestack/car0/cmd/drive x40``). Its rules come from the
whole configuration (``hub_settings``): the stack's keys and the keys of the ``[ros2]``
topics, so a configured ROS topic is allowed without a code change.
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import threading
from typing import Any

from pydantic import PrivateAttr

from services.router.denials import ACL_LOG_DIRECTIVES, DenialCounter, growth_text
from shared.bus import Bus, enable_zenoh_log
from shared.config import BusSettings, ConfigError, RacestackConfig
from shared.config.bus import SessionPlan
from shared.keys import EVENTS_LOG
from shared.messages import LogEvent, LogLevelName
from shared.service import Service, publishes


class HubBusSettings(BusSettings):
    """``[bus]`` of the hub with access rules built from the whole configuration.

    ``BusSettings.session_plan`` knows only ``[bus]``; this one replaces the plan's
    ``access_control`` (the hub's only) with ``access_rules`` when they are set.
    """

    _access_rules: dict[str, Any] | None = PrivateAttr(default=None)

    def session_plan(self, **kwargs: Any) -> SessionPlan:
        """``BusSettings.session_plan`` with this hub's access rules."""
        plan = super().session_plan(**kwargs)
        if plan.access_control is None or self._access_rules is None:
            return plan
        return dataclasses.replace(plan, access_control=self._access_rules)


def hub_settings(cfg: RacestackConfig) -> BusSettings:
    """The router's ``[bus]``: in the secure profile with the rules of ``shared.security.acl``
    for ``[bus] car`` (every car of ``[[cars]]`` when there are several, each car's services
    with their own identity) and the ``[ros2]`` topics (``cfg.bus`` itself in the plain
    profile).

    Raises:
        ConfigError: a ``[[ros2.topics]]`` key the rules cannot hold (bad or inside
            ``racestack/``).
    """
    if cfg.bus.security != "mtls":
        return cfg.bus
    from shared.security.acl import access_control
    from shared.security.identities import IDENTITIES, fleet_identities

    fleet = tuple(c.name for c in cfg.cars) if len(cfg.cars) >= 2 else ()
    try:
        rules = access_control(cfg.bus.car, fleet_identities(fleet) if fleet else IDENTITIES,
                               ros2=cfg.ros2, fleet=fleet)
    except ValueError as exc:
        raise ConfigError(f"secure profile: {exc}") from None
    hub = HubBusSettings.model_validate(cfg.bus.model_dump())
    hub._access_rules = rules
    return hub


class Router(Service):
    """Holds a router session open, logs which services come and go, reports denials."""

    NAME = "router"
    LISTEN_DEFAULT = True
    MODE = "router"
    PERIOD_S = 0.5
    PORTS = (publishes(EVENTS_LOG, LogEvent),)

    def __init__(self, bus: Bus, denials: DenialCounter | None = None, **kwargs) -> None:
        """`denials`: the access-control denials counted by the log tap (None: not
        counted, the plain profile)."""
        super().__init__(bus, **kwargs)
        self.seen: frozenset[str] = frozenset()
        self.denials = denials
        self._reported: dict = {}
        self._next_denial_report = 0.0
        self.log.info("router listening on %s", ", ".join(bus.settings.listen))
        if bus.settings.security == "mtls":
            self.log.info("secure profile: mutual TLS, access rules on, denials counted")

    def tick(self) -> None:
        """Log the set of live services when it changed; report new denials."""
        alive = self.bus.alive()
        if alive != self.seen:
            self.log.info("services alive: %s", ", ".join(sorted(alive)) or "none")
            self.seen = alive
        self.report_denials()

    def report_denials(self) -> bool:
        """Say the denials since the last report, at most every ``REPORT_PERIOD_S``."""
        if self.denials is None or self.clock() < self._next_denial_report:
            return False
        snap = self.denials.snapshot()
        n, parts = growth_text(snap, self._reported)
        if not n:
            return False
        self._next_denial_report = self.clock() + self.REPORT_PERIOD_S
        self._reported = snap
        total = sum(snap.values())
        return self.say(LogLevelName.WARNING, f"denied {n} messages (total {total}): {parts}")

    @classmethod
    def body(cls, cfg: RacestackConfig, args: argparse.Namespace, stop: threading.Event) -> int:
        """``host``; in the secure profile with the access-control trace tapped first."""
        if cfg.bus.security != "mtls":
            return cls.host(cfg.bus, stop, lambda bus: cls(bus))
        from services.router.logtap import StdoutTap

        settings = hub_settings(cfg)

        if os.environ.get("RUST_LOG"):
            print(f"router: RUST_LOG is set: denials are counted only if it has "
                  f"{','.join(ACL_LOG_DIRECTIVES.split(',')[1:])}", flush=True)
        tap = StdoutTap()
        try:
            enable_zenoh_log(ACL_LOG_DIRECTIVES)
            return cls.host(settings, stop, lambda bus: cls(bus, denials=tap.counter))
        finally:
            tap.close()


main = Router.main
