"""The VESC's IMU end to end: fake VESC -> serial bytes -> vesc_driver -> ``vehicle/imu``.

In process: the simulator's ``VescActuation`` (``set_imu`` with the step truth, or its
kinematic estimate) answers the driver core's GET_IMU_DATA requests. As a REAL process: the
vesc_driver service on a fake VESC's pty publishes the fake's reading in the car frame over
Zenoh, with a mounting rotation applied, and survives garbage and truncated IMU replies
(counted). Every process is stopped by PID with a timeout in a ``finally``.
"""

from __future__ import annotations

import math
import os
import re
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path

import pytest

from services.simulator.vesc_actuation import VescActuation
from services.tools.launcher.supervisor import stop_process
from services.vesc_driver.driver import ImuRecord, VescDriver
from shared.bus import Bus
from shared.config import load_config
from shared.config.vesc import VescSettings
from shared.messages import Imu
from shared.net import free_loopback_port
from shared.vesc.fake import FakeImu
from shared.vesc.fake_pty import FakeVesc, pty_available
from shared.vesc.imu import STANDARD_GRAVITY_MPS2, encode_imu_payload
from shared.vesc.protocol import encode_frame

ROOT = Path(__file__).resolve().parents[2]
START_TIMEOUT_S = 20.0
STOP_TIMEOUT_S = 10.0

pytestmark = pytest.mark.skipif(not pty_available(), reason="needs pseudo-terminals (os.openpty)")


def _until(cond: Callable[[], bool], timeout_s: float) -> bool:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if cond():
            return True
        time.sleep(0.01)
    return cond()


