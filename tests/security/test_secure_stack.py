"""Issue 15's secure profile with real processes on loopback: ``racestack up`` with
``[bus] security = "mtls"`` races a lap while this test plays the intruders:

* a session without a client certificate, and one with a ``planner`` certificate from a
  foreign CA, cannot connect;
* a session with a valid certificate of another service (telemetry's) publishes
  ``cmd/drive`` at 10 m/s, 50 Hz for 2 s: the car's speed (``sim/truth``) stays what the
  planner makes it, and the router reports exactly that many denied puts on ``events/log``;
* the race completes its lap with no off-track event, and every process is gone after.
"""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest
import zenoh

from services.tools.launcher.supervisor import stop_process
from shared.bus import Bus, BusOpenError
from shared.config import config_from_dict
from shared.messages import DriveCmd, LogEvent, SimTruth
from shared.net import free_loopback_port
from shared.security.certs import make_bundle, make_certs, write_bundle

pytestmark = pytest.mark.slow
ROOT = Path(__file__).resolve().parents[2]
RATE_HZ = 50.0
SECONDS = 2.0


def raw_session(port: int, files: dict[str, str]) -> zenoh.Session:
    """A client session on the hub's TLS endpoint with exactly `files` (tls keys)."""
    c = zenoh.Config()
    for k, v in {
        "mode": '"client"',
        "connect/endpoints": json.dumps([f"tls/127.0.0.1:{port}"]),
        "scouting/multicast/enabled": "false",
        "scouting/gossip/enabled": "false",
        **{f"transport/link/tls/{k}": json.dumps(v) for k, v in files.items()},
    }.items():
        c.insert_json5(k, v)
    return zenoh.open(c)


def started_pids(run_dir: Path, output: str) -> dict[str, int]:
    """The processes the launcher started, by PID: the services from RUN/logs/launcher.log
    (the console shows only warnings), the router from the console's secure-profile line."""
    text = (run_dir / "logs" / "launcher.log").read_text()
    pids = {m[0]: int(m[1]) for m in re.findall(r"started (\w+) \(pid (\d+)\)", text)}
    router = re.search(r"router \(pid (\d+)\)", output)
    if router:
        pids["router"] = int(router[1])
    return pids


def gone(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return True
    return False


def test_secure_profile_refuses_strangers_denies_intruders_and_races_clean(
    tmp_path: Path,
) -> None:
    certs = tmp_path / "certs"
    make_certs(certs)
    foreign = tmp_path / "foreign"
    write_bundle(foreign, make_bundle(("planner",)))
    port = free_loopback_port()
    cfg_path = tmp_path / "secure.toml"
    cfg_path.write_text(
        f'[bus]\nlisten = ["tcp/127.0.0.1:{port}"]\nsecurity = "mtls"\ncerts_dir = "{certs}"\n'
    )
    cfg = config_from_dict(
        {"bus": {"listen": [f"tcp/127.0.0.1:{port}"], "security": "mtls",
                 "certs_dir": str(certs)}}
    )
    env = {**os.environ, "XDG_CONFIG_HOME": str(tmp_path / "xdg")}
    env.pop("RACESTACK_CERTS_DIR", None)
    proc = subprocess.Popen(
        [sys.executable, "-m", "services.tools.cli", "up", "--laps", "1", "--config", str(cfg_path),
         "--run-dir", str(tmp_path / "run")],
        cwd=ROOT, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
    )
    lines: list[str] = []
    racing = threading.Event()

    def read() -> None:
        assert proc.stdout is not None
        for line in proc.stdout:
            lines.append(line)
            if "all services alive: racing" in line:
                racing.set()

    reader = threading.Thread(target=read, daemon=True)
    reader.start()
    try:
        assert racing.wait(150), "".join(lines)
        # 1. strangers: no client certificate; a planner certificate of another CA
        with pytest.raises(zenoh.ZError):
            raw_session(port, {"root_ca_certificate": str(certs / "ca.crt"),
                               "enable_mtls": True})
        with pytest.raises(zenoh.ZError):
            raw_session(port, {"root_ca_certificate": str(certs / "ca.crt"),
                               "enable_mtls": True,
                               "connect_certificate": str(foreign / "planner.crt"),
                               "connect_private_key": str(foreign / "planner.key")})
        plain = cfg.bus.model_copy(update={"security": "none"})
        with pytest.raises(BusOpenError):  # plain TCP to the TLS port: no session
            Bus(plain.model_copy(update={"mode": "client"}), "intruder", announce=False)

        # 2. an intruder with telemetry's certificate drives at 10 m/s
        speeds: list[tuple[float, float]] = []
        denied: list[str] = []
        with Bus(cfg.bus, "operator", announce=False) as watch, \
                Bus(cfg.bus, "telemetry", announce=False) as intruder:
            watch.subscribe(watch.keys.sim_truth, SimTruth,
                            lambda m: speeds.append((time.monotonic(), m.speed_mps)))
            watch.subscribe(watch.keys.events_log, LogEvent,
                            lambda m: denied.append(m.text) if m.source == "router" else None)
            cmd = intruder.publisher(intruder.keys.drive_cmd, DriveCmd)
            assert cmd.wait_matching(5.0)  # the simulator's subscription is seen
            time.sleep(2.0)
            t0 = time.monotonic()
            sent = 0
            while time.monotonic() - t0 < SECONDS:
                cmd.put(DriveCmd(stamp_s=time.time(), speed_mps=10.0, steering_rad=0.3))
                sent += 1
                time.sleep(1.0 / RATE_HZ)
            t1 = time.monotonic()
            deadline = time.monotonic() + 6.0
            pattern = re.compile(r"telemetry Put \(ingress\) \S+/cmd/drive x(\d+)")

            def counted() -> int:
                return sum(int(n) for t in list(denied) for n in pattern.findall(t))

            while counted() < sent and time.monotonic() < deadline:
                time.sleep(0.1)
            time.sleep(1.5)  # one more report period: nothing beyond `sent`
        assert counted() == sent, (sent, denied)
        before = [v for t, v in speeds if t0 - 2.0 <= t < t0]
        during = [v for t, v in speeds if t0 <= t <= t1 + 0.5]
        assert len(before) > 50 and len(during) > 50, (len(before), len(during))
        assert max(during) < 4.5 and max(during) <= max(before) + 0.5, (before, during)

        # 3. the race goes on to the end
        proc.wait(timeout=240)
    finally:
        stop_process(proc, grace_s=20.0)
        reader.join(5.0)
    out = "".join(lines)
    assert proc.returncode == 0, out
    laps = re.findall(r"lap \d: \d+\.\d+ s, .* off-track (\d+)", out)
    assert laps == ["0"], out
    assert "secure profile: certificates from" in out, out
    pids = started_pids(tmp_path / "run", out)
    assert {"router", "simulator", "localization_bridge", "planner", "telemetry"} <= set(pids)
    assert all(gone(pid) for pid in pids.values()), out
