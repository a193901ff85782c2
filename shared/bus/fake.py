"""An in-process stand-in for ``shared.bus.Bus``: a service shell under test without Zenoh.

The publishers are the real ``TypedPublisher`` (sequence numbers, ``try_put`` and the fault
counting) over a recorder of payloads (a ``RawPublisher``); the subscriptions are the real
``Subscription`` / a queue-backed channel, fed by ``deliver``. What a shell published reads
back decoded, so validated. Like the other pure modules of ``shared.bus`` it imports no
zenoh::

    bus = FakeBus()
    svc = BridgeService(bus, LocalizationSettings())
    bus.deliver(bus.keys.odom, Odom(stamp_s=1.0, speed_mps=2.0, steering_rad=0.0))
    states = bus.sent(bus.keys.state, State)"""

from __future__ import annotations

import queue
from collections.abc import Callable
from typing import Any

from shared.bus.counters import DropCounter, FaultCounter
from shared.bus.pubsub import Subscription, TypedPublisher
from shared.keys import Keys
from shared.messages import Message, decode


class RecordingRaw:
    """Stands in for ``zenoh.Publisher`` (a ``RawPublisher``): keeps every payload."""

    def __init__(self) -> None:
        self.sent: list[bytes] = []
        self.undeclared = False

    def put(self, data: bytes) -> None:
        """Keep one payload."""
        self.sent.append(data)

    def undeclare(self) -> None:
        """Note that the publisher was undeclared (the payloads stay readable)."""
        self.undeclared = True


class FakeChannel:
    """Stands in for ``ChannelSubscription``: ``recv`` blocks until a record or ``close``."""

    def __init__(self, key: str) -> None:
        self.key = key
        self._queue: queue.Queue[Message | None] = queue.Queue()

    def put(self, record: Message | None) -> None:
        """Hand over one record (None: the bus closed)."""
        self._queue.put(record)

    def recv(self) -> Any:
        """The next record; None once closed."""
        return self._queue.get()

    def try_recv(self) -> Any:
        """The next record if one is queued, else None (never waits; a close stays queued
        for ``recv``)."""
        try:
            record = self._queue.get_nowait()
        except queue.Empty:
            return None
        if record is None:
            self._queue.put(None)
        return record


class FakeBus:
    """What the service shells use of ``Bus``, in process (see the module docstring)."""

    def __init__(self, car: str = "car0") -> None:
        self.keys = Keys(car)
        self.drops = DropCounter()
        self.faults = FaultCounter()
        self.raws: dict[str, RecordingRaw] = {}
        self.subs: dict[str, list[Subscription[Any]]] = {}
        self.channels: dict[str, FakeChannel] = {}
        self.alive_declared: list[str] = []
        self.closed = False

    def publisher(self, key: str, msg_type: type[Message], **_: Any) -> TypedPublisher[Any]:
        """A real ``TypedPublisher`` over a recorder."""
        return TypedPublisher(self.raws.setdefault(key, RecordingRaw()), key, msg_type, self.faults)

    def subscribe(
        self,
        key: str,
        msg_type: type[Message] | None,
        callback: Callable[[Any], None] | None = None,
        *,
        queue_size: int = 0,
    ) -> Subscription[Any]:
        """A real ``Subscription``; ``deliver`` feeds it."""
        sub: Subscription[Any] = Subscription(key, msg_type, self.drops, callback, queue_size)
        self.subs.setdefault(key, []).append(sub)
        return sub

    def subscribe_channel(self, key: str, msg_type: type[Message], *, capacity: int = 1) -> Any:
        """A queue-backed channel; ``deliver`` feeds it, ``close`` ends its ``recv``."""
        channel = self.channels[key] = FakeChannel(key)
        return channel

    def declare_alive(self, service: str) -> None:
        """Note the liveliness token."""
        self.alive_declared.append(service)

    def deliver(self, key: str, record: Message) -> None:
        """Hand `record` to every subscription and channel of `key` (as Zenoh would)."""
        for sub in self.subs.get(key, []):
            sub._deliver(key, record)
        if key in self.channels:
            self.channels[key].put(record)

    def sent(self, key: str, msg_type: type[Message]) -> list[Any]:
        """Every record published on `key`, decoded (and so validated)."""
        raw = self.raws.get(key)
        return [decode(b, msg_type) for b in raw.sent] if raw else []

    def close(self) -> None:
        """End every channel's ``recv``."""
        self.closed = True
        for channel in self.channels.values():
            channel.put(None)
