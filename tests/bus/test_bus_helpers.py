"""Bus helpers that need no network: drop counting and logging, hand-over slots, configs."""

from __future__ import annotations

import logging
import threading
import time

import pytest
import zenoh

from shared.bus import DropCounter, DropOldestQueue, LatestSlot, Subscription, zenoh_config
from shared.config.bus import BusSettings
from shared.messages import DriveCmd, State


class FakeClock:
    def __init__(self) -> None:
        self.t = 100.0

    def __call__(self) -> float:
        return self.t


def test_drop_counter_counts_per_key_and_reason() -> None:
    d = DropCounter()
    d.record("k1", "not_msgpack")
    d.record("k1", "not_msgpack")
    d.record("k1", "wrong_type")
    d.record("k2", "not_msgpack")
    assert d.total == 4
    assert d.count("k1") == 3 and d.count(reason="not_msgpack") == 3
    assert d.count("k2", "wrong_type") == 0
    assert d.snapshot() == {
        ("k1", "not_msgpack"): 2,
        ("k1", "wrong_type"): 1,
        ("k2", "not_msgpack"): 1,
    }


def test_drop_logging_is_rate_limited(caplog: pytest.LogCaptureFixture) -> None:
    clock = FakeClock()
    d = DropCounter(summary_interval_s=5.0, clock=clock)
    with caplog.at_level(logging.WARNING, logger="racestack.bus"):
        for _ in range(100):  # a burst: one line
            d.record("k", "not_msgpack", "garbage")
        assert len(caplog.records) == 1
        clock.t += 1.0
        d.record("k", "not_msgpack", "garbage")
        assert len(caplog.records) == 1
        clock.t += 5.0
        d.record("k", "not_msgpack", "latest one")  # summary of the 100 + this one
        assert len(caplog.records) == 2
        assert "101 more" in caplog.records[-1].getMessage()
        assert "latest one" in caplog.records[-1].getMessage()
        d.record("k", "wrong_type", "other reason")  # a new pair logs at once
        assert len(caplog.records) == 3
        d.record("k", "wrong_type", "again")
        d.flush()
        assert len(caplog.records) == 4 and "1 more" in caplog.records[-1].getMessage()
        d.flush()  # nothing pending
        assert len(caplog.records) == 4
    assert d.total == 104


def test_latest_slot() -> None:
    s: LatestSlot[int] = LatestSlot()
    assert s.peek() is None and s.take() is None and s.wait(0.01) is None
    s.put(1)
    s.put(2)
    assert s.overwritten == 1
    assert s.peek() == 2 and s.take() == 2 and s.take() is None and s.peek() == 2
    threading.Timer(0.05, s.put, args=(3,)).start()
    t0 = time.monotonic()
    assert s.wait(5.0) == 3
    assert time.monotonic() - t0 < 4.0


def test_drop_oldest_queue() -> None:
    q: DropOldestQueue[int] = DropOldestQueue(3)
    for i in range(5):
        q.put(i)
    assert q.dropped == 2 and len(q) == 3
    assert q.get() == 2
    assert q.drain() == [3, 4] and q.get(0.01) is None
    with pytest.raises(ValueError):
        DropOldestQueue(0)


class FakeSample:
    """Just enough of zenoh.Sample for Subscription.on_sample."""

    def __init__(self, key: str, payload: object, kind: zenoh.SampleKind = zenoh.SampleKind.PUT):
        self.key_expr = key
        self.kind = kind
        self.payload = payload


class Payload:
    def __init__(self, data: bytes) -> None:
        self.data = data

    def to_bytes(self) -> bytes:
        return self.data


def _cmd(seq: int) -> bytes:
    return DriveCmd(stamp_s=1.0, speed_mps=1.0, steering_rad=0.0).with_seq(seq).encode()


def test_subscription_callback_never_raises() -> None:
    drops = DropCounter()
    seen: list[DriveCmd] = []

    def bad_callback(msg: DriveCmd) -> None:
        seen.append(msg)
        raise RuntimeError("boom")

    sub = Subscription("k", DriveCmd, drops, bad_callback, queue_size=2)
    sub.on_sample(FakeSample("k", Payload(b"garbage")))  # type: ignore[arg-type]
    sub.on_sample(FakeSample("k", Payload(_cmd(0))))  # type: ignore[arg-type]
    sub.on_sample(FakeSample("k", None))  # type: ignore[arg-type]  # internal error
    sub.on_sample(FakeSample("k", Payload(b""), zenoh.SampleKind.DELETE))  # type: ignore[arg-type]
    state = State(
        stamp_s=0.0, x_m=0, y_m=0, yaw_rad=0, speed_mps=0, yaw_rate_radps=0,
        steering_rad=0, source_stamp_s=0, valid=True,
    )  # fmt: skip
    sub.on_sample(FakeSample("k", Payload(state.encode())))  # type: ignore[arg-type]
    assert len(seen) == 1 and sub.received == 1
    assert drops.snapshot() == {
        ("k", "not_msgpack"): 1,
        ("k", "callback_error"): 1,
        ("k", "internal_error"): 1,
        ("k", "not_put"): 1,
        ("k", "wrong_type"): 1,
    }
    assert sub.dropped == 5


def test_subscription_hand_over_and_seq_gaps() -> None:
    sub = Subscription("k", DriveCmd, DropCounter(), queue_size=2)
    for seq in (0, 1, 4, 5):  # 2 and 3 lost
        sub.on_sample(FakeSample("k", Payload(_cmd(seq))))  # type: ignore[arg-type]
    assert sub.received == 4 and sub.seq_gaps == 2
    assert sub.latest() is not None and sub.latest().seq == 5  # type: ignore[union-attr]
    assert sub.overflowed == 2
    assert [m.seq for m in sub.drain()] == [4, 5]
    assert sub.take().seq == 5 and sub.take() is None  # type: ignore[union-attr]
    sub.on_sample(FakeSample("k", Payload(_cmd(0))))  # type: ignore[arg-type]  # restart
    assert sub.seq_gaps == 2
    no_queue = Subscription("k", DriveCmd, DropCounter())
    with pytest.raises(RuntimeError):
        no_queue.get()


def test_zenoh_config_has_scouting_off_and_explicit_endpoints() -> None:
    cfg = zenoh_config(BusSettings(), listen_default=False)
    assert cfg.get_json("scouting/multicast/enabled") == "false"
    assert cfg.get_json("scouting/gossip/enabled") == "true"
    assert cfg.get_json("listen/endpoints") == '["tcp/127.0.0.1:0"]'
    assert cfg.get_json("connect/endpoints") == '["tcp/127.0.0.1:7447"]'
    hub = zenoh_config(BusSettings(), listen_default=True, mode="router")
    assert hub.get_json("mode") == '"router"'
    assert hub.get_json("listen/endpoints") == '["tcp/127.0.0.1:7447"]'
