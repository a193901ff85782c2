"""The real actuation chain in simulation: DriveCmd -> vesc_driver -> serial bytes -> simulator.

The simulator runs with ``[simulator] actuation = "fake_vesc"``: it owns a fake VESC whose
pty is at ``fake_vesc_link`` and does not subscribe to ``cmd/drive``; the vesc_driver's
``[vesc] port`` is that link. Both are REAL processes; this test process hosts the hub and
publishes the commands. If the car moves, the bytes went through the fake VESC. Both
processes are stopped by PID with a timeout in a ``finally``.
"""

from __future__ import annotations

import os
import subprocess
import sys
import threading
import time
from collections.abc import Callable
from pathlib import Path

import pytest
from pydantic import ValidationError

from services.simulator.vesc_actuation import VescActuation
from services.tools.launcher.supervisor import stop_process
from services.vesc_driver.driver import VescDriver
from shared.bus import Bus
from shared.config import ConfigError, load_config
from shared.config.simulator import SimulatorSettings
from shared.config.vesc import VescSettings
from shared.messages import DriveCmd, Odom, SimTruth
from shared.net import free_loopback_port
from shared.vesc.fake_pty import pty_available

ROOT = Path(__file__).resolve().parents[2]
START_TIMEOUT_S = 25.0
STOP_TIMEOUT_S = 10.0


pytestmark = pytest.mark.skipif(not pty_available(), reason="needs pseudo-terminals (os.openpty)")


def _start(module: str, toml: Path, log_path: Path) -> subprocess.Popen[bytes]:
    env = {**os.environ, "PYTHONPATH": str(ROOT), "PYTHONUNBUFFERED": "1"}
    with open(log_path, "wb") as out:
        return subprocess.Popen(
            [sys.executable, "-m", module, "--config", str(toml)],
            cwd=str(ROOT),
            env=env,
            stdout=out,
            stderr=subprocess.STDOUT,
        )


def _stop(proc: subprocess.Popen[bytes]) -> int | None:
    """SIGINT by PID, wait; SIGKILL if it does not exit in time."""
    return stop_process(proc, STOP_TIMEOUT_S)


def _until(cond: Callable[[], bool], timeout_s: float) -> bool:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if cond():
            return True
        time.sleep(0.01)
    return cond()


def test_drive_commands_move_the_simulated_car_through_the_fake_vesc(tmp_path: Path) -> None:
    link = tmp_path / "racestack-fake-vesc"
    toml = tmp_path / "racestack.toml"
    toml.write_text(
        f'[bus]\ncar = "vescsim"\nlisten = ["tcp/127.0.0.1:{free_loopback_port()}"]\n\n'
        f'[simulator]\nactuation = "fake_vesc"\nfake_vesc_link = "{link}"\n\n'
        "[simulator.lidar]\nrate_hz = 5.0\nbeams = 90\n\n"
        f'[vesc]\nport = "{link}"\nreconnect_backoff_max_s = 0.2\n',
        encoding="utf-8",
    )
    cfg = load_config(toml)
    logs = {name: tmp_path / f"{name}.log" for name in ("simulator", "vesc_driver")}

    def output() -> str:
        return "\n".join(
            f"--- {n}\n{p.read_text(errors='replace')[-3000:]}"
            for n, p in logs.items()
            if p.exists()
        )

    procs: list[subprocess.Popen[bytes]] = []
    stop_stream = threading.Event()
    with Bus(cfg.bus, "test", listen_default=True, mode="router") as hub:
        truth = hub.subscribe(hub.keys.sim_truth, SimTruth)
        odoms = hub.subscribe(hub.keys.odom, Odom, queue_size=2048)
        cmd = hub.publisher(hub.keys.drive_cmd, DriveCmd)

        def stream() -> None:
            while not stop_stream.is_set():
                cmd.put(DriveCmd(stamp_s=time.time(), speed_mps=2.0, steering_rad=0.0))
                stop_stream.wait(0.05)  # 20 Hz, like the planner

        streamer = threading.Thread(target=stream, daemon=True)
        try:
            for name in ("simulator", "vesc_driver"):
                procs.append(_start(f"services.{name}", toml, logs[name]))
            assert hub.wait_alive(["simulator", "vesc_driver"], START_TIMEOUT_S), output()
            # the simulator's token comes with its session, the link once its loop is built
            assert _until(link.is_symlink, START_TIMEOUT_S), output()
            # the simulator does not listen to cmd/drive: the only subscriber is the driver
            assert cmd.wait_matching(START_TIMEOUT_S), output()
            assert truth.wait(START_TIMEOUT_S) is not None, output()
            streamer.start()

            def moving() -> bool:
                t = truth.latest()
                return t is not None and t.speed_mps > 1.0

            assert _until(moving, 10.0), output()
            # the vesc_driver's odometry (GET_VALUES answered with the simulated wheel speed)
            assert _until(lambda: any(o.speed_mps > 1.0 for o in odoms.drain()), 3.0), output()
            # commands stop: the driver's brake frames stop the simulated car
            stop_stream.set()
            streamer.join(2.0)

            def stopped() -> bool:
                t = truth.latest()
                return t is not None and t.speed_mps < 0.2

            assert _until(stopped, 5.0), output()
        finally:
            stop_stream.set()
            if streamer.is_alive():
                streamer.join(2.0)
            codes = [_stop(p) for p in reversed(procs)]
    assert codes == [0, 0], output()
    assert not link.exists() and not link.is_symlink()  # the simulator removed its link


