"""Settings of the Zenoh bus: car name, session mode and endpoints, per-service overrides.

Topology on one machine with no network (the defaults): ONE process - the simulator or the
launcher's router - is the *hub*: it listens on the well-known loopback endpoint ``listen``
(``tcp/127.0.0.1:7447``). Every other service connects to the hub (``connect``, empty =
the hub's ``listen`` endpoints) and itself listens on ``local_listen``
(``tcp/127.0.0.1:0``, a free loopback port) so that gossip can link the peers directly.
Multicast scouting is off; gossip is on only while every endpoint this process listens on
is loopback (so it can only ever advertise loopback addresses) unless set explicitly.

Multi-machine use is configuration only, e.g. a router on the car and a laptop::

    # car (racestack.toml)                  # laptop
    [bus]                                   [bus]
    listen = ["tcp/0.0.0.0:7447"]           mode = "client"
    [bus.services.router]                   connect = ["tcp/192.168.1.10:7447"]
    mode = "router"

Which process is the hub is the service's built-in role (``listen_default``), which the
``[bus.services.<name>]`` table can override together with mode and endpoints.
``BusSettings.session_plan(...)`` resolves all of this into a ``SessionPlan`` (pure data,
no zenoh import); ``shared.bus.session`` turns the plan into a ``zenoh.Config``.

The secure profile (``security = "mtls"``; the default ``"none"`` is the simulator demo's):

* every link is Zenoh's TLS transport with client certificates (mutual TLS): ``tcp/`` endpoints
  are used as ``tls/`` on the same host and port; each process presents the certificate of its
  identity, its service name (``<certs_dir>/<service>.crt`` / ``.key``, CN = the name), and
  trusts only ``<certs_dir>/ca.crt`` (``racestack certs`` makes them); the server name is
  verified against the certificate (SAN ``localhost``, ``127.0.0.1``);
* the hub is the ``router`` service (``services/router``) and carries the access rules
  (``shared.security.acl``); every other process, the launcher included, is a ``client`` of it
  with gossip off and no listener, so every sample passes the rules and no peer link can
  bypass them (a ``[bus.services.<name>] listen_default`` override still moves the hub);
* ``certs_dir`` is resolved against the working directory of the process (not the config
  file), unless ``$RACESTACK_CERTS_DIR`` is set (the launcher sets it for its children when it
  made a throwaway set in the run folder).
"""

from __future__ import annotations

import ipaddress
import json
import re
from dataclasses import dataclass
from typing import Any, Literal

from pydantic import Field, field_validator, model_validator

from shared.config.base import Section
from shared.keys import DEFAULT_CAR, check_chunk

Mode = Literal["peer", "client", "router"]
Security = Literal["none", "mtls"]

#: The well-known loopback endpoint of the hub.
DEFAULT_HUB_ENDPOINT = "tcp/127.0.0.1:7447"
#: What a non-hub peer listens on: any free loopback port.
DEFAULT_LOCAL_LISTEN = "tcp/127.0.0.1:0"

_ENDPOINT = re.compile(
    r"^(?P<proto>tcp|udp|tls)/(?P<host>\[[0-9A-Fa-f:.]+\]|[A-Za-z0-9.-]+):(?P<port>\d{1,5})$"
)
_LABEL = r"[A-Za-z0-9]([A-Za-z0-9-]{0,61}[A-Za-z0-9])?"
_HOSTNAME = re.compile(rf"^(?=.{{1,253}}$){_LABEL}(\.{_LABEL})*$")


@dataclass(frozen=True)
class Endpoint:
    """A parsed Zenoh locator ``proto/host:port`` (host without IPv6 brackets)."""

    proto: str
    host: str
    port: int

    @property
    def is_loopback(self) -> bool:
        """True for ``localhost`` and loopback addresses (127.0.0.0/8, ::1)."""
        if self.host == "localhost":
            return True
        try:
            return ipaddress.ip_address(self.host).is_loopback
        except ValueError:
            return False

    @property
    def is_wildcard(self) -> bool:
        """True for ``0.0.0.0`` and ``::`` (listen on every interface)."""
        try:
            return ipaddress.ip_address(self.host).is_unspecified
        except ValueError:
            return False

    def __str__(self) -> str:
        host = f"[{self.host}]" if ":" in self.host else self.host
        return f"{self.proto}/{host}:{self.port}"