def _next_imu(driver: VescDriver, timeout_s: float = 2.0) -> ImuRecord:
    """Tick the driver until an IMU reply comes back."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        time.sleep(0.02)
        imu = driver.tick(driver.now()).imu
        if imu is not None:
            return imu
    raise AssertionError("no IMU reply")


# --------------------------------------------------------------------------- in process
def test_simulator_truth_comes_back_through_the_mounting_rotation(tmp_path: Path) -> None:
    link = tmp_path / "vesc-link"
    # board upside down and turned 90 deg: every axis differs from the car's
    settings = VescSettings(
        port=str(link), poll_imu_rate_hz=50.0, imu_roll_deg=180.0, imu_yaw_deg=90.0
    )
    act = VescActuation(link, settings)
    driver = VescDriver(settings)
    try:
        act.set_imu(0.7, 1.25, -3.5)
        imu = _next_imu(driver)
        for _ in range(5):  # a reply to a request from before set_imu may come first
            if imu.yaw_rate_radps != 0.0:
                break
            imu = _next_imu(driver)
        tol = 1e-5  # float32 on the wire
        assert imu.yaw_rate_radps == pytest.approx(0.7, abs=tol)
        assert imu.ax_mps2 == pytest.approx(1.25, abs=tol)
        assert imu.ay_mps2 == pytest.approx(-3.5, abs=tol)
        # the board itself saw something else (what the firmware would send)
        board = act.fake.model.imu_reading()
        assert board.accel_g[2] == pytest.approx(-1.0, abs=1e-9)  # gravity along -z_board
        act.set_imu(math.nan, 0.0, 0.0)  # ignored: the last truth stays
        assert _next_imu(driver).yaw_rate_radps == pytest.approx(0.7, abs=tol)
    finally:
        driver.close()
        act.close()


def test_without_truth_the_fake_reports_the_kinematic_estimate(tmp_path: Path) -> None:
    link = tmp_path / "vesc-link"
    settings = VescSettings(port=str(link), poll_imu_rate_hz=50.0)
    act = VescActuation(link, settings)
    driver = VescDriver(settings)
    try:
        now = driver.now()
        driver.on_command(2.0, 0.2, now)
        driver.tick(now)
        assert act.fake.wait_for(lambda f: f.last_servo is not None, 2.0)
        cmd = act.update(2.0)
        assert cmd is not None
        act.update(2.0)  # the estimate uses the steering of the previous update
        r = 2.0 * math.tan(cmd.steering_rad) / settings.wheelbase_m
        imu = _next_imu(driver)
        for _ in range(5):  # a reply to a request from before the update may come first
            if imu.yaw_rate_radps != 0.0:
                break
            imu = _next_imu(driver)
        assert imu.yaw_rate_radps == pytest.approx(r, rel=1e-4)
        assert imu.ay_mps2 == pytest.approx(2.0 * r, rel=1e-4)
        assert not act.imu_from_truth
    finally:
        driver.close()
        act.close()


# --------------------------------------------------------------------------- the process
def test_service_publishes_the_fake_imu_in_the_car_frame(tmp_path: Path) -> None:
    (tmp_path / "dev").mkdir()
    # board yawed +90 deg: board x = car left, board y = car backwards
    board = FakeImu(accel_g=(0.2, -0.1, 1.0), gyro_dps=(0.0, 0.0, 57.29577951308232))
    fake = FakeVesc(link_dir=tmp_path / "dev", imu=board)
    toml = tmp_path / "racestack.toml"
    toml.write_text(
        f'[bus]\ncar = "vescimu"\nlisten = ["tcp/127.0.0.1:{free_loopback_port()}"]\n\n'
        f'[vesc]\nport = "{fake.path}"\nevent_interval_s = 0.2\npoll_imu_rate_hz = 50.0\n'
        "imu_yaw_deg = 90.0\nstale_imu_s = 0.3\n",
        encoding="utf-8",
    )
    cfg = load_config(toml)
    log_path = tmp_path / "vesc_driver.log"
    env = {**os.environ, "PYTHONPATH": str(ROOT), "PYTHONUNBUFFERED": "1"}
    proc: subprocess.Popen[bytes] | None = None

    def output() -> str:
        return log_path.read_text(errors="replace")[-4000:] if log_path.exists() else ""

    try:
        with Bus(cfg.bus, "test", listen_default=True, mode="router") as hub:
            imus = hub.subscribe(hub.keys.imu, Imu, queue_size=1024)
            with open(log_path, "wb") as out:
                proc = subprocess.Popen(
                    [sys.executable, "-m", "services.vesc_driver", "--config", str(toml)],
                    cwd=str(ROOT),
                    env=env,
                    stdout=out,
                    stderr=subprocess.STDOUT,
                )
            assert hub.wait_alive(["vesc_driver"], START_TIMEOUT_S), output()
            got: list[Imu] = []

            def five() -> bool:
                got.extend(imus.drain())
                return len(got) >= 5

            assert _until(five, 10.0), output()
            m = got[-1]
            g = STANDARD_GRAVITY_MPS2
            assert m.ax_mps2 == pytest.approx(0.1 * g, abs=1e-5)  # -board y
            assert m.ay_mps2 == pytest.approx(0.2 * g, abs=1e-5)  # board x
            assert m.yaw_rate_radps == pytest.approx(1.0, abs=1e-5)
            assert abs(time.time() - m.stamp_s) < 2.0
            # garbage and short IMU replies between the good ones: dropped and counted
            for _ in range(3):
                fake.inject(b"\x41\x02\x41\x03" + encode_frame(b"\x41\x01\xf8\x00\x00"))
                fake.inject(encode_frame(encode_imu_payload(0x01F8)[:-5]))
            imus.drain()
            assert _until(lambda: len(imus.drain()) > 0, 3.0), output()  # still publishing
            assert proc.poll() is None
            # the IMU goes silent: a warning on events/log, then it is back
            logs = hub.subscribe(hub.keys.events_log, None, queue_size=256)
            fake.imu_replies_enabled = False
            assert _until(
                lambda: any("IMU" in getattr(e, "text", "") for e in logs.drain()), 5.0
            ), output()
            fake.imu_replies_enabled = True
            assert _until(lambda: len(imus.drain()) > 0, 3.0), output()
            assert stop_process(proc, STOP_TIMEOUT_S) == 0, output()
    finally:
        if proc is not None and proc.poll() is None:
            stop_process(proc, STOP_TIMEOUT_S)
        fake.close()
    found = re.search(r"'driver\.malformed_imu': (\d+)", output())
    assert found is not None and int(found.group(1)) >= 3, output()
