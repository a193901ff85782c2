"""rmw_zenoh's graph in the secure profile, against the real router process: the gateway's
liveliness tokens (``@ros2_lv/<domain>/**``) pass the hub's rules and the ROS side (the
``ros2`` certificate) sees them with a liveliness query; another identity's token there is
denied and reported. Every process is stopped by PID with a timeout in a ``finally``."""

from __future__ import annotations

import threading
import time
from pathlib import Path

import pytest

from services.ros2_gateway import Ros2GatewayService
from services.ros2_gateway.liveliness import parse_token
from services.tools.launcher.supervisor import Supervisor, service_argv
from shared.bus import Bus, BusOpenError
from shared.config import RacestackConfig, load_config
from shared.messages import LogEvent
from shared.net import free_loopback_port
from shared.security.certs import make_certs

pytestmark = pytest.mark.slow
START_TIMEOUT_S = 60.0

ROS2_TOML = """
[ros2]
scheme = "rmw_zenoh"
domain_id = 5
"""


def client(cfg: RacestackConfig, service: str) -> Bus:
    """A client bus of `service` once the hub listens (it refuses before)."""
    deadline = time.monotonic() + START_TIMEOUT_S
    while True:
        try:
            return Bus(cfg.bus, service, announce=False)
        except BusOpenError:
            if time.monotonic() > deadline:
                raise
            time.sleep(0.5)


def test_the_gateway_s_graph_tokens_pass_the_rules_and_others_are_denied(tmp_path: Path) -> None:
    certs = tmp_path / "certs"
    make_certs(certs)
    port = free_loopback_port()
    cfg_path = tmp_path / "secure.toml"
    cfg_path.write_text(
        f'[bus]\nlisten = ["tcp/127.0.0.1:{port}"]\nsecurity = "mtls"\n'
        f'certs_dir = "{certs}"\n{ROS2_TOML}',
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

    try:
        sup.start("router", service_argv("router", str(cfg_path)))
        with client(cfg, "operator") as watch, client(cfg, "ros2_gateway") as gw_bus, \
                client(cfg, "ros2") as ros, client(cfg, "telemetry") as intruder:
            watch.subscribe(watch.keys.events_log, LogEvent, on_log)
            svc = Ros2GatewayService(cfg.ros2, gw_bus)  # holds its tokens
            fake = "@ros2_lv/5/0123456789abcdef/0/0/NN/%/%/impostor"
            token = intruder.session.liveliness().declare_token(fake)
            deadline = time.monotonic() + 10.0
            seen: list[str] = []
            while time.monotonic() < deadline:
                replies = ros.session.liveliness().get("@ros2_lv/**", timeout=2.0)
                seen = [str(r.ok.key_expr) for r in replies if r.ok is not None]
                if len(seen) >= 4:
                    break
                time.sleep(0.2)
            tokens = [parse_token(k) for k in seen]
            assert sorted((t.kind, t.topic) for t in tokens if t) == [
                ("MP", "/drive"), ("MP", "/odom"), ("MP", "/plan"), ("NN", None),
            ], (seen, reports)
            assert fake not in seen
            deadline = time.monotonic() + 10.0
            while time.monotonic() < deadline:
                with lock:
                    if any("impostor" in r for r in reports):
                        break
                time.sleep(0.1)
            token.undeclare()
            assert len(svc.tokens) == 4
        with lock:
            got = list(reports)
        assert any(f"telemetry Liveliness Token (ingress) {fake} x1" in r for r in got), got
        assert not any("ros2_gateway" in r for r in got), got  # its tokens, puts allowed
    finally:
        codes = sup.stop_all(grace_s=5.0)
        assert all(c is not None for c in codes.values()), f"left running: {codes}"