def parse_endpoint(text: str) -> Endpoint:
    """Parse ``tcp/HOST:PORT``, ``udp/HOST:PORT`` or ``tls/HOST:PORT`` (IPv4, ``[IPv6]`` or
    hostname).

    Raises:
        ValueError: anything else (other protocols, ``?``/``#`` options, bad host or port).
    """
    m = _ENDPOINT.match(text) if isinstance(text, str) else None
    if m is None:
        raise ValueError(f"endpoint {text!r} is not tcp/, udp/ or tls/HOST:PORT")
    host, port = m["host"], int(m["port"])
    if host.startswith("["):
        host = host[1:-1]
        try:
            ipaddress.IPv6Address(host)
        except ValueError:
            raise ValueError(f"endpoint {text!r}: bad IPv6 address") from None
    elif re.fullmatch(r"[0-9.]+", host):
        try:
            ipaddress.IPv4Address(host)
        except ValueError:
            raise ValueError(f"endpoint {text!r}: bad IPv4 address") from None
    elif not _HOSTNAME.match(host):
        raise ValueError(f"endpoint {text!r}: bad host name")
    if port > 65535:
        raise ValueError(f"endpoint {text!r}: port {port} > 65535")
    return Endpoint(m["proto"], host, port)


def connectable(text: str) -> str:
    """The endpoint to connect to for a listen endpoint: wildcard hosts become loopback."""
    ep = parse_endpoint(text)
    if ep.is_wildcard:
        host = "::1" if ":" in ep.host else "127.0.0.1"
        ep = Endpoint(ep.proto, host, ep.port)
    return str(ep)


def as_tls(text: str) -> str:
    """The ``tls/`` endpoint on the same host and port as a ``tcp/`` or ``tls/`` one.

    Raises:
        ValueError: a ``udp/`` endpoint (TLS runs over TCP only).
    """
    ep = parse_endpoint(text)
    if ep.proto == "udp":
        raise ValueError(f"endpoint {text!r}: the secure profile needs tcp/ or tls/, not udp/")
    return str(Endpoint("tls", ep.host, ep.port))


def _check_endpoints(values: list[str] | None, *, connect: bool) -> list[str] | None:
    if values is None:
        return None
    for text in values:
        ep = parse_endpoint(text)
        if connect and ep.port == 0:
            raise ValueError(f"cannot connect to port 0 ({text!r})")
    return values


class ServiceBusOverride(Section):
    """Per-service overrides (``[bus.services.<name>]``); None keeps the general value.

    Attributes:
        mode: Zenoh mode of this service ("peer", "client" or "router").
        listen_default: True: this service is the hub and listens on `listen`.
        listen: endpoints this service listens on when it is the hub.
        connect: endpoints this service connects to.
        local_listen: what this service listens on when it is not the hub.
        gossip: gossip scouting for this service.
    """

    mode: Mode | None = None
    listen_default: bool | None = Field(
        None, description="True: this service is the hub and listens on `listen`"
    )
    listen: list[str] | None = None
    connect: list[str] | None = None
    local_listen: list[str] | None = None
    gossip: bool | None = None

    @field_validator("listen", "local_listen")
    @classmethod
    def _listen_ok(cls, v: list[str] | None) -> list[str] | None:
        return _check_endpoints(v, connect=False)

    @field_validator("connect")
    @classmethod
    def _connect_ok(cls, v: list[str] | None) -> list[str] | None:
        return _check_endpoints(v, connect=True)


@dataclass(frozen=True)
class TlsPlan:
    """The files of one process's mutual-TLS session (paths as given, cwd-relative or not).

    Attributes:
        root_ca: the CA certificate every peer must chain to.
        cert, key: this process's certificate (CN = its identity) and private key.
        listen: True for the hub (it also serves TLS with the same certificate).
    """

    root_ca: str
    cert: str
    key: str
    listen: bool

    def missing(self) -> list[str]:
        """The files that do not exist (the caller says so; nothing is read)."""
        from pathlib import Path

        return [p for p in (self.root_ca, self.cert, self.key) if not Path(p).is_file()]

    def zenoh_entries(self) -> dict[str, str]:
        """``transport/link/tls/*`` paths -> JSON5 values (Zenoh 1.x keys)."""
        base = "transport/link/tls/"
        out = {
            base + "root_ca_certificate": json.dumps(self.root_ca),
            base + "enable_mtls": json.dumps(True),
            base + "connect_private_key": json.dumps(self.key),
            base + "connect_certificate": json.dumps(self.cert),
            base + "verify_name_on_connect": json.dumps(True),
        }
        if self.listen:
            out[base + "listen_private_key"] = json.dumps(self.key)
            out[base + "listen_certificate"] = json.dumps(self.cert)
        return out


