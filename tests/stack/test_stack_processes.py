"""The distributed stack as real processes on loopback (issue 4's acceptance tests).

One stack (simulator, localization bridge, planner) is started for the module; this test
process hosts the Zenoh hub on a free loopback port and watches the traffic. Tests run in
file order: a lap, garbage on every subscribed key, then the planner killed and restarted.
Every process is stopped by PID with timeouts in the fixture's teardown.
"""

from __future__ import annotations

import math
import signal
import threading
import time
from pathlib import Path

import msgpack
import pytest

from services.tools.launcher.supervisor import Supervisor, service_argv
from shared.bus import Bus
from shared.config import load_config
from shared.messages import Imu, LapEvent, LogEvent, SimControl, SimTruth
from shared.net import free_loopback_port

pytestmark = pytest.mark.slow
SERVICES = ("simulator", "localization_bridge", "planner")


class Watcher:
    """Collects lap events, logs and the newest truth from the bus (callbacks only enqueue)."""

    def __init__(self, bus: Bus) -> None:
        self.lock = threading.Lock()
        self.laps: list[LapEvent] = []
        self.logs: list[LogEvent] = []
        self.truth: list[SimTruth] = []
        bus.subscribe(bus.keys.lap, LapEvent, callback=self._lap)
        bus.subscribe(bus.keys.events_log, LogEvent, callback=self._log)
        bus.subscribe(bus.keys.sim_truth, SimTruth, callback=self._truth)

    def _lap(self, m: LapEvent) -> None:
        with self.lock:
            self.laps.append(m)

    def _log(self, m: LogEvent) -> None:
        with self.lock:
            self.logs.append(m)

    def _truth(self, m: SimTruth) -> None:
        with self.lock:
            self.truth.append(m)
            del self.truth[:-2000]

    def latest_truth(self) -> SimTruth | None:
        with self.lock:
            return self.truth[-1] if self.truth else None

    def wait_for(self, pred, timeout_s: float) -> bool:
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            if pred():
                return True
            time.sleep(0.02)
        return False


@pytest.fixture(scope="module")
def stack(tmp_path_factory: pytest.TempPathFactory):
    tmp = tmp_path_factory.mktemp("stack")
    cfg_path = tmp / "stack.toml"
    cfg_path.write_text(f'[bus]\nlisten = ["tcp/127.0.0.1:{free_loopback_port()}"]\n')
    cfg = load_config(cfg_path)
    sup = Supervisor(log_dir=tmp / "logs")
    with Bus(cfg.bus, "test", listen_default=True, mode="router") as bus:
        try:
            watcher = Watcher(bus)
            for name in SERVICES:
                sup.start(name, service_argv(name, str(cfg_path)))
            alive = sup.wait_until(lambda: not bus.missing_alive(SERVICES), timeout_s=90.0)
            if not alive:
                logs = "\n".join(
                    f"--- {c.name} (exit {c.exit_code()})\n{c.log_path.read_text()[-2000:]}"
                    for c in sup.children
                    if c.log_path and c.log_path.exists()
                )
                pytest.fail(f"stack did not come up; missing {bus.missing_alive(SERVICES)}\n{logs}")
            yield {"bus": bus, "sup": sup, "watch": watcher, "cfg_path": cfg_path, "cfg": cfg}
        finally:
            codes = sup.stop_all(grace_s=5.0)
            assert all(c is not None for c in codes.values()), f"processes left running: {codes}"


def test_one_lap_in_real_time_without_leaving_the_track(stack) -> None:
    bus, watch = stack["bus"], stack["watch"]
    control = bus.publisher(bus.keys.sim_control, SimControl)
    assert control.wait_matching(60.0)  # the simulator subscribes once its lidar map is built
    control.put(SimControl(stamp_s=time.time(), action="reset"))
    t0 = time.monotonic()
    got_lap = watch.wait_for(lambda: any(e.kind == "lap" for e in watch.laps), timeout_s=60.0)
    assert got_lap, f"no lap event in 60 s; events: {watch.laps}"
    wall = time.monotonic() - t0
    lap = next(e for e in watch.laps if e.kind == "lap")
    assert lap.off_track_events == 0
    assert not [e for e in watch.laps if e.kind == "off_track"]
    assert lap.max_abs_e_con_m is not None and lap.max_abs_e_con_m < 0.6
    # a flying lap of the 42 m paperlike track (after the out lap), raced in real time
    assert 5.0 < lap.lap_time_s < 20.0
    assert wall >= lap.lap_time_s - 0.5


