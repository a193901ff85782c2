"""A race of two cars in the secure profile, against the real router process (issue #24):
car1's planner, connected with its own certificate (``planner-car1``), drives car1 but its
commands to car0's ``cmd/drive`` are denied by the hub and never reach the simulator's
input there. Every process is stopped by PID with a timeout in a ``finally``."""

from __future__ import annotations

import threading
import time
from pathlib import Path

import pytest

from services.tools.launcher.supervisor import Supervisor, service_argv
from shared.bus import Bus, BusOpenError
from shared.config import RacestackConfig, load_config
from shared.config.bus import BusSettings
from shared.keys import Keys
from shared.messages import DriveCmd
from shared.net import free_loopback_port
from shared.security.certs import make_bundle, write_bundle
from shared.security.identities import fleet_identities

pytestmark = pytest.mark.slow
START_TIMEOUT_S = 60.0


def open_when_up(settings: BusSettings, service: str) -> Bus:
    """A client bus of `service` once the hub listens (it refuses before)."""
    deadline = time.monotonic() + START_TIMEOUT_S
    while True:
        try:
            return Bus(settings, service, announce=False)
        except BusOpenError:
            if time.monotonic() > deadline:
                raise
            time.sleep(0.5)


def test_car1_s_planner_drives_car1_and_is_denied_car0(tmp_path: Path) -> None:
    certs = tmp_path / "certs"
    write_bundle(certs, make_bundle(fleet_identities(("car0", "car1"))))
    port = free_loopback_port()
    race = tmp_path / "race.toml"
    race.write_text(
        f'[bus]\nlisten = ["tcp/127.0.0.1:{port}"]\nsecurity = "mtls"\ncerts_dir = "{certs}"\n'
        '[[cars]]\nname = "car0"\n[[cars]]\nname = "car1"\n', encoding="utf-8")
    cfg: RacestackConfig = load_config(race)
    car1 = cfg.bus.model_copy(update={"car": "car1", "per_car_identity": True})
    got: dict[str, list[DriveCmd]] = {"car0": [], "car1": []}
    lock = threading.Lock()

    def on(car: str):
        def put(m: DriveCmd) -> None:
            with lock:
                got[car].append(m)
        return put

    sup = Supervisor(log_dir=tmp_path / "logs", env={"RACESTACK_CERTS_DIR": str(certs)})
    try:
        sup.start("router", service_argv("router", str(race)))
        with open_when_up(cfg.bus, "simulator") as sim:  # the simulator's inputs of both cars
            for car in got:
                sim.subscribe(Keys(car).drive_cmd, DriveCmd, on(car))
            with Bus(car1, "planner", announce=False) as planner:  # CN planner-car1
                own = planner.publisher(Keys("car1").drive_cmd, DriveCmd)
                other = planner.publisher(Keys("car0").drive_cmd, DriveCmd)
                deadline = time.monotonic() + 20.0
                while time.monotonic() < deadline:
                    now = time.time()
                    other.put(DriveCmd(stamp_s=now, speed_mps=5.0, steering_rad=0.3))
                    own.put(DriveCmd(stamp_s=now, speed_mps=2.0, steering_rad=0.0))
                    time.sleep(0.02)
                    with lock:
                        if len(got["car1"]) >= 20:
                            break
                for _ in range(20):  # and more of the forbidden ones, after its own arrived
                    other.put(DriveCmd(stamp_s=time.time(), speed_mps=5.0, steering_rad=0.3))
                    time.sleep(0.02)
                time.sleep(1.0)
            with lock:
                assert got["car0"] == [], "car1's planner must never drive car0"
            # the control: car0's own planner (CN planner-car0) does reach car0's input
            car0 = cfg.bus.model_copy(update={"per_car_identity": True})
            with Bus(car0, "planner", announce=False) as planner0:
                pub = planner0.publisher(Keys("car0").drive_cmd, DriveCmd)
                deadline = time.monotonic() + 20.0
                while time.monotonic() < deadline and not got["car0"]:
                    pub.put(DriveCmd(stamp_s=time.time(), speed_mps=1.0, steering_rad=0.0))
                    time.sleep(0.05)
        with lock:
            assert got["car0"] and all(m.speed_mps == 1.0 for m in got["car0"])
            assert len(got["car1"]) >= 20, "car1's own commands must reach its simulator input"
    finally:
        codes = sup.stop_all(grace_s=5.0)
        assert all(c is not None for c in codes.values()), f"left running: {codes}"
