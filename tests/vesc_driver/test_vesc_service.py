"""The vesc_driver service as a REAL process against a fake VESC on a pty, over Zenoh.

The test process hosts the hub (a router ``Bus`` on a free loopback port) and the
``FakeVesc``; the service runs as ``python -m services.vesc_driver --config <tmp toml>`` with
``[vesc] port`` at the fake's symlink. Every process is stopped by PID with a timeout
(SIGINT, then SIGKILL) in a ``finally``; every wait has a timeout.
"""

from __future__ import annotations

import itertools
import math
import os
import re
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Iterator
from dataclasses import fields, replace
from pathlib import Path

import msgpack
import pytest

from services.vesc_driver.driver import OdometryRecord
from services.vesc_driver.service import _STATE_FIELDS, odom_message, vesc_state_message
from shared.bus import Bus, Subscription, TypedPublisher
from shared.config import load_config
from shared.messages import DriveCmd, LogEvent, Odom, Pose, VescState
from shared.net import free_loopback_port
from shared.ratelimit import EpisodeLimiter, GrowthLimiter
from shared.vesc.fake import DEFAULT_VALUES, FakeEvent
from shared.vesc.fake_pty import FakeVesc, pty_available
from shared.vesc.protocol import CommandId
from shared.vesc.values import VescValues

ROOT = Path(__file__).resolve().parents[2]
SERVICE = "vesc_driver"
START_TIMEOUT_S = 20.0
STOP_TIMEOUT_S = 10.0
WAIT_S = 3.0
#: Event rate limit of the service under test [s] (``[vesc] event_interval_s``).
EVENT_INTERVAL_S = 0.2


pytestmark = pytest.mark.skipif(not pty_available(), reason="needs pseudo-terminals (os.openpty)")


# --------------------------------------------------------------------------- helpers
def write_toml(path: Path, port: int, vesc_port: str, extra: str = "") -> Path:
    """A config with the hub endpoint, the VESC port and a short event interval."""
    path.write_text(
        f'[bus]\ncar = "vesctest"\nlisten = ["tcp/127.0.0.1:{port}"]\n\n'
        f'[vesc]\nport = "{vesc_port}"\nevent_interval_s = {EVENT_INTERVAL_S}\n{extra}',
        encoding="utf-8",
    )
    return path


def start_service(toml: Path, log_path: Path) -> subprocess.Popen[bytes]:
    """``python -m services.vesc_driver --config toml`` with its output in ``log_path``."""
    env = {**os.environ, "PYTHONPATH": str(ROOT), "PYTHONUNBUFFERED": "1"}
    with open(log_path, "wb") as out:
        return subprocess.Popen(
            [sys.executable, "-m", "services.vesc_driver", "--config", str(toml)],
            cwd=str(ROOT),
            env=env,
            stdout=out,
            stderr=subprocess.STDOUT,
        )


def stop_process(proc: subprocess.Popen[bytes], sig: int = signal.SIGINT) -> int | None:
    """Signal the process by PID, wait; SIGKILL if it does not exit in time."""
    if proc.poll() is None:
        proc.send_signal(sig)
        try:
            return proc.wait(timeout=STOP_TIMEOUT_S)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait(timeout=5.0)
            return None
    return proc.returncode


def until(cond: Callable[[], bool], timeout_s: float = WAIT_S) -> bool:
    """Poll ``cond`` every 5 ms until it holds or ``timeout_s`` [s] passed."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if cond():
            return True
        time.sleep(0.005)
    return cond()


def events_after(fake: FakeVesc, cmd: int, t_s: float) -> list[FakeEvent]:
    """The fake's events of command ``cmd`` recorded after time ``t_s`` [s]."""
    return [e for e in fake.events(cmd) if e.t_s > t_s]


class Streamer:
    """Publishes one DriveCmd at ``rate_hz`` on a thread until stopped."""

    def __init__(
        self, pub: TypedPublisher[DriveCmd], speed: float, steer: float, rate_hz: float = 50.0
    ) -> None:
        self.pub, self.speed, self.steer, self.period = pub, speed, steer, 1.0 / rate_hz
        self.last_put_s = -math.inf
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)

    def _run(self) -> None:
        while not self._stop.is_set():
            self.pub.put(
                DriveCmd(stamp_s=time.time(), speed_mps=self.speed, steering_rad=self.steer)
            )
            self.last_put_s = time.monotonic()
            self._stop.wait(self.period)

    def __enter__(self) -> Streamer:
        self._thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self._stop.set()
        self._thread.join(2.0)
        assert not self._thread.is_alive()


