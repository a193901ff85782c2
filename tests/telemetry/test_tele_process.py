"""The real telemetry PROCESS records a synthetic lap published over Zenoh (loopback only).

The test process is the hub (``Bus(..., listen_default=True)`` on a free loopback port); the
telemetry service runs as ``python -m services.telemetry --config <tmp toml> --out <dir>``,
connects to it, and is stopped with SIGINT (then killed by PID if it hangs). Garbage is
injected on several keys in the middle of the lap. The recording is read back with
``rr.chunk.RrdReader``.
"""

from __future__ import annotations

import json
import math
import os
import socket
import subprocess
import sys
import time
from collections import defaultdict
from pathlib import Path
from typing import Any

import msgpack
import numpy as np
import pyarrow as pa
import pytest
import rerun as rr

from services.telemetry.rrd_files import find_segments
from services.telemetry.synthetic import lap_stream, replay
from services.tools import report
from services.tools.launcher.supervisor import stop_process
from shared.bus import Bus
from shared.config import load_config
from shared.config.methods import CIMPCC
from shared.config.telemetry import TelemetrySettings
from shared.keys import DRIVE_CMD, EVENTS_LOG, LAP, PLAN, POSE, STATE
from shared.messages import LogEvent, State
from shared.track import load_track

ROOT = Path(__file__).resolve().parents[2]
T0_S = 1000.0  #: first stamp of the synthetic stream [s] (simulation time)
DURATION_S = 2.6  #: length of the stream [s]
SEGMENT_S = 1.0  #: [telemetry] segment_interval_s of the run: several segments [s]
SPEED_MPS = 3.5
GARBAGE_AT_S = 1.0  #: stream time of the garbage burst [s]
START_TIMEOUT_S = 25.0
STOP_TIMEOUT_S = 15.0

#: Invalid payloads of several kinds, put on several keys between valid messages.
GARBAGE: list[tuple[str, bytes]] = [
    (STATE, b"\xc1 not msgpack at all"),
    (
        STATE,
        msgpack.packb(
            {
                "type": "pose",
                "v": 1,
                "stamp_s": 1.0,
                "seq": 0,
                "x_m": 0.0,
                "y_m": 0.0,
                "yaw_rad": 0.0,
            }
        ),
    ),
    (PLAN, msgpack.packb({"type": "plan", "v": 1, "stamp_s": 1.0, "seq": 0})),
    (
        POSE,
        msgpack.packb(
            {
                "type": "pose",
                "v": 1,
                "stamp_s": 1.0,
                "seq": 0,
                "x_m": float("nan"),
                "y_m": 0.0,
                "yaw_rad": 0.0,
            }
        ),
    ),
    (LAP, b""),
    (EVENTS_LOG, msgpack.packb([1, 2, 3])),
    (
        DRIVE_CMD,
        msgpack.packb(
            {
                "type": "drive_cmd",
                "v": 99,
                "stamp_s": 1.0,
                "seq": 0,
                "speed_mps": 1.0,
                "steering_rad": 0.0,
            }
        ),
    ),
]


def _stop(proc: subprocess.Popen[bytes]) -> int | None:
    """SIGINT by PID, wait; SIGKILL if it does not exit in time."""
    return stop_process(proc, STOP_TIMEOUT_S)


def _wait_or_kill(proc: subprocess.Popen[bytes] | None) -> int | None:
    """Wait for a process that ends by itself (its stream closed); kill it by PID if not."""
    if proc is None:
        return None
    try:
        return proc.wait(timeout=STOP_TIMEOUT_S)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.wait(timeout=5)
        return None


def _free_ports(n: int) -> list[int]:
    socks = [socket.socket(socket.AF_INET, socket.SOCK_STREAM) for _ in range(n)]
    try:
        for s in socks:
            s.bind(("127.0.0.1", 0))
        return [int(s.getsockname()[1]) for s in socks]
    finally:
        for s in socks:
            s.close()