@dataclass(frozen=True)
class SessionPlan:
    """The resolved session settings of one process (what ``shared.bus.session`` gives Zenoh).

    Attributes:
        mode: "peer" | "client" | "router".
        listen: endpoints this process listens on (empty for a client).
        connect: endpoints this process connects to.
        multicast_scouting: multicast scouting on (never by default).
        gossip: gossip scouting on.
        tls: the mutual-TLS files (None: plain TCP, the profile ``security = "none"``).
        access_control: the hub's Zenoh ``access_control`` section (None: no rules).
    """

    mode: Mode
    listen: tuple[str, ...]
    connect: tuple[str, ...]
    multicast_scouting: bool
    gossip: bool
    tls: TlsPlan | None = None
    access_control: dict[str, Any] | None = None

    def zenoh_entries(self) -> dict[str, str]:
        """Zenoh config path -> JSON5 value, for ``zenoh.Config.insert_json5``."""
        out = {
            "mode": json.dumps(self.mode),
            "listen/endpoints": json.dumps(list(self.listen)),
            "connect/endpoints": json.dumps(list(self.connect)),
            "scouting/multicast/enabled": json.dumps(self.multicast_scouting),
            "scouting/gossip/enabled": json.dumps(self.gossip),
        }
        if self.tls is not None:
            out.update(self.tls.zenoh_entries())
        if self.access_control is not None:
            out["access_control"] = json.dumps(self.access_control)
        return out


