"""No valid sample displaced, every drop counted (issue 15), on real Zenoh sessions on loopback.

Garbage floods ``vehicle/pose`` at 2000 Hz while valid poses arrive at 40 Hz; the consumer is
a thread blocked in ``recv`` on the same ``Bus.subscribe_channel`` the localization bridge
uses (capacity ``[localization] pose_queue``, 4: a consumer late by up to three poses
loses none). Every valid pose must reach it, and the channel's counts must add up:
received = valid + rejected + dropped (+ pending, 0 at the end). A second test makes the
consumer slower than its input so valid records ARE overwritten, and checks that those are
counted and reported on ``events/log`` too.
"""

from __future__ import annotations

import math
import threading
import time
from collections.abc import Callable, Iterator

import msgpack
import pytest

from shared.bus import Bus, DropReporter
from shared.config.bus import BusSettings
from shared.config.localization import LocalizationSettings
from shared.messages import DriveCmd, LogEvent, Pose

FLOOD_S = 3.0  #: length of the flood [s]
GARBAGE_HZ = 2000.0
VALID_HZ = 40.0
WAIT_S = 10.0


def _until(cond: Callable[[], bool], timeout_s: float = WAIT_S) -> bool:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if cond():
            return True
        time.sleep(0.01)
    return cond()


@pytest.fixture
def hub(free_port: int) -> Iterator[Bus]:
    bus = Bus(BusSettings(car="floodcar", listen=[f"tcp/127.0.0.1:{free_port}"]), "simulator",
              listen_default=True)
    try:
        yield bus
    finally:
        bus.close()


@pytest.fixture
def peer(hub: Bus) -> Iterator[Bus]:
    bus = Bus(hub.settings, "localization_bridge")
    try:
        yield bus
    finally:
        bus.close()


def _garbage() -> list[bytes]:
    """Three kinds of invalid payload: not msgpack, the wrong type, a NaN field."""
    nan_pose = msgpack.unpackb(Pose(stamp_s=1.0, x_m=0.0, y_m=0.0, yaw_rad=0.0).encode(0))
    nan_pose["x_m"] = math.nan
    return [
        b"\xc1 not msgpack",
        DriveCmd(stamp_s=1.0, speed_mps=1.0, steering_rad=0.0).encode(0),
        msgpack.packb(nan_pose),
    ]


def _consume(chan, got: list[Pose], per_record_s: float = 0.0) -> threading.Thread:
    def run() -> None:
        while (p := chan.recv()) is not None:
            got.append(p)
            if per_record_s:
                time.sleep(per_record_s)

    worker = threading.Thread(target=run, name="consumer", daemon=True)
    worker.start()
    return worker


def _flood(hub: Bus, stop: threading.Event, sent: list[int]) -> threading.Thread:
    """Garbage at GARBAGE_HZ on the pose key, in bursts of 10 every 5 ms."""
    payloads = _garbage()
    key = hub.keys.pose

    def run() -> None:
        t_next = time.monotonic()
        burst = 10
        while not stop.is_set():
            for i in range(burst):
                hub.put_raw(key, payloads[(sent[0] + i) % len(payloads)])
            sent[0] += burst
            t_next += burst / GARBAGE_HZ
            delay = t_next - time.monotonic()
            if delay > 0:
                time.sleep(delay)

    worker = threading.Thread(target=run, name="flood", daemon=True)
    worker.start()
    return worker


def test_garbage_flood_never_displaces_a_valid_pose(hub: Bus, peer: Bus) -> None:
    capacity = LocalizationSettings().pose_queue  # what the bridge subscribes with
    chan = peer.subscribe_channel(peer.keys.pose, Pose, capacity=capacity)
    log_sub = hub.subscribe(hub.keys.events_log, LogEvent, queue_size=100)
    reporter = DropReporter(peer, "localization_bridge", period_s=0.0)
    assert _until(lambda: log_sub.raw is not None)
    # the valid poses go out reliably (BLOCK): this test is about the channel, not the
    # transport, so none may be lost before they reach it
    pub = hub.publisher(hub.keys.pose, Pose, reliable=True)
    assert pub.wait_matching(WAIT_S)
    got: list[Pose] = []
    consumer = _consume(chan, got)
    stop = threading.Event()
    garbage_sent = [0]
    flood = _flood(hub, stop, garbage_sent)
    valid_sent = 0
    t_end = time.monotonic() + FLOOD_S
    t_next = time.monotonic()
    try:
        while time.monotonic() < t_end:
            pub.put(Pose(stamp_s=time.time(), x_m=0.01 * valid_sent, y_m=0.0, yaw_rad=0.0))
            valid_sent += 1
            t_next += 1.0 / VALID_HZ
            time.sleep(max(0.0, t_next - time.monotonic()))
    finally:
        stop.set()
        flood.join(WAIT_S)
    total = valid_sent + garbage_sent[0]
    assert _until(lambda: chan.stats().received == total and chan.stats().pending == 0), (
        chan.stats(), total)
    s = chan.stats()
    rate = garbage_sent[0] / FLOOD_S
    print(f"\nflood: {garbage_sent[0]} garbage ({rate:.0f} Hz) + {valid_sent} valid poses in "
          f"{FLOOD_S:g} s -> {s}")
    assert rate > 0.8 * GARBAGE_HZ, "the flood did not reach its rate"
    assert s.received == s.valid + s.rejected + s.dropped + s.pending
    assert s.valid == valid_sent and s.dropped == 0 and s.rejected == garbage_sent[0]
    assert [p.seq for p in got] == list(range(valid_sent)), "every valid pose, in order"
    assert chan.seq_gaps == 0
    assert peer.drops.count(peer.keys.pose) == garbage_sent[0]  # the bus's count by reason
    for reason in ("not_msgpack", "wrong_type"):
        assert peer.drops.count(peer.keys.pose, reason) > 0
    assert reporter.poll()  # reported on events/log, as every service does
    assert _until(lambda: any("rejected" in e.text for e in log_sub.drain()))
    peer.close()
    consumer.join(WAIT_S)
    assert not consumer.is_alive(), "recv returns None once the bus is closed"


