"""The bus with real Zenoh sessions on loopback, two or three sessions in this process.

Every wait has a timeout (and the conftest watchdog ends a test that passes 20 s); every
session is closed by its fixture, also when the test fails.
"""

from __future__ import annotations

import subprocess
import sys
import threading
import time
from collections.abc import Callable, Iterator
from pathlib import Path

import msgpack
import pytest
import zenoh

from shared.bus import Bus, wait_matching
from shared.config.bus import BusSettings
from shared.keys import TOPIC_TYPES
from shared.messages import REGISTRY, DriveCmd, Message, Pose, State

WAIT_S = 5.0

Sample = Callable[[type[Message]], Message]


def _until(cond: Callable[[], bool], timeout_s: float = WAIT_S) -> bool:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if cond():
            return True
        time.sleep(0.005)
    return cond()


@pytest.fixture
def settings(free_port: int) -> BusSettings:
    return BusSettings(car="testcar", listen=[f"tcp/127.0.0.1:{free_port}"])


@pytest.fixture
def hub(settings: BusSettings) -> Iterator[Bus]:
    bus = Bus(settings, "simulator", listen_default=True)
    try:
        yield bus
    finally:
        bus.close()


@pytest.fixture
def peer(hub: Bus) -> Iterator[Bus]:
    bus = Bus(hub.settings, "planner")
    try:
        yield bus
    finally:
        bus.close()


def test_typed_round_trip(hub: Bus, peer: Bus) -> None:
    sub = peer.subscribe(peer.keys.drive_cmd, DriveCmd)
    pub = hub.publisher(hub.keys.drive_cmd, DriveCmd)
    assert pub.raw.congestion_control == zenoh.CongestionControl.BLOCK
    assert pub.wait_matching(WAIT_S)
    sent = pub.put(DriveCmd(stamp_s=1.25, speed_mps=2.5, steering_rad=-0.1))
    got = sub.wait(WAIT_S)
    assert got == sent and got is not None and got.seq == 0
    sent2 = pub.put(DriveCmd(stamp_s=1.30, speed_mps=2.6, steering_rad=-0.1))
    got2 = sub.wait(WAIT_S)
    assert got2 == sent2 and got2 is not None and got2.seq == 1
    assert sub.received == 2 and sub.seq_gaps == 0 and peer.drops.total == 0


def test_every_type_through_a_wildcard_subscription(hub: Bus, peer: Bus, sample: Sample) -> None:
    sub = peer.subscribe(peer.keys.all_data, None, queue_size=64)
    pubs = {
        tag: hub.publisher(hub.keys.key(suffix), REGISTRY[tag], reliable=True)
        for suffix, tag in TOPIC_TYPES.items()
    }
    assert all(wait_matching(p, WAIT_S) for p in pubs.values())
    sent = {tag: p.put(sample(REGISTRY[tag])) for tag, p in pubs.items()}
    got: dict[str, Message] = {}
    deadline = time.monotonic() + WAIT_S
    while len(got) < len(sent) and time.monotonic() < deadline:
        msg = sub.get(timeout_s=0.1)
        if msg is not None:
            got[msg.TYPE] = msg
    assert got == sent
    assert peer.drops.total == 0


