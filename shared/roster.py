"""The roster: every service that runs as its own process, in one place.

Each entry is one process ``python -m services.<name>`` (``services/<name>/``). The cli's
``racestack run`` choices, the services ``racestack up`` starts and their start order, the
identities of the secure profile (``shared.security.identities``), the import rules and the
contract tests read this list, and a test checks ``docker-compose.yml`` against it. A new
process service is one line here (see docs/architecture.md, "Where a new service goes").

The order of ``ROSTER`` is the order everywhere: ``racestack up`` starts its services in it
(``up_names``), ``racestack run`` and ``racestack certs`` list them in it. This module imports
nothing from ``services/`` (it names modules, it does not load them).
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class Process:
    """One process service.

    Attributes:
        name: the service name: its folder ``services/<name>/``, ``racestack run <name>``, its
            ``Service.NAME`` and its liveliness token ``alive/<name>``.
        up: True when ``racestack up`` starts it as a child process with the stack.
        hub: True for the Zenoh router, the hub every other process connects to. ``up`` does
            not start it as a child in the plain profile (the launcher hosts the hub itself);
            in the secure profile it starts it first. A compose file runs it as a container.
        identity: its certificate's common name in the secure profile (default: `name`).
    """

    name: str
    up: bool
    hub: bool = False
    identity: str = ""

    def __post_init__(self) -> None:
        if not self.identity:
            object.__setattr__(self, "identity", self.name)

    @property
    def module(self) -> str:
        """The module ``python -m`` runs: ``services.<name>``."""
        return f"services.{self.name}"


#: Every process service, in start order.
ROSTER: tuple[Process, ...] = (
    Process("router", up=False, hub=True),
    Process("simulator", up=True),
    Process("localization_bridge", up=True),
    Process("planner", up=True),
    Process("telemetry", up=True),
    Process("vesc_driver", up=False),  # on the car, in place of the simulator
    Process("lidar_driver", up=False),  # on the car: the Hokuyo
    Process("ros2_gateway", up=False),  # beside a ROS 2 system (needs the [ros2] extra)
)


def names() -> tuple[str, ...]:
    """The name of every process service, in roster order."""
    return tuple(p.name for p in ROSTER)


def up_names() -> tuple[str, ...]:
    """The services ``racestack up`` starts as child processes, in start order."""
    return tuple(p.name for p in ROSTER if p.up)


def hub() -> Process:
    """The hub (the Zenoh router): the one entry with ``hub=True``."""
    (only,) = (p for p in ROSTER if p.hub)
    return only


def process(name: str) -> Process:
    """The roster entry called `name` (KeyError when there is none)."""
    for p in ROSTER:
        if p.name == name:
            return p
    raise KeyError(f"no process service {name!r} in the roster ({', '.join(names())})")