def test_overwritten_valid_records_are_counted_and_reported(hub: Bus, peer: Bus) -> None:
    """A consumer slower than its input: the newest is kept, the pushed-out ones counted."""
    chan = peer.subscribe_channel(peer.keys.pose, Pose, capacity=1)
    log_sub = hub.subscribe(hub.keys.events_log, LogEvent, queue_size=100)
    reporter = DropReporter(peer, "localization_bridge", period_s=0.0)
    pub = hub.publisher(hub.keys.pose, Pose, reliable=True)
    assert pub.wait_matching(WAIT_S)
    got: list[Pose] = []
    consumer = _consume(chan, got, per_record_s=0.02)
    n = 200
    for k in range(n):
        pub.put(Pose(stamp_s=float(k), x_m=0.0, y_m=0.0, yaw_rad=0.0))
        time.sleep(0.001)
    hub.put_raw(hub.keys.pose, b"\xc1")
    assert _until(lambda: chan.stats().received == n + 1 and chan.stats().pending == 0)
    time.sleep(0.05)
    s = chan.stats()
    assert s.received == s.valid + s.rejected + s.dropped + s.pending
    assert s.rejected == 1 and s.overwritten > 0 and s.dropped == s.overwritten
    assert s.valid == len(got) and got[-1].stamp_s == float(n - 1), "the newest is never lost"
    assert peer.displaced.count(peer.keys.pose, "overwritten") == s.overwritten
    assert reporter.poll()
    assert _until(lambda: any("dropped" in e.text and "overwritten" in e.text
                              for e in log_sub.drain()))
    peer.close()
    consumer.join(WAIT_S)


def test_stale_records_are_dropped_and_counted(hub: Bus, peer: Bus) -> None:
    """``max_age_s``: a record older than that when taken is dropped and counted as stale."""
    chan = peer.subscribe_channel(peer.keys.pose, Pose, capacity=4, max_age_s=1.0)
    pub = hub.publisher(hub.keys.pose, Pose, reliable=True)
    assert pub.wait_matching(WAIT_S)
    pub.put(Pose(stamp_s=time.time() - 5.0, x_m=0.0, y_m=0.0, yaw_rad=0.0))
    pub.put(Pose(stamp_s=time.time(), x_m=1.0, y_m=0.0, yaw_rad=0.0))
    assert _until(lambda: chan.stats().received == 2)
    fresh = chan.recv(timeout_s=WAIT_S)
    assert fresh is not None and fresh.x_m == 1.0
    assert chan.recv(timeout_s=0.05) is None  # a timeout
    s = chan.stats()
    assert (s.received, s.valid, s.stale, s.dropped, s.pending) == (2, 1, 1, 1, 0)
    assert peer.displaced.count(peer.keys.pose, "stale") == 1


def test_a_full_subscription_queue_counts_what_it_drops(hub: Bus, peer: Bus) -> None:
    """The callback subscription's bounded queue: the dropped oldest are counted too."""
    sub = peer.subscribe(peer.keys.pose, Pose, queue_size=2)
    pub = hub.publisher(hub.keys.pose, Pose, reliable=True)
    assert pub.wait_matching(WAIT_S)
    for k in range(5):
        pub.put(Pose(stamp_s=float(k), x_m=0.0, y_m=0.0, yaw_rad=0.0))
    assert _until(lambda: sub.received == 5)
    assert [p.stamp_s for p in sub.drain()] == [3.0, 4.0]
    assert sub.overflowed == 3 == peer.displaced.count(peer.keys.pose, "queue_full")
