"""Several cars in one simulator process (issue #24): each car's view of the one bus.

``CarView(bus, car)`` is the bus with another car's keys: publishers and subscriptions on
``racestack/<car>/...`` over the same session, the same drop and fault counters (keyed by
full key, so the car is in every count). The simulator builds one ``SimulatorService`` per
extra car on such a view; the first car's service runs the loop for all.

An incident is one ``events/log`` warning of the simulator
(``shared.vehicle.incidents.incident_line``).
"""

from __future__ import annotations

from typing import Any

from shared.keys import Keys

__all__ = ["CarView"]


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