class BusSettings(Section):
    """The ``[bus]`` section: which car, how this process joins the Zenoh network.

    Attributes:
        car: car name, the ``<car>`` chunk of every key (``[A-Za-z0-9_-]+``).
        mode: Zenoh mode of every service unless overridden ("peer" by default).
        listen: endpoints of the hub (the process opened with ``listen_default=True``).
        connect: endpoints every other process connects to; empty: the hub's ``listen``
            endpoints (with ``0.0.0.0`` / ``::`` replaced by loopback).
        local_listen: what a non-hub peer or router listens on (a free loopback port).
        multicast_scouting: multicast scouting (False: it would leave loopback).
        gossip: gossip scouting; None = on iff every listen endpoint of the process is
            loopback.
        services: per-service overrides, by service name.
        security: "none" (plain TCP, anyone on the bus may publish: the simulator demo) or
            "mtls" (mutual TLS, one certificate per service, the hub's access rules: see the
            module docstring).
        certs_dir: the certificates folder of "mtls" (``racestack certs --out DIR``),
            relative to the working directory of the process.
        per_car_identity: "mtls" in a race of several cars (``[[cars]]``): this process's
            identity is its service's for ``car`` (``planner-car1``,
            ``shared.security.identities.car_identity``) for the bridge, the planner and
            telemetry (``racestack up --cars`` sets it in each car's configuration).
    """

    car: str = DEFAULT_CAR
    mode: Mode = "peer"
    listen: list[str] = Field(default_factory=lambda: [DEFAULT_HUB_ENDPOINT], min_length=1)
    connect: list[str] = Field(default_factory=list)
    local_listen: list[str] = Field(default_factory=lambda: [DEFAULT_LOCAL_LISTEN])
    multicast_scouting: bool = False
    gossip: bool | None = None
    services: dict[str, ServiceBusOverride] = Field(default_factory=dict)
    security: Security = "none"
    certs_dir: str = Field("certs", min_length=1)
    per_car_identity: bool = False

    @field_validator("car")
    @classmethod
    def _car_ok(cls, v: str) -> str:
        return check_chunk(v, "car name")

    @field_validator("listen", "local_listen")
    @classmethod
    def _listen_ok(cls, v: list[str]) -> list[str]:
        return _check_endpoints(v, connect=False) or []

    @field_validator("connect")
    @classmethod
    def _connect_ok(cls, v: list[str]) -> list[str]:
        return _check_endpoints(v, connect=True) or []

    @field_validator("services")
    @classmethod
    def _service_names_ok(cls, v: dict[str, ServiceBusOverride]) -> dict[str, ServiceBusOverride]:
        for name in v:
            check_chunk(name, "service name")
        return v

    @model_validator(mode="after")
    def _hub_reachable(self) -> BusSettings:
        if not self.connect and any(parse_endpoint(e).port == 0 for e in self.listen):
            raise ValueError("listen has port 0 and connect is empty: nobody could reach the hub")
        lists = [self.listen, self.connect, self.local_listen]
        for o in self.services.values():
            lists += [o.listen or [], o.connect or [], o.local_listen or []]
        endpoints = [e for lst in lists for e in lst]
        if self.security == "mtls":
            for e in endpoints:
                as_tls(e)  # ValueError for udp
        else:
            tls = [e for e in endpoints if parse_endpoint(e).proto == "tls"]
            if tls:
                raise ValueError(f"tls/ endpoints {tls} need security = \"mtls\"")
        return self

    def session_plan(
        self,
        *,
        listen_default: bool,
        service: str | None = None,
        mode: Mode | None = None,
        certs_dir: str | None = None,
    ) -> SessionPlan:
        """Resolve the session settings of one process.

        Args:
            listen_default: the service's built-in role: True for the hub (listens on the
                well-known ``listen`` endpoints), False for everyone else. Ignored by
                "mtls", where the hub is the ``router`` service.
            service: the service name; its ``services`` override (if any) wins over the
                built-in role and the general settings. In "mtls" also its identity (its
                certificate's name); required there.
            mode: the service's built-in Zenoh mode (e.g. "router" for the launcher's
                router); None: the general ``mode``.
            certs_dir: overrides ``certs_dir`` (the shell passes ``$RACESTACK_CERTS_DIR``).
        """
        if self.security == "mtls":
            return self._secure_plan(service, certs_dir)
        o = self.services.get(service) if service else None
        o = o or ServiceBusOverride()
        hub = o.listen_default if o.listen_default is not None else listen_default
        mode_ = o.mode or mode or self.mode
        hub_listen = o.listen if o.listen is not None else self.listen
        connect = o.connect if o.connect is not None else self.connect
        local = o.local_listen if o.local_listen is not None else self.local_listen
        if hub:
            listen = list(hub_listen)
        elif mode_ == "client":
            listen = []
        else:
            listen = list(local)
        if hub:  # never connect to oneself
            own = {connectable(e) for e in listen}
            connect = [e for e in connect if connectable(e) not in own]
        elif not connect:
            connect = [connectable(e) for e in hub_listen]
        gossip = o.gossip if o.gossip is not None else self.gossip
        if gossip is None:
            gossip = all(parse_endpoint(e).is_loopback for e in listen)
        return SessionPlan(
            mode=mode_,
            listen=tuple(listen),
            connect=tuple(connect),
            multicast_scouting=self.multicast_scouting,
            gossip=bool(gossip),
        )

    def _secure_plan(self, service: str | None, certs_dir: str | None) -> SessionPlan:
        """The session of `service` in the secure profile (see the module docstring)."""
        from pathlib import Path

        from shared.security.acl import access_control
        from shared.security.identities import HUB_IDENTITY, identity_files

        if not service:
            raise ValueError('security = "mtls" needs the service name (its identity)')
        o = self.services.get(service) or ServiceBusOverride()
        hub = o.listen_default if o.listen_default is not None else service == HUB_IDENTITY
        hub_listen = o.listen if o.listen is not None else self.listen
        connect = o.connect if o.connect is not None else self.connect
        if hub:
            listen = [as_tls(e) for e in hub_listen]
            own = {connectable(e) for e in listen}
            connect = [as_tls(e) for e in connect if connectable(as_tls(e)) not in own]
        else:
            listen = []
            connect = [as_tls(connectable(e)) for e in (connect or hub_listen)]
        from shared.security.identities import car_identity

        identity = car_identity(service, self.car) if self.per_car_identity else service
        files = identity_files(Path(certs_dir or self.certs_dir), identity)
        return SessionPlan(
            mode="router" if hub else "client",
            listen=tuple(listen),
            connect=tuple(connect),
            multicast_scouting=False,
            gossip=False,
            tls=TlsPlan(str(files.ca), str(files.cert), str(files.key), listen=hub),
            access_control=access_control(self.car) if hub else None,
        )