class Rig:
    """Hub, fake VESC and the service process, plus the hub's subscriptions."""

    def __init__(self, tmp: Path, vesc_port: str | None = None) -> None:
        self.tmp = tmp
        self.fake: FakeVesc | None = None
        self.proc: subprocess.Popen[bytes] | None = None
        self.log_path = tmp / "vesc_driver.log"
        port = free_loopback_port()
        if vesc_port is None:
            (tmp / "dev").mkdir()
            self.fake = FakeVesc(link_dir=tmp / "dev")
            vesc_port = self.fake.path
        self.toml = write_toml(tmp / "racestack.toml", port, vesc_port)
        cfg = load_config(self.toml)
        self.hub = Bus(cfg.bus, "test", listen_default=True, mode="router")
        k = self.hub.keys
        self.states: Subscription[VescState] = self.hub.subscribe(
            k.vesc_state, VescState, queue_size=1024
        )
        self.odoms: Subscription[Odom] = self.hub.subscribe(k.odom, Odom, queue_size=1024)
        self.logs: Subscription[LogEvent] = self.hub.subscribe(
            k.events_log, LogEvent, queue_size=1024
        )
        self.log_events: list[LogEvent] = []
        self.cmd = self.hub.publisher(k.drive_cmd, DriveCmd)

    def start(self) -> None:
        """Start the service and wait until it is alive and subscribed."""
        self.proc = start_service(self.toml, self.log_path)
        assert self.hub.wait_alive([SERVICE], START_TIMEOUT_S), self.output()
        assert self.cmd.wait_matching(START_TIMEOUT_S), self.output()

    def output(self) -> str:
        """The service's log so far."""
        try:
            return self.log_path.read_text(errors="replace")
        except OSError:
            return "(no log)"

    def alive(self) -> bool:
        """The process runs and its liveliness token is seen."""
        return self.proc is not None and self.proc.poll() is None and (SERVICE in self.hub.alive())

    def drive(self, speed: float, steer: float, duration_s: float) -> float:
        """Publish commands at 50 Hz for ``duration_s`` [s]; the time of the last put [s]."""
        end = time.monotonic() + duration_s
        while True:
            self.cmd.put(DriveCmd(stamp_s=time.time(), speed_mps=speed, steering_rad=steer))
            t = time.monotonic()
            if t >= end:
                return t
            time.sleep(0.02)

    def wait_log(
        self, pred: Callable[[LogEvent], bool], timeout_s: float = WAIT_S
    ) -> LogEvent | None:
        """The first LogEvent of the service (seen so far or arriving) matching ``pred``."""
        deadline = time.monotonic() + timeout_s
        while True:
            self.log_events += self.logs.drain()
            for ev in self.log_events:
                if ev.source == SERVICE and pred(ev):
                    return ev
            if time.monotonic() >= deadline:
                return None
            time.sleep(0.01)

    def close(self) -> None:
        """Stop the process (by PID, with a timeout), close the hub and the fake."""
        try:
            if self.proc is not None:
                stop_process(self.proc)
        finally:
            self.hub.close()
            if self.fake is not None:
                self.fake.close()


@pytest.fixture(scope="module")
def rig(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Rig]:
    r = Rig(tmp_path_factory.mktemp("vesc-service"))
    try:
        r.start()
        yield r
    finally:
        r.close()


def _fake(r: Rig) -> FakeVesc:
    assert r.fake is not None
    return r.fake


# --------------------------------------------------------------------------- tests
def test_drive_command_reaches_the_wire(rig: Rig) -> None:
    fake = _fake(rig)
    t0 = time.monotonic()
    rig.drive(2.0, 0.1, 0.3)
    assert fake.wait_for(
        lambda f: (
            any(e.value == 9228.0 for e in events_after(f, CommandId.SET_RPM, t0))
            and any(e.value == 0.409 for e in events_after(f, CommandId.SET_SERVO_POS, t0))
        ),
        WAIT_S,
    ), rig.output()
    assert events_after(fake, CommandId.ALIVE, t0)
    assert rig.wait_log(lambda e: "first drive command" in e.text) is not None


def test_state_and_odometry_arrive_over_zenoh(rig: Rig) -> None:
    rig.states.drain()
    rig.odoms.drain()
    rig.drive(2.0, 0.1, 0.5)
    now = time.time()
    states = [s for s in rig.states.drain() if s.erpm == 9228.0]
    odoms = [o for o in rig.odoms.drain() if abs(o.speed_mps - 2.0) < 1e-6]
    assert len(states) >= 5, rig.output()
    assert len(odoms) >= 5, rig.output()
    s = states[-1]
    assert s.status == "ok" and s.fault_code == 0
    assert s.v_in_v == pytest.approx(16.8) and s.temp_fet_c == pytest.approx(31.5)
    assert s.temp_mos3_c == pytest.approx(32.0) and s.tachometer == 0
    assert abs(now - s.stamp_s) < 1.0
    o = odoms[-1]
    assert o.steering_rad == pytest.approx(0.1, abs=1e-9)
    assert o.yaw_rate_radps == pytest.approx(2.0 * math.tan(0.1) / 0.324, rel=1e-6)
    assert abs(now - o.stamp_s) < 1.0
    assert all(b.stamp_s >= a.stamp_s for a, b in itertools.pairwise(odoms))