# --------------------------------------------------------------------------- in process
def test_vesc_actuation_inverts_the_driver_frames_and_reports_the_wheel_speed(
    tmp_path: Path,
) -> None:
    link = tmp_path / "vesc-link"
    link.symlink_to(tmp_path / "stale-target")  # a stale link from an earlier run is replaced
    settings = VescSettings(port=str(link))
    act = VescActuation(link, settings)
    driver = VescDriver(settings)
    try:
        assert os.readlink(link) == act.fake.path
        assert act.update(0.0) is None  # nothing received yet
        now = driver.now()
        driver.on_command(2.0, 0.1, now)
        driver.tick(now)
        assert act.fake.wait_for(lambda f: f.last_erpm == 9228.0 and f.last_servo == 0.409, 2.0)
        cmd = act.update(1.5)
        assert cmd is not None and not cmd.braking
        assert cmd.speed_mps == pytest.approx(2.0)
        assert cmd.steering_rad == pytest.approx((0.409 - 0.5304) / -1.2135)
        assert act.update(1.5) is None  # no new frame since
        # GET_VALUES is answered with the wheel speed, 1.5 m/s from now on
        speeds: list[float] = []
        deadline = time.monotonic() + 2.0
        while not any(v > 1.0 for v in speeds) and time.monotonic() < deadline:
            time.sleep(0.01)
            odom = driver.tick(driver.now()).odometry
            speeds += [odom.speed_mps] if odom is not None else []
        assert speeds and speeds[-1] == pytest.approx(1.5, abs=1e-3), speeds
        # no command for the driver's timeout: its brake frames give speed 0
        time.sleep(settings.command_timeout_s + 0.02)
        result = driver.tick(driver.now())
        assert result.braking
        assert act.fake.wait_for(lambda f: f.mode == "brake", 2.0)
        brake = act.update(1.0)
        assert brake is not None and brake.braking and brake.speed_mps == 0.0
        assert brake.steering_rad == pytest.approx(cmd.steering_rad)  # the servo holds
    finally:
        driver.close()
        act.close()
    assert not link.exists() and not link.is_symlink()


def test_vesc_actuation_refuses_to_replace_a_regular_file(tmp_path: Path) -> None:
    target = tmp_path / "not-a-link"
    target.write_text("keep me", encoding="utf-8")
    with pytest.raises(ConfigError, match="not a symlink"):
        VescActuation(target, VescSettings())
    assert target.read_text(encoding="utf-8") == "keep me"
    with pytest.raises(ConfigError, match="cannot create"):
        VescActuation(tmp_path / "missing-dir" / "link", VescSettings())


def test_simulator_settings_actuation_defaults_and_validation() -> None:
    s = SimulatorSettings()
    assert s.actuation == "bus" and s.fake_vesc_link == "/tmp/racestack-fake-vesc"
    assert SimulatorSettings(actuation="fake_vesc").actuation == "fake_vesc"
    with pytest.raises(ValidationError):
        SimulatorSettings(actuation="serial")  # type: ignore[arg-type]
    with pytest.raises(ValidationError):
        SimulatorSettings(fake_vesc_link="")
