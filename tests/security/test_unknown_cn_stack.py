"""A certificate of the project's CA whose common name is no identity, against the real
router process (the hub, its log tap and its reports on ``events/log``).

Zenoh's access control matches such a session to no subject and denies everything it
sends, mostly without a trace line per message. The router must still count and report
it: the connection itself (named by the common name the TLS link logged) and the decisions
Zenoh did trace (its liveliness token, its first put). Every process is stopped by PID
with a timeout in a ``finally``.
"""

from __future__ import annotations

import threading
import time
from pathlib import Path

import pytest

from services.router.denials import CONNECT_DENIED, UNKNOWN_CN
from services.tools.launcher.supervisor import Supervisor, service_argv
from shared.bus import Bus, BusOpenError
from shared.config import RacestackConfig, load_config
from shared.messages import DriveCmd, LogEvent
from shared.net import free_loopback_port
from shared.security import IDENTITIES
from shared.security.certs import make_bundle, write_bundle

pytestmark = pytest.mark.slow
START_TIMEOUT_S = 60.0


def open_when_up(cfg: RacestackConfig, service: str) -> Bus:
    """A client bus of `service` once the hub listens (it refuses before)."""
    deadline = time.monotonic() + START_TIMEOUT_S
    while True:
        try:
            return Bus(cfg.bus, service, announce=False)
        except BusOpenError:
            if time.monotonic() > deadline:
                raise
            time.sleep(0.5)


def test_an_unknown_common_name_is_denied_counted_and_reported(tmp_path: Path) -> None:
    certs = tmp_path / "certs"
    write_bundle(certs, make_bundle((*IDENTITIES, "stranger")))  # same CA, one CN too many
    port = free_loopback_port()
    cfg_path = tmp_path / "secure.toml"
    cfg_path.write_text(
        f'[bus]\nlisten = ["tcp/127.0.0.1:{port}"]\nsecurity = "mtls"\ncerts_dir = "{certs}"\n',
        encoding="utf-8",
    )
    cfg = load_config(cfg_path)
    sup = Supervisor(log_dir=tmp_path / "logs", env={"RACESTACK_CERTS_DIR": str(certs)})
    lock = threading.Lock()
    reports: list[str] = []

    def on_log(m: LogEvent) -> None:
        if m.source == "router":
            with lock:
                reports.append(m.text)

    def seen(text: str) -> bool:
        with lock:
            return any(text in r for r in reports)

    try:
        sup.start("router", service_argv("router", str(cfg_path)))
        with open_when_up(cfg, "operator") as watch:
            watch.subscribe(watch.keys.events_log, LogEvent, on_log)
            with Bus(cfg.bus, "stranger") as stranger:  # its token alive/stranger: denied
                cmd = stranger.publisher(stranger.keys.drive_cmd, DriveCmd)
                for _ in range(20):
                    cmd.put(DriveCmd(stamp_s=time.time(), speed_mps=5.0, steering_rad=0.0))
                    time.sleep(0.02)
                deadline = time.monotonic() + 10.0
                while not seen(CONNECT_DENIED) and time.monotonic() < deadline:
                    time.sleep(0.1)
        who = "stranger" + UNKNOWN_CN
        assert seen(f"{who} {CONNECT_DENIED} (ingress) * x1"), reports
        assert seen(f"{who} Liveliness Token (ingress) racestack/car0/alive/stranger x1"), reports
    finally:
        codes = sup.stop_all(grace_s=5.0)
        assert all(c is not None for c in codes.values()), f"left running: {codes}"
