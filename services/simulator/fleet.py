"""Several cars in one simulator process (issue #24): each car's view of the one bus, and
the incident line the simulator says on ``events/log`` (and the launcher reads back).

``CarView(bus, car)`` is the bus with another car's keys: publishers and subscriptions on
``racestack/<car>/...`` over the same session, the same drop and fault counters (keyed by
full key, so the car is in every count). The simulator builds one ``SimulatorService`` per
extra car on such a view; the first car's service runs the loop for all.

An incident (``shared.vehicle.contact.Incident``) is one ``events/log`` warning of the
simulator, ``incident_line`` / ``parse_incident``::

    contact 1: car1 hit car0 at t = 12.345 s, depth 0.021 m, 1.52 m/s closing
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from typing import Any

from shared.keys import Keys

__all__ = ["CarView", "IncidentRecord", "incident_line", "parse_incident"]


class CarView:
    """`bus` seen as car `car`'s: its keys, the same session and counters.

    Args:
        bus: the open bus (``shared.bus.Bus`` or the fake).
        car: the car name (a safe key chunk).
    """

    def __init__(self, bus: Any, car: str) -> None:
        self._bus = bus
        self.keys = Keys(car)
        self.drops = bus.drops
        self.faults = bus.faults

    def publisher(self, key: str, msg_type: Any, **kw: Any) -> Any:
        """``Bus.publisher`` on a full key of this car."""
        return self._bus.publisher(key, msg_type, **kw)

    def subscribe(self, key: str, msg_type: Any, callback: Any = None, *,
                  queue_size: int = 0) -> Any:
        """``Bus.subscribe`` on a full key of this car."""
        return self._bus.subscribe(key, msg_type, callback, queue_size=queue_size)

    def subscribe_channel(self, key: str, msg_type: Any, *, capacity: int = 1) -> Any:
        """``Bus.subscribe_channel`` on a full key of this car."""
        return self._bus.subscribe_channel(key, msg_type, capacity=capacity)

    def __getattr__(self, name: str) -> Any:  # anything else: the bus's own
        return getattr(self._bus, name)


@dataclass(frozen=True)
class IncidentRecord:
    """One contact as the simulator said it.

    Attributes:
        number: the incident's number in the run (1, 2, ...).
        striker, struck: car names (striker "none": undecided; then `struck` is "a+b").
        t_s: simulation time [s]; depth_m: penetration at the start [m]; closing_mps: the
            relative speed along the normal at the start [m/s].
    """

    number: int
    striker: str
    struck: str
    t_s: float
    depth_m: float
    closing_mps: float


def incident_line(rec: IncidentRecord) -> str:
    """The ``events/log`` text of an incident (module docstring)."""
    who = (f"{rec.striker} hit {rec.struck}" if rec.striker != "none"
           else f"{rec.struck.replace('+', ' and ')} touched")
    return (f"contact {rec.number}: {who} at t = {rec.t_s:.3f} s, depth {rec.depth_m:.3f} m, "
            f"{rec.closing_mps:.2f} m/s closing")


_LINE = re.compile(
    r"contact (?P<n>\d+): (?:(?P<a>[\w-]+) hit (?P<b>[\w-]+)|(?P<c>[\w-]+) and (?P<d>[\w-]+) "
    r"touched) at t = (?P<t>[-\d.]+) s, depth (?P<depth>[-\d.]+) m, (?P<v>[-\d.]+) m/s closing"
)


def parse_incident(text: str) -> IncidentRecord | None:
    """The incident of an ``incident_line`` text (None: not one)."""
    m = _LINE.fullmatch(text.strip())
    if m is None:
        return None
    if m["a"]:
        striker, struck = m["a"], m["b"]
    else:
        striker, struck = "none", f"{m['c']}+{m['d']}"
    return IncidentRecord(int(m["n"]), striker, struck, float(m["t"]), float(m["depth"]),
                          float(m["v"]))
