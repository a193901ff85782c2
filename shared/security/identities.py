"""Who may be on the bus in the secure profile: the identities and their certificate files.

One certificate per identity; the certificate's subject common name (CN) *is* the identity
the hub's access control sees (``cert_common_names``). A service's identity is its service
name (``shared.service.Service.NAME``), so a process knows which files are its own.

Files in a certificates folder (``racestack certs --out DIR``)::

    ca.crt                  the local certificate authority (every session trusts only it)
    ca.key                  its private key (keep it off the car once the certificates exist)
    <identity>.crt / .key   one pair per identity (PEM; keys written with mode 0600)
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from shared.roster import ROSTER
from shared.roster import hub as roster_hub

#: The identity of the ROS 2 side: zenoh-bridge-ros2dds, or rmw_zenoh's router or nodes,
#: connecting to the hub with this certificate; it may put the keys of the inbound
#: ``[[ros2.topics]]`` (ROS -> stack), which the ros2_gateway turns into ``vehicle/*``.
ROS2_IDENTITY = "ros2"

#: The identities that are no process service of the roster: the launcher (``racestack
#: up``), an operator's console (allowed to send ``sim/control``) and the ROS 2 side.
OTHER_IDENTITIES: tuple[str, ...] = ("launcher", "operator", ROS2_IDENTITY)

#: Every identity ``racestack certs`` makes a certificate for: each process service of the
#: roster (``shared.roster``, in its order: the stack, the real-car drivers and gateways),
#: then ``OTHER_IDENTITIES``.
IDENTITIES: tuple[str, ...] = (*(p.identity for p in ROSTER), *OTHER_IDENTITIES)

#: The services each car of a race of several cars (``[[cars]]``) runs for itself: each has
#: one identity per car, ``car_identity`` (the simulator, the launcher and the rest are one
#: identity for every car).
PER_CAR_SERVICES: tuple[str, ...] = ("localization_bridge", "planner", "telemetry")


def car_identity(service: str, car: str) -> str:
    """The identity (certificate common name) of `service` of car `car` in a race of several
    cars: ``planner-car1`` (a service of ``PER_CAR_SERVICES``; any other: `service`)."""
    return f"{service}-{car}" if service in PER_CAR_SERVICES else service


def fleet_identities(cars: tuple[str, ...] | list[str]) -> tuple[str, ...]:
    """Every identity of a race of `cars`: ``IDENTITIES`` and each car's own of
    ``PER_CAR_SERVICES`` (``car_identity``)."""
    own = tuple(car_identity(s, c) for c in cars for s in PER_CAR_SERVICES)
    return (*IDENTITIES, *own)


#: The identity of the hub in the secure profile: the router (``services/router``, the
#: roster's hub) carries the access rules; every other process, the launcher included, is a
#: client of it.
HUB_IDENTITY = roster_hub().identity
#: Environment variable that overrides ``[bus] certs_dir`` (the launcher sets it for its
#: children when it made a throwaway certificates folder in the run folder).
CERTS_DIR_ENV = "RACESTACK_CERTS_DIR"

#: File name of the certificate authority's certificate in a certificates folder.
CA_CERT = "ca.crt"
#: File name of the certificate authority's private key.
CA_KEY = "ca.key"


@dataclass(frozen=True)
class IdentityFiles:
    """The three files one TLS session needs (absolute or cwd-relative paths).

    Attributes:
        ca: the CA certificate every peer certificate must chain to.
        cert: this identity's certificate (CN = the identity).
        key: this identity's private key (PEM, unencrypted, mode 0600).
    """

    ca: Path
    cert: Path
    key: Path

    def missing(self) -> list[Path]:
        """The files that do not exist (empty when the identity can open a session)."""
        return [p for p in (self.ca, self.cert, self.key) if not p.is_file()]


def identity_files(certs_dir: Path, identity: str) -> IdentityFiles:
    """The file names of `identity` in `certs_dir` (no file is read)."""
    return IdentityFiles(
        ca=certs_dir / CA_CERT,
        cert=certs_dir / f"{identity}.crt",
        key=certs_dir / f"{identity}.key",
    )