def read_rrd(path: Path) -> dict[str, dict[str, list[Any]]]:
    """entity -> column -> values (rows of every chunk in file order, the segments of a
    segmented recording one after the other; times in s)."""
    out: dict[str, dict[str, list[Any]]] = defaultdict(lambda: defaultdict(list))
    chunks = [c for f in find_segments(path)
              for c in rr.chunk.RrdReader(str(f)).stream().collect().stream()]
    for chunk in chunks:
        rb = chunk.to_record_batch()
        cols = out[chunk.entity_path.lstrip("/")]
        for name in rb.schema.names:
            if name == "rerun.controls.RowId":
                continue
            col = rb.column(name)
            if name in ("sim_time", "wall_time"):
                cols[name].extend(
                    (col.cast(pa.int64()).to_numpy(zero_copy_only=False) / 1e9).tolist()
                )
            else:
                cols[name].extend(col.to_pylist())
    return out


@pytest.fixture(scope="module")
def recorded(tmp_path_factory: pytest.TempPathFactory, tele_circle_csv: Path) -> dict[str, Any]:
    """Run the telemetry process against a published synthetic lap; returns what happened."""
    tmp = tmp_path_factory.mktemp("tele-run")
    port, serve_port, saver_port = _free_ports(3)
    toml = tmp / "racestack.toml"
    toml.write_text(
        f'[track]\nsource = "{tele_circle_csv}"\n\n'
        f'[bus]\ncar = "teletest"\nlisten = ["tcp/127.0.0.1:{port}"]\n\n'
        f"[telemetry]\nsegment_interval_s = {SEGMENT_S}\n",
        encoding="utf-8",
    )
    cfg = load_config(toml)
    out = tmp / "run"
    env = {**os.environ, "PYTHONPATH": str(ROOT), "PYTHONUNBUFFERED": "1"}
    log_path = tmp / "telemetry.log"
    with Bus(cfg.bus, "test", listen_default=True) as hub, open(log_path, "wb") as log:
        proc = subprocess.Popen(
            [
                sys.executable,
                "-m",
                "services.telemetry",
                "--config",
                str(toml),
                "--out",
                str(out),
                "--serve",
                str(serve_port),
            ],
            cwd=str(ROOT),
            env=env,
            stdout=log,
            stderr=subprocess.STDOUT,
        )
        saver: subprocess.Popen[bytes] | None = None
        try:
            assert hub.wait_alive(["telemetry"], timeout_s=START_TIMEOUT_S), (
                "telemetry did not come up:\n" + log_path.read_text(errors="replace")
            )
            # a headless client of the live stream (what a viewer gets), its own gRPC
            # server bound to loopback: `rerun --bind 127.0.0.1 --port P URL --save FILE`
            saver = subprocess.Popen(
                [
                    str(Path(sys.executable).parent / "rerun"),
                    "--bind",
                    "127.0.0.1",
                    "--port",
                    str(saver_port),
                    f"rerun+http://127.0.0.1:{serve_port}/proxy",
                    "--save",
                    str(tmp / "live.rrd"),
                ],
                cwd=str(tmp),
                env=env,
                stdout=subprocess.DEVNULL,
                stderr=subprocess.DEVNULL,
            )
            probe = hub.publisher(hub.keys.state, State)
            assert probe.wait_matching(5.0)
            probe.undeclare()
            logs = hub.subscribe(hub.keys.events_log, LogEvent, queue_size=1000)
            garbage_sent: list[float] = []

            def inject(t: float) -> None:
                if not garbage_sent and t >= GARBAGE_AT_S:
                    for suffix, payload in GARBAGE:
                        hub.put_raw(hub.keys.key(suffix), payload)
                    garbage_sent.append(t)

            track = load_track(str(tele_circle_csv))
            sent = replay(
                hub,
                lap_stream(track, DURATION_S, t0_s=T0_S, speed_mps=SPEED_MPS),
                before_put=inject,
            )
            t_report = time.monotonic() + 5.0  # the rejections reported within a period
            reported = False
            while not reported and time.monotonic() < t_report:
                reported = any(e.source == "telemetry" and "rejected" in e.text
                               for e in logs.drain())
                time.sleep(0.05)
        finally:
            code = _stop(proc)
            saver_code = _wait_or_kill(saver)
    return {
        "reported_rejections": reported,
        "code": code,
        "sent": sent,
        "garbage_at": T0_S + garbage_sent[0],
        "out": out,
        "serve_port": serve_port,
        "saver_code": saver_code,
        "live": tmp / "live.rrd",
        "log": log_path.read_text(errors="replace"),
        "data": read_rrd(out),
        "track": track,
    }


def _monotone(times: list[float]) -> bool:
    return bool(np.all(np.diff(np.asarray(times)) >= 0.0))


