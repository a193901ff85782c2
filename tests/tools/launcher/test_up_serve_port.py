"""``racestack up --serve PORT`` with the port already taken (a Rerun viewer serving there):
one line and exit code 2 before anything starts (no bus, no process, no run folder)."""

from __future__ import annotations

import socket
from pathlib import Path

from services.tools.launcher import up
from shared.config import RacestackConfig
from shared.net import loopback_port_taken


def test_a_taken_serve_port_stops_up_before_anything_starts(tmp_path: Path, capsys,
                                                            monkeypatch) -> None:
    opened = []
    monkeypatch.setattr(up.Launcher, "open_bus", lambda *a, **k: opened.append(1))
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as viewer:
        viewer.bind(("127.0.0.1", 0))
        viewer.listen(1)
        port = viewer.getsockname()[1]
        assert loopback_port_taken(port)
        run_dir = tmp_path / "run"
        opts = up.UpOptions(config_path=None, run_dir=run_dir,
                            telemetry_args=["--serve", str(port)])
        assert up.run_up(RacestackConfig(), opts) == 2
    err = capsys.readouterr().err
    assert f"--serve {port}: 127.0.0.1:{port} is already in use" in err
    assert len(err.strip().splitlines()) == 1
    assert opened == [] and not run_dir.exists()