def test_invalid_payloads_are_counted_and_do_not_break_later_messages(
    hub: Bus, peer: Bus, sample: Sample
) -> None:
    key = peer.keys.state
    callback_seen = threading.Event()
    sub = peer.subscribe(key, State, callback=lambda _m: callback_seen.set())
    probe = hub.publisher(key, State)
    assert probe.wait_matching(WAIT_S)
    good = sample(State).encode()
    wire = msgpack.unpackb(good, raw=False)
    bad_payloads = {
        "not_msgpack": [b"\xc1garbage", good[: len(good) // 2]],
        "not_a_map": [msgpack.packb([1, 2, 3])],
        "wrong_type": [sample(DriveCmd).encode()],
        "wrong_version": [msgpack.packb({**wire, "v": 2})],
        "missing_field": [msgpack.packb({k: v for k, v in wire.items() if k != "x_m"})],
        "not_finite": [msgpack.packb({**wire, "speed_mps": float("nan")})],
        "out_of_range": [msgpack.packb({**wire, "steering_rad": 3.0})],
    }
    n_bad = sum(len(v) for v in bad_payloads.values())
    for payloads in bad_payloads.values():
        for data in payloads:
            hub.put_raw(key, data)
    assert _until(lambda: peer.drops.count(key) == n_bad), peer.drops.snapshot()
    for reason, payloads in bad_payloads.items():
        assert peer.drops.count(key, reason) == len(payloads), reason
    assert sub.received == 0 and sub.latest() is None and not callback_seen.is_set()
    sent = probe.put(sample(State))
    assert sub.wait(WAIT_S) == sent
    assert callback_seen.wait(WAIT_S)
    assert sub.dropped == n_bad


def test_raising_callback_is_contained(hub: Bus, peer: Bus, sample: Sample) -> None:
    calls: list[Pose] = []

    def callback(msg: Pose) -> None:
        calls.append(msg)
        raise RuntimeError("service bug")

    sub = peer.subscribe(peer.keys.pose, Pose, callback)
    pub = hub.publisher(hub.keys.pose, Pose, reliable=True)
    assert pub.wait_matching(WAIT_S)
    for _ in range(3):
        pub.put(sample(Pose))
    assert _until(lambda: len(calls) == 3)
    assert peer.drops.count(peer.keys.pose, "callback_error") == 3
    assert sub.received == 3 and sub.latest() is not None


def test_liveliness_wait(hub: Bus, peer: Bus) -> None:
    assert peer.wait_alive(["simulator", "planner"], WAIT_S)
    assert hub.wait_alive(["planner"], WAIT_S)
    t0 = time.monotonic()
    assert not peer.wait_alive(["ghost"], 0.3)
    assert time.monotonic() - t0 < 3.0
    extra = Bus(hub.settings, "telemetry")
    try:
        assert peer.wait_alive(["telemetry"], WAIT_S)
    finally:
        extra.close()
    assert _until(lambda: "telemetry" not in peer.alive())
    assert peer.missing_alive(["simulator", "telemetry"]) == {"telemetry"}


def test_other_car_is_invisible(hub: Bus, peer: Bus) -> None:
    other = Bus(hub.settings.model_copy(update={"car": "othercar"}), "intruder")
    try:
        assert other.wait_alive(["simulator"], 0.5) is False
        assert peer.wait_alive(["planner"], WAIT_S)
        assert "intruder" not in peer.alive()
    finally:
        other.close()


def test_wait_matching_times_out_without_subscriber(hub: Bus) -> None:
    pub = hub.publisher(hub.keys.sim_control + "/nobody", DriveCmd)
    t0 = time.monotonic()
    assert not wait_matching(pub, 0.2)
    assert 0.15 < time.monotonic() - t0 < 3.0
    assert not pub.matching


def test_publisher_options_and_type_check(hub: Bus, sample: Sample) -> None:
    pose_pub = hub.publisher(hub.keys.pose, Pose)
    assert pose_pub.raw.congestion_control == zenoh.CongestionControl.DROP
    forced = hub.publisher(hub.keys.pose, Pose, reliable=True)
    assert forced.raw.congestion_control == zenoh.CongestionControl.BLOCK
    assert hub.publisher(hub.keys.drive_cmd, DriveCmd, reliable=False).raw.congestion_control == (
        zenoh.CongestionControl.DROP
    )
    with pytest.raises(TypeError):
        pose_pub.put(sample(DriveCmd))  # type: ignore[arg-type]
    assert pose_pub.next_seq == 0
    pose_pub.put(sample(Pose))
    assert pose_pub.next_seq == 1


def test_session_closed_on_exception(settings: BusSettings) -> None:
    holder: list[Bus] = []
    with pytest.raises(RuntimeError, match="service failed"):
        with Bus(settings, "simulator", listen_default=True) as bus:
            holder.append(bus)
            bus.subscribe(bus.keys.state, State)  # a callback subscriber: would keep us alive
            raise RuntimeError("service failed")
    assert holder[0].closed and holder[0].session.is_closed()
    holder[0].close()  # idempotent


def test_client_mode_through_a_router(settings: BusSettings, sample: Sample) -> None:
    with Bus(settings, "router", listen_default=True, mode="router", announce=False) as router:
        client_settings = settings.model_copy(update={"mode": "client"})
        with Bus(client_settings, "telemetry") as a, Bus(client_settings, "planner") as b:
            sub = a.subscribe(a.keys.drive_cmd, DriveCmd)
            pub = b.publisher(b.keys.drive_cmd, DriveCmd)
            assert pub.wait_matching(WAIT_S)
            sent = pub.put(sample(DriveCmd))
            assert sub.wait(WAIT_S) == sent
            assert router.wait_alive(["telemetry", "planner"], WAIT_S)


def test_a_service_process_exits_after_its_bus_closes(free_port: int) -> None:
    """A callback subscriber keeps a process alive unless the session is closed: Bus does."""
    code = f"""
import sys
from shared.bus import Bus
from shared.config.bus import BusSettings
from shared.messages import State
settings = BusSettings(listen=["tcp/127.0.0.1:{free_port}"])
with Bus(settings, "child", listen_default=True) as bus:
    bus.subscribe(bus.keys.state, State, callback=lambda m: None)
print("closed", flush=True)
"""
    root = Path(__file__).resolve().parents[2]
    proc = subprocess.run(
        [sys.executable, "-c", code], cwd=root, capture_output=True, text=True, timeout=15
    )
    assert proc.returncode == 0, proc.stderr
    assert "closed" in proc.stdout


def test_channel_subscription_recv_in_a_worker_thread(hub: Bus, peer: Bus) -> None:
    """The latency-critical input: records come out of ``recv`` in the consumer's thread,
    garbage and wrong types are counted and skipped, and closing the bus ends ``recv``."""
    chan = peer.subscribe_channel(peer.keys.pose, Pose, capacity=8)
    assert chan.try_recv() is None
    pub = hub.publisher(hub.keys.pose, Pose)
    assert pub.wait_matching(WAIT_S)
    got: list[Pose | None] = []
    done = threading.Event()

    def consume() -> None:
        while (p := chan.recv()) is not None:
            got.append(p)
        got.append(None)
        done.set()

    worker = threading.Thread(target=consume, daemon=True)
    worker.start()
    pub.put(Pose(stamp_s=1.0, x_m=1.0, y_m=2.0, yaw_rad=0.5, cov=None))
    hub.put_raw(hub.keys.pose, b"\xc1garbage")
    hub.put_raw(hub.keys.pose, DriveCmd(stamp_s=1.0, speed_mps=1.0, steering_rad=0.0).encode())
    pub.put(Pose(stamp_s=2.0, x_m=1.5, y_m=2.0, yaw_rad=0.5, cov=None))
    assert _until(lambda: len(got) == 2)
    assert [p.stamp_s for p in got if p] == [1.0, 2.0] and [p.seq for p in got if p] == [0, 1]
    assert chan.received == 2 and chan.seq_gaps == 0
    assert _until(lambda: chan.dropped == 2)
    assert peer.drops.count(peer.keys.pose, "not_msgpack") == 1
    assert peer.drops.count(peer.keys.pose, "wrong_type") == 1
    peer.close()
    assert done.wait(WAIT_S), "recv did not return after the bus closed"
    worker.join(WAIT_S)
    assert got[-1] is None and chan.recv() is None and chan.try_recv() is None


def test_channel_subscription_keeps_the_newest(hub: Bus, peer: Bus) -> None:
    chan = peer.subscribe_channel(peer.keys.pose, Pose, capacity=1)
    pub = hub.publisher(hub.keys.pose, Pose, reliable=True)
    assert pub.wait_matching(WAIT_S)
    pub.put(Pose(stamp_s=0.0, x_m=0.0, y_m=0.0, yaw_rad=0.0, cov=None))
    assert _until(lambda: chan.received == 1 or chan.try_recv() is not None)
    probe = peer.subscribe(peer.keys.pose, Pose, queue_size=8)
    for k in range(1, 6):
        pub.put(Pose(stamp_s=float(k), x_m=0.0, y_m=0.0, yaw_rad=0.0, cov=None))
    assert _until(lambda: probe.received == 5)  # all of them have arrived here too
    last = chan.try_recv()
    assert last is not None and last.stamp_s == 5.0 and chan.try_recv() is None
    assert chan.seq_gaps == 4  # the four overwritten ones
    with pytest.raises(ValueError):
        peer.subscribe_channel(peer.keys.pose, Pose, capacity=0)
