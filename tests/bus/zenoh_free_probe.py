"""The pure parts of ``shared.bus`` and its fake bus, run where zenoh cannot be imported.

Run as a script (by ``test_bus_package.py``, in a fresh interpreter): a meta-path finder
makes every ``import zenoh`` fail and notes the attempt; then the pure modules and the fake
bus are imported and exercised (publish and subscribe on ``FakeBus``, the counters, slots,
channel stats, the drop reporter). It checks that zenoh was never asked for, then that a
session name (``shared.bus.Bus``) does ask for it (so the finder works), and prints
``zenoh-free: ok``. Any failure is an exception (exit code 1).
"""

from __future__ import annotations

import importlib.abc
import math
import sys
from collections.abc import Sequence
from types import ModuleType
from typing import Any

#: The zenoh modules an import asked for (every one was refused).
ATTEMPTS: list[str] = []


class BlockZenoh(importlib.abc.MetaPathFinder):
    """Refuses ``zenoh`` and its submodules as if they were not installed."""

    def find_spec(
        self, fullname: str, path: Sequence[str] | None, target: ModuleType | None = None
    ) -> None:
        """Raise ``ModuleNotFoundError`` for zenoh; None (ask the next finder) otherwise."""
        if fullname == "zenoh" or fullname.startswith("zenoh."):
            ATTEMPTS.append(fullname)
            raise ModuleNotFoundError(f"No module named {fullname!r} (blocked)", name=fullname)
        return None


class Sample:
    """A received sample as the pure subscriptions read it (``RawSample``)."""

    class Payload:
        def __init__(self, data: bytes) -> None:
            self.data = data

        def to_bytes(self) -> bytes:
            return self.data

    def __init__(self, key: str, data: bytes, kind: str = "SampleKind.PUT") -> None:
        self.key_expr = key
        self.kind = kind
        self.payload = Sample.Payload(data)


class Matching:
    """A raw publisher that reports a matching subscriber (``MatchingPublisher``)."""

    class Status:
        matching = True

    matching_status = Status()

    def put(self, payload: bytes) -> None:
        pass

    def undeclare(self) -> None:
        pass