def test_brake_within_150_ms_of_the_last_command(rig: Rig) -> None:
    fake = _fake(rig)
    time.sleep(EVENT_INTERVAL_S + 0.05)  # so the braking event is not rate-limited away
    t_last = rig.drive(1.5, 0.0, 0.4)
    assert fake.wait_for(
        lambda f: bool(events_after(f, CommandId.SET_CURRENT_BRAKE, t_last)), WAIT_S
    ), rig.output()
    first = events_after(fake, CommandId.SET_CURRENT_BRAKE, t_last)[0]
    assert first.value == pytest.approx(20.0)
    assert first.t_s - t_last <= 0.150, f"brake {1e3 * (first.t_s - t_last):.1f} ms after"
    # no motor command after the brake, and the brake is held
    time.sleep(0.1)
    assert not events_after(fake, CommandId.SET_RPM, first.t_s)
    assert len(events_after(fake, CommandId.SET_CURRENT_BRAKE, t_last)) >= 3
    assert rig.wait_log(lambda e: e.level == "warning" and "braking" in e.text) is not None


def test_invalid_bus_payloads_are_dropped_counted_and_reported(rig: Rig) -> None:
    fake = _fake(rig)
    key = rig.hub.keys.drive_cmd
    good = DriveCmd(stamp_s=1.0, speed_mps=1.0, steering_rad=0.0).encode()
    wire = msgpack.unpackb(good, raw=False)
    garbage = [
        b"\xc1 garbage",
        good[: len(good) // 2],  # truncated
        b"",
        Pose(stamp_s=1.0, x_m=0.0, y_m=0.0, yaw_rad=0.0).encode(),  # wrong type
        msgpack.packb({**wire, "v": 2}),  # wrong schema version
        msgpack.packb({k: v for k, v in wire.items() if k != "speed_mps"}),  # missing field
        msgpack.packb({**wire, "steering_rad": 3.0}),  # out of range
        msgpack.packb({**wire, "speed_mps": float("nan")}),  # not finite
        msgpack.packb({**wire, "speed_mps": "fast"}),  # bad type
    ]
    for data in garbage:
        rig.hub.put_raw(key, data)

    def reports_all(ev: LogEvent) -> bool:  # "rejected N messages (total T): key reason xN"
        m = re.match(r"rejected \d+ messages \(total (\d+)\)", ev.text)
        return m is not None and int(m[1]) >= len(garbage)

    ev = rig.wait_log(reports_all, timeout_s=5.0)
    assert ev is not None, (rig.log_events, rig.output())
    assert ev.level == "warning" and "cmd/drive" in ev.text
    assert rig.alive(), rig.output()
    t0 = time.monotonic()
    rig.drive(1.0, 0.0, 0.2)
    assert fake.wait_for(
        lambda f: any(e.value == 4614.0 for e in events_after(f, CommandId.SET_RPM, t0)), WAIT_S
    ), rig.output()


def test_out_of_range_command_is_clamped_and_reported(rig: Rig) -> None:
    fake = _fake(rig)
    t0 = time.monotonic()
    rig.drive(10.0, 0.0, 0.2)  # 46140 ERPM > 23250
    assert fake.wait_for(
        lambda f: any(e.value == 23250.0 for e in events_after(f, CommandId.SET_RPM, t0)),
        WAIT_S,
    ), rig.output()
    assert not any(abs(e.value or 0.0) > 23250.0 for e in fake.events(CommandId.SET_RPM))
    ev = rig.wait_log(lambda e: "invalid drive commands" in e.text)
    assert ev is not None and "clamped" in ev.text


def test_unplug_and_replug_while_running(rig: Rig) -> None:
    fake = _fake(rig)
    time.sleep(EVENT_INTERVAL_S + 0.05)
    with Streamer(rig.cmd, 2.0, 0.0):
        t0 = time.monotonic()
        assert fake.wait_for(lambda f: bool(events_after(f, CommandId.SET_RPM, t0)), WAIT_S)
        fake.unplug()
        lost = rig.wait_log(lambda e: "lost the VESC port" in e.text)
        assert lost is not None and lost.level == "error", rig.output()
        rig.states.drain()
        time.sleep(0.6)
        assert rig.alive(), rig.output()
        # while unplugged the state says so
        assert any(s.status == "disconnected" for s in rig.states.drain())
        fake.replug()
        t1 = time.monotonic()
        assert fake.wait_for(
            lambda f: any(e.value == 9228.0 for e in events_after(f, CommandId.SET_RPM, t1)),
            5.0,
        ), rig.output()
        assert rig.wait_log(lambda e: "back: resuming" in e.text) is not None
        rig.odoms.drain()
        assert until(lambda: any(o.speed_mps == pytest.approx(2.0) for o in rig.odoms.drain()))
    assert rig.alive(), rig.output()


def test_missing_port_is_waited_for_then_sigterm_brakes_and_exits(tmp_path: Path) -> None:
    """No device at start: the service runs and retries; it drives once the port appears;
    SIGTERM while driving: one brake frame, port closed, exit code 0, token gone."""
    link = tmp_path / "later-vesc"
    rig = Rig(tmp_path, vesc_port=str(link))
    fake: FakeVesc | None = None
    try:
        rig.start()
        ev = rig.wait_log(lambda e: "waiting for the VESC port" in e.text)
        assert ev is not None, rig.output()
        assert until(lambda: any(s.status == "disconnected" for s in rig.states.drain()))
        time.sleep(0.3)
        assert rig.alive(), rig.output()
        (tmp_path / "dev").mkdir()
        fake = FakeVesc(link_dir=tmp_path / "dev")
        os.symlink(fake.path, link)  # the device appears (a chain of symlinks)
        with Streamer(rig.cmd, 2.0, 0.1):
            assert fake.wait_for(
                lambda f: any(e.value == 9228.0 for e in f.events(CommandId.SET_RPM)), 5.0
            ), rig.output()
            assert rig.wait_log(lambda e: "open" in e.text and str(link) in e.text) is not None
            assert rig.proc is not None
            t_sig = time.monotonic()
            code = stop_process(rig.proc, signal.SIGTERM)
        assert code == 0, rig.output()
        # the fake reads its end of the pty on its own thread: on a loaded machine the frame
        # the driver wrote before it exited may be decoded a little later
        fake.wait_for(lambda f: bool(events_after(f, CommandId.SET_CURRENT_BRAKE, t_sig)),
                      WAIT_S)
        brakes = events_after(fake, CommandId.SET_CURRENT_BRAKE, t_sig)
        assert brakes and brakes[0].value == pytest.approx(20.0), rig.output()
        assert not events_after(fake, CommandId.SET_RPM, brakes[0].t_s)
        assert until(lambda: SERVICE not in rig.hub.alive())
        assert "stopping: brake sent" in rig.output()
    finally:
        rig.close()
        if fake is not None:
            fake.close()


# --------------------------------------------------------------------------- pure pieces
def test_state_message_maps_values_and_leaves_out_what_the_message_rejects() -> None:
    values = replace(
        DEFAULT_VALUES, erpm=9228.0, amp_hours=-0.5, temp_motor_c=999.0, duty=0.25, tachometer=-12
    )
    msg, skipped = vesc_state_message(values, "ok", 123.0)
    assert set(skipped) == {"amp_hours", "temp_motor_c"}
    assert msg.amp_hours is None and msg.temp_motor_c is None
    assert (msg.erpm, msg.duty, msg.tachometer, msg.v_in_v) == (9228.0, 0.25, -12, 16.8)
    assert msg.status == "ok" and msg.stamp_s == 123.0
    # every VescState value field has the same name in VescValues
    names = {f.name for f in fields(VescValues)}
    assert all(name in names for name, _ in _STATE_FIELDS)
    empty, none_skipped = vesc_state_message(None, "disconnected", 1.0)
    assert empty.status == "disconnected" and empty.erpm is None and none_skipped == ()


def test_odom_message_skips_or_blanks_what_the_message_rejects() -> None:
    ok, bad = odom_message(OdometryRecord(1.0, 2.0, 0.1, 0.6), 5.0)
    assert ok is not None and bad == () and ok.speed_mps == 2.0 and ok.stamp_s == 5.0
    too_fast, bad = odom_message(OdometryRecord(1.0, 80.0, 0.1, 0.6), 5.0)
    assert too_fast is None and bad == ("speed_mps",)
    spin, bad = odom_message(OdometryRecord(1.0, 40.0, 0.3, 60.0), 5.0)
    assert spin is not None and spin.yaw_rate_radps is None and bad == ("yaw_rate_radps",)


def test_episode_limiter_pairs_starts_and_ends() -> None:
    lim = EpisodeLimiter(1.0)
    assert lim.start(0.0) == 0 and lim.end()
    assert lim.start(0.5) is None and not lim.end()  # suppressed, and so is its end
    assert lim.start(0.7) is None
    assert lim.start(1.2) == 2 and lim.end()


def test_growth_limiter_reports_first_growth_at_once_then_rate_limited() -> None:
    lim = GrowthLimiter(1.0)
    assert not lim.check(0, 0.0)
    assert lim.check(1, 0.1)
    assert not lim.check(5, 0.5)
    assert lim.check(5, 1.2) and lim.reported == 5
    assert not lim.check(5, 3.0)