def _garbage_payloads(bus: Bus, key: str) -> list[bytes]:
    valid = Imu(stamp_s=time.time(), yaw_rate_radps=0.0, ax_mps2=0.0, ay_mps2=0.0).encode()
    nan_cmd = msgpack.packb(
        {
            "type": "drive_cmd",
            "v": 1,
            "stamp_s": time.time(),
            "seq": 0,
            "speed_mps": math.nan,
            "steering_rad": 0.0,
        }
    )
    future = msgpack.packb(
        {
            "type": "drive_cmd",
            "v": 99,
            "stamp_s": time.time(),
            "seq": 0,
            "speed_mps": 1.0,
            "steering_rad": 0.0,
        }
    )
    return [
        b"\x00\xffgarbage",
        valid[: len(valid) // 2],
        msgpack.packb([1, 2, 3]),
        nan_cmd,
        future,
        b"",
    ] + ([valid] if key != bus.keys.imu else [])


def test_garbage_on_every_subscribed_key_is_counted_and_harmless(stack) -> None:
    bus, watch, sup = stack["bus"], stack["watch"], stack["sup"]
    keys = [
        bus.keys.pose,
        bus.keys.imu,
        bus.keys.odom,
        bus.keys.state,
        bus.keys.drive_cmd,
        bus.keys.sim_control,
    ]
    n_logs = len(watch.logs)
    for _ in range(3):
        for key in keys:
            for payload in _garbage_payloads(bus, key):
                bus.put_raw(key, payload)
        time.sleep(0.05)

    def reported(service: str) -> bool:
        return any(
            m.source == service and m.text.startswith("rejected") for m in watch.logs[n_logs:]
        )

    assert watch.wait_for(lambda: all(reported(s) for s in SERVICES), timeout_s=5.0), [
        m.text for m in watch.logs[n_logs:]
    ]
    texts = " ".join(m.text for m in watch.logs[n_logs:])
    for key in keys:
        assert key in texts, f"no drop reported for {key}"
    assert not sup.dead()
    assert not bus.missing_alive(SERVICES)
    # still racing afterwards
    assert watch.wait_for(
        lambda: (t := watch.latest_truth()) is not None and t.speed_mps > 1.0, timeout_s=10.0
    )


def test_killing_the_planner_stops_the_car_and_a_new_planner_resumes(stack) -> None:
    bus, watch, sup = stack["bus"], stack["watch"], stack["sup"]
    planner = next(c for c in sup.children if c.name == "planner" and c.exit_code() is None)
    others = {c.name: c.pid for c in sup.children if c.name != "planner"}
    # kill mid-lap, while the car is cornering or accelerating out of a turn
    assert watch.wait_for(
        lambda: (
            (t := watch.latest_truth()) is not None
            and 2.0 < t.speed_mps < 3.3
            and 5.0 < t.s_m < 35.0
        ),
        timeout_s=30.0,
    ), "the car never reached racing speed mid-lap"
    v_kill = watch.latest_truth().speed_mps
    planner.process.send_signal(signal.SIGKILL)
    t_kill = time.time()
    planner.process.wait(timeout=5.0)

    def stopped() -> bool:
        t = watch.latest_truth()
        return t is not None and t.stamp_s > t_kill and abs(t.speed_mps) < 0.05

    assert watch.wait_for(stopped, timeout_s=3.0), "car did not stop"
    with watch.lock:
        first_stop = next(t for t in watch.truth if t.stamp_s > t_kill and abs(t.speed_mps) < 0.05)
    stop_time = first_stop.stamp_s - t_kill
    assert stop_time <= 0.5, f"stopped {stop_time:.3f} s after the kill (from {v_kill:.2f} m/s)"

    sup.forget(planner)
    sup.start("planner", service_argv("planner", str(stack["cfg_path"])))
    assert sup.wait_until(lambda: "planner" in bus.alive(), timeout_s=60.0)
    assert watch.wait_for(
        lambda: (t := watch.latest_truth()) is not None and t.speed_mps > 1.5, timeout_s=20.0
    ), "racing did not resume"
    # the others were never restarted
    assert {c.name: c.pid for c in sup.children if c.name != "planner"} == others
    assert not sup.dead()


def test_processes_leave_no_orphans(stack) -> None:
    sup = stack["sup"]
    assert all(Path(f"/proc/{c.pid}").exists() or c.exit_code() is not None for c in sup.children)