def test_tele_process_exits_cleanly_and_writes_files(recorded: dict[str, Any]) -> None:
    assert recorded["code"] == 0, recorded["log"]
    out: Path = recorded["out"]
    segments = find_segments(out)
    assert len(segments) >= 2, "a new segment every SEGMENT_S"
    assert [p.name for p in segments[:2]] == ["telemetry.0000.rrd", "telemetry.0001.rrd"]
    assert sum(p.stat().st_size for p in segments) > 10_000
    assert (out / "telemetry.rbl").is_file()
    stats = json.loads((out / "telemetry_stats.json").read_text())
    assert stats["segments"] == [p.name for p in segments]
    assert stats["dropped_by_queue"] == {}
    assert stats["record_errors"] == 0
    assert sum(stats["rejected"].values()) >= len(GARBAGE) - 1  # every bad payload counted
    for path in segments:  # each closed cleanly: footer, static track
        reader = rr.chunk.RrdReader(str(path))
        reader.store()  # needs the footer
        entities = {c.entity_path.lstrip("/") for c in reader.stream().collect().stream()}
        assert "world/track/left" in entities, path.name  # every segment has the track
    # the layout is sent once (each blueprint sent leaks memory in rerun-sdk 0.41)
    assert rr.chunk.RrdReader(str(segments[0])).blueprints()


def test_tele_reports_its_rejections_on_events_log(recorded: dict[str, Any]) -> None:
    """Like every service, telemetry publishes its rejected-payload counts on events/log."""
    assert recorded["reported_rejections"], recorded["log"]


def test_tele_track_is_static(recorded: dict[str, Any]) -> None:
    data, track = recorded["data"], recorded["track"]
    for name in ("centerline", "left", "right"):
        cols = data[f"world/track/{name}"]
        assert "sim_time" not in cols  # static: no timeline
        strip = np.asarray(cols["LineStrips2D:strips"][0][0])
        assert strip.shape == (track.n_points + 1, 2)
        r = np.hypot(strip[:, 0], strip[:, 1] - 1.2)
        expect = {"centerline": 1.2, "left": 0.8, "right": 1.6}[name]  # CCW: left is inside
        assert np.allclose(r, expect, atol=1e-3)
    meta = data["meta/track"]
    assert meta["source"][0] == [track.source]
    assert meta["length_m"][0][0] == pytest.approx(track.length_m)


def test_tele_car_pose_and_horizon(recorded: dict[str, Any]) -> None:
    data, sent = recorded["data"], recorded["sent"]
    car = data["world/car"]
    drawn = min(sent[STATE], DURATION_S * TelemetrySettings().visual_max_hz)  # rate-limited
    assert len(car["sim_time"]) >= 0.9 * drawn
    assert _monotone(car["sim_time"])
    assert T0_S <= car["sim_time"][0] and car["sim_time"][-1] <= T0_S + DURATION_S
    assert len(car["LineStrips2D:strips"]) == len(car["sim_time"])
    for strips in car["LineStrips2D:strips"]:
        box = np.asarray(strips[0])
        assert box.shape == (5, 2)
        sides = np.hypot(*np.diff(box, axis=0).T)
        assert sorted(np.round(sides, 3)) == [0.31, 0.31, 0.58, 0.58]
        centre = box[:4].mean(axis=0)
        assert abs(math.hypot(centre[0], centre[1] - 1.2) - 1.2) < 0.05  # on the circle
    assert len(car["Arrows2D:vectors"]) == len(car["sim_time"])
    horizon = data["world/plan/horizon"]
    assert len(horizon["sim_time"]) >= 0.9 * sent[PLAN]
    assert _monotone(horizon["sim_time"])
    for strips in horizon["LineStrips2D:strips"]:
        pts = np.asarray(strips[0])
        assert pts.shape == (11, 2)
        assert np.all(np.abs(np.hypot(pts[:, 0], pts[:, 1] - 1.2) - 1.2) < 0.05)
    assert len(data["world/car_beta"]["Points2D:positions"]) == len(horizon["sim_time"])
    assert any(k.startswith("world/path/lap_") for k in data)


def _series(data: dict[str, Any], entity: str) -> tuple[np.ndarray, np.ndarray]:
    cols = data[entity]
    rows = [
        (t, v[0])
        for t, v in zip(cols["sim_time"], cols["Scalars:scalars"], strict=True)
        if v is not None
    ]
    t = np.array([r[0] for r in rows])
    return t, np.array([r[1] for r in rows])