def exercise() -> None:
    """Import and use the pure modules and the fake bus; raise on any wrong result."""
    from shared.bus import (
        ChannelSubscription,
        DropCounter,
        DropOldestQueue,
        DropReporter,
        FaultCounter,
        LatestSlot,
        SeqTracker,
        Subscription,
        wait_matching,
    )
    from shared.bus.fake import FakeBus
    from shared.messages import DriveCmd, LogEvent, State

    def cmd(stamp_s: float = 1.0) -> DriveCmd:
        return DriveCmd(stamp_s=stamp_s, speed_mps=2.0, steering_rad=0.1)

    def state(stamp_s: float) -> State:
        return State(
            stamp_s=stamp_s, x_m=1.0, y_m=2.0, yaw_rad=0.0, speed_mps=1.0, yaw_rate_radps=0.0,
            steering_rad=0.0, source_stamp_s=stamp_s, valid=True,
        )  # fmt: skip

    # the fake bus: typed publishers over recorders, subscriptions fed by deliver
    bus = FakeBus()
    pub = bus.publisher(bus.keys.drive_cmd, DriveCmd)
    assert pub.put(cmd()).seq == 0 and pub.put(cmd(2.0)).seq == 1
    assert pub.try_put(stamp_s=math.nan, speed_mps=1.0, steering_rad=0.0) is None
    assert [c.stamp_s for c in bus.sent(bus.keys.drive_cmd, DriveCmd)] == [1.0, 2.0]
    assert bus.faults.snapshot() == {(bus.keys.drive_cmd, "not_finite"): 1}
    seen: list[Any] = []
    sub = bus.subscribe(bus.keys.state, State, seen.append, queue_size=2)
    for t in (1.0, 2.0, 3.0):
        bus.deliver(bus.keys.state, state(t).with_seq(int(t) * 2))  # 0, 2 and 4: gaps
    assert sub.take() == seen[-1] and sub.take() is None and len(seen) == 3
    assert [s.stamp_s for s in sub.drain()] == [2.0, 3.0] and sub.overflowed == 1
    assert sub.received == 3 and sub.seq_gaps == 2
    chan = bus.subscribe_channel("k/channel", State)
    bus.deliver("k/channel", state(4.0))
    assert chan.recv().stamp_s == 4.0
    bus.close()
    assert chan.recv() is None and bus.closed

    # the decoding of raw samples and the drop counts
    drops = DropCounter()
    raw_sub = Subscription("k", DriveCmd, drops)
    raw_sub.on_sample(Sample("k", cmd().with_seq(0).encode()))
    raw_sub.on_sample(Sample("k", b"garbage"))
    raw_sub.on_sample(Sample("k", b"", kind="SampleKind.DELETE"))
    raw_sub.on_sample(Sample("k", state(1.0).encode()))
    assert raw_sub.received == 1 and raw_sub.latest() is not None
    assert drops.snapshot() == {
        ("k", "not_msgpack"): 1, ("k", "not_put"): 1, ("k", "wrong_type"): 1,
    }  # fmt: skip

    # a channel's counts add up
    displaced = DropCounter()
    chan2 = ChannelSubscription("k", DriveCmd, DropCounter(), displaced=displaced)
    for sample in (Sample("k", b"junk"), Sample("k", cmd().with_seq(0).encode()),
                   Sample("k", cmd().with_seq(1).encode())):
        chan2.on_sample(sample)
    assert chan2.try_recv() is not None
    stats = chan2.stats()
    assert (stats.received, stats.valid, stats.rejected, stats.overwritten) == (3, 1, 1, 1)
    assert stats.received == stats.valid + stats.rejected + stats.dropped + stats.pending
    assert displaced.snapshot() == {("k", "overwritten"): 1}

    # counters, slots, sequence gaps, matching
    faults = FaultCounter()
    with faults.guard("k"):
        cmd(math.inf)
    assert faults.count("k", "not_finite") == 1
    slot: LatestSlot[int] = LatestSlot()
    slot.put(1)
    slot.put(2)
    assert slot.wait(0.0) == 2 and slot.take() is None and slot.overwritten == 1
    queue: DropOldestQueue[int] = DropOldestQueue(2)
    assert [queue.put(i) for i in range(3)] == [False, False, True] and queue.drain() == [1, 2]
    seq = SeqTracker()
    assert [seq.gap("k", s) for s in (0, 1, 5, 0, 1)] == [0, 0, 3, 0, 0]
    assert wait_matching(Matching(), 0.0)

    # the drop reporter on the fake bus
    bus = FakeBus()
    now = [0.0]
    reporter = DropReporter(bus, "probe", clock=lambda: now[0], wall_clock=lambda: 10.0)
    assert not reporter.poll()
    bus.drops.record(bus.keys.state, "not_msgpack")
    now[0] = 2.0
    assert reporter.poll()
    (event,) = bus.sent(bus.keys.events_log, LogEvent)
    assert event.source == "probe" and "rejected 1 messages" in event.text


def main() -> None:
    """Block zenoh, exercise the pure parts, check zenoh was never asked for."""
    assert "zenoh" not in sys.modules, "zenoh was imported before the probe started"
    sys.meta_path.insert(0, BlockZenoh())
    exercise()
    assert not ATTEMPTS, f"the pure parts asked for {ATTEMPTS}"
    assert not any(m == "zenoh" or m.startswith("zenoh.") for m in sys.modules)
    assert "shared.bus.session" not in sys.modules
    try:  # the session's names do need zenoh: the finder is in the way
        from shared.bus import Bus  # noqa: F401
    except ModuleNotFoundError as exc:
        assert exc.name == "zenoh", exc
    else:
        raise AssertionError("shared.bus.Bus was importable with zenoh blocked")
    assert ATTEMPTS == ["zenoh"], ATTEMPTS
    print("zenoh-free: ok")


if __name__ == "__main__":
    main()