def test_tele_series_speed_solve_time_latency(recorded: dict[str, Any]) -> None:
    data, sent = recorded["data"], recorded["sent"]
    for entity, key, lo, hi in (
        ("speed/measured", STATE, SPEED_MPS - 1e-9, SPEED_MPS + 1e-9),
        ("speed/commanded", DRIVE_CMD, SPEED_MPS - 1e-9, SPEED_MPS + 1e-9),
        ("solver/solve_time_ms", PLAN, 4.0, 6.0),
        ("beta/beta", PLAN, 0.0, 1.0),
        ("latency/state", STATE, 0.0, 500.0),
    ):
        t, v = _series(data, entity)
        kept = min(sent[key], DURATION_S * TelemetrySettings().series_max_hz)  # decimated
        assert len(t) >= 0.9 * kept, entity
        assert _monotone(t.tolist()), entity
        assert T0_S <= t[0] and t[-1] <= T0_S + DURATION_S, entity
        assert np.all((v >= lo) & (v <= hi)), (entity, v.min(), v.max())
    t, v = _series(data, "solver/status_code")
    assert np.all(v == 0)


def test_tele_lap_and_log_events(recorded: dict[str, Any]) -> None:
    data = recorded["data"]
    lap = data["events/lap"]
    assert lap["kind"] == [["start"], ["lap"]]
    assert lap["lap"][1] == [1]
    lap_time = recorded["track"].length_m / SPEED_MPS
    assert lap["lap_time_s"][1][0] == pytest.approx(lap_time, rel=1e-9)
    assert lap["sim_time"][1] == pytest.approx(T0_S + lap_time, abs=1e-6)
    assert "lap 1:" in lap["TextLog:text"][1][0]
    _t, v = _series(data, "laps/lap_time_s")
    assert v.tolist() == pytest.approx([lap_time])
    logs = data["events/log/synthetic"]
    assert len(logs["TextLog:text"]) == 3 and _monotone(logs["sim_time"])


def test_tele_garbage_does_not_stop_the_recording(recorded: dict[str, Any]) -> None:
    data, after = recorded["data"], recorded["garbage_at"]
    for entity in ("state/x_m", "solver/solve_time_ms", "pose/x_m", "speed/commanded"):
        t, _ = _series(data, entity)
        assert np.count_nonzero(t > after + 0.5) >= 10, entity  # valid messages after it
    assert data["events/log/synthetic"]["sim_time"][-1] > after  # events too
    warnings = [txt[0] for txt in data["events/telemetry"]["TextLog:text"] if txt]
    rejected = [w for w in warnings if w.startswith("rejected messages")]
    assert rejected, warnings
    assert "racestack/teletest/state" in rejected[0] and "not_msgpack" in rejected[0]
    assert any(k.startswith("telemetry/rejected/") for k in data)


def test_tele_report_of_the_recording(
    recorded: dict[str, Any], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    rc = report.main([str(recorded["out"]), "--out", str(tmp_path)])
    text = capsys.readouterr().out
    assert rc == 0, text
    lap_time = recorded["track"].length_m / SPEED_MPS
    assert f"{lap_time:.3f}" in text and CIMPCC in text and "1/1" in text
    doc = json.loads((tmp_path / "results.json").read_text())
    laps = doc["methods"][CIMPCC]["laps"]
    assert len(laps) == 1 and laps[0]["lap_time_s"] == pytest.approx(lap_time)
    for name in (
        "fig4_curvature.png",
        "fig5_speed_vs_s.png",
        "fig6_trajectories.png",
        "fig7_laps.png",
        "fig8_solve_time.png",
    ):
        assert (tmp_path / name).stat().st_size > 1000


def test_tele_live_stream_on_loopback(recorded: dict[str, Any]) -> None:
    url = f"rerun+http://127.0.0.1:{recorded['serve_port']}/proxy"
    assert f"rerun --connect {url}" in recorded["log"]  # the exact line to type
    assert recorded["saver_code"] == 0
    live = read_rrd(recorded["live"])
    assert "world/track/left" in live  # logged before the client connected: buffered
    assert live["events/lap"]["kind"] == [["start"], ["lap"]]
    assert len(live["world/car"]["sim_time"]) == len(recorded["data"]["world/car"]["sim_time"])
