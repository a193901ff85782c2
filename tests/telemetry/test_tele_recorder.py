"""The telemetry core without Zenoh: inbox policy, recorder output, warnings, helpers."""

from __future__ import annotations

import socket
import sys
import threading
import time
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pydantic
import pytest
import rerun as rr

from services.telemetry.inbox import Inbox
from services.telemetry.recorder import (
    SIM_TIME,
    WALL_TIME,
    Recorder,
    footprint,
    timeline_of,
)
from services.telemetry.recording import (
    connect_url,
    display_available,
    free_recording_stem,
    new_run_dir,
    open_segment,
    serve_problem,
    spawn_viewer,
)
from services.telemetry.synthetic import lap_stream
from services.tools import report
from shared.config.telemetry import TelemetrySettings
from shared.curvature import curvature_profile
from shared.keys import IMU, LAP, PLAN, SIM_TRUTH, STATE, VESC_STATE
from shared.messages import Imu, LapEvent, Plan, SimTruth, VescState
from shared.track import Track, load_track

Rec = tuple[rr.RecordingStream, Path]


class FakeClock:
    """A settable wall clock [s]."""

    def __init__(self, t: float = 1_800_000_000.0) -> None:
        self.t = t

    def __call__(self) -> float:
        return self.t


@pytest.fixture
def track(tele_circle_csv: Path) -> Track:
    return load_track(str(tele_circle_csv))


@pytest.fixture
def recording(tmp_path: Path) -> Iterator[tuple[rr.RecordingStream, Path]]:
    path = tmp_path / "t.rrd"
    rec = open_segment(TelemetrySettings(), path, "unit")
    try:
        yield rec, path
    finally:
        rec.disconnect()


def _close(rec: rr.RecordingStream, recorder: Recorder) -> None:
    recorder.close()
    rec.flush(timeout_sec=5.0)
    rec.disconnect()


def _texts(data: report.RecordingData, entity: str) -> list[str]:
    return [r["TextLog:text"] for r in data.rows.get(entity, [])]


# --------------------------------------------------------------------------- inbox
def test_tele_inbox_drops_oldest_data_never_events() -> None:
    inbox = Inbox(maxlen=5, event_max=1000)
    imu = Imu(stamp_s=1.0, yaw_rate_radps=0.0, ax_mps2=0.0, ay_mps2=0.0)
    lap = LapEvent(stamp_s=1.0, kind="start", lap=0, off_track_events=0)
    for i in range(200):
        inbox.put(IMU, imu.with_seq(i))
        if i % 20 == 0:
            inbox.put(LAP, lap.with_seq(i // 20))
    assert inbox.dropped() == {IMU: 195}
    assert inbox.received() == {IMU: 200, LAP: 10}
    batch = inbox.get_batch(0.0)
    assert [it.msg.seq for it in batch if it.suffix == LAP] == list(range(10))
    assert [it.msg.seq for it in batch if it.suffix == IMU] == [195, 196, 197, 198, 199]
    assert [it.order for it in batch] == sorted(it.order for it in batch)
    assert inbox.get_batch(0.01) == [] and len(inbox) == 0


def test_tele_inbox_put_never_waits_for_the_consumer() -> None:
    inbox = Inbox(maxlen=100)
    imu = Imu(stamp_s=1.0, yaw_rate_radps=0.0, ax_mps2=0.0, ay_mps2=0.0)
    got: list[int] = []
    stop = threading.Event()

    def consume() -> None:
        while not stop.is_set():
            got.extend(it.msg.seq for it in inbox.get_batch(0.01, max_items=7))
            time.sleep(0.001)  # a slow consumer

    th = threading.Thread(target=consume)
    th.start()
    t = time.perf_counter()
    for i in range(20_000):
        inbox.put(IMU, imu.with_seq(i))
    put_s = time.perf_counter() - t
    stop.set()
    th.join(5.0)
    got.extend(it.msg.seq for it in inbox.drain())
    assert put_s < 2.0
    assert len(got) + inbox.dropped().get(IMU, 0) == 20_000
    assert got == sorted(got)


# --------------------------------------------------------------------------- recorder
def test_tele_recorder_stream_round_trip(recording: Rec, track: Track) -> None:
    rec, path = recording
    clock = FakeClock()
    recorder = Recorder(rec, TelemetrySettings(), clock=clock)
    profile = curvature_profile(track.xy, track.s_m, track.length_m, 1.2, 5.0)
    recorder.log_static(track, profile, {"car": "unit"})
    for t, suffix, msg in lap_stream(track, 2.5, t0_s=50.0, speed_mps=3.5):
        clock.t = 1_800_000_000.0 + t
        recorder.handle(suffix, msg, clock.t + 0.001)
        recorder.periodic()
    _close(rec, recorder)
    data = report.read_recording(path)
    assert data.complete and data.timelines == {SIM_TIME}
    t, v = data.series["speed/measured"]
    kept = round(2.5 * TelemetrySettings().series_max_hz)  # 40 Hz decimated to 30 Hz
    assert len(t) == kept and np.allclose(v, 3.5) and np.all(np.diff(t) > 0)
    t, v = data.series["latency/state"]  # simulation stamps: age above the best case
    assert v.min() == pytest.approx(0.0) and v.max() < 1.0
    t, v = data.series["beta/nsc"]
    assert np.all((v >= 0.0) & (v <= 1.0))
    laps = report.lap_events(data)
    assert [e["kind"] for e in laps] == ["start", "lap"]
    assert laps[1]["lap_time_s"] == pytest.approx(track.length_m / 3.5)
    assert data.static["meta/track"]["name"] == ["circle"]
    rebuilt = report.track_from_recording(data)  # the geometry alone gives the track back
    assert rebuilt.length_m == pytest.approx(track.length_m, rel=1e-6)
    assert np.allclose(rebuilt.w_left_m, track.w_left_m)
    assert data.rows["plan/info"][0]["method"] == "cimpcc"


def test_tele_recorder_wall_clock_stamps_and_latency(recording: Rec) -> None:
    rec, path = recording
    recorder = Recorder(rec, TelemetrySettings())
    now = time.time()
    for i in range(5):
        imu = Imu(stamp_s=now + 0.01 * i, yaw_rate_radps=0.1, ax_mps2=0.0, ay_mps2=0.0)
        recorder.handle(IMU, imu, now + 0.01 * i + 0.004)  # arrives 4 ms after its stamp
    _close(rec, recorder)
    data = report.read_recording(path)
    assert data.timelines == {WALL_TIME}
    t, v = data.series["latency/vehicle_imu"]
    assert np.allclose(v, 4.0, atol=1e-3)
    assert t[0] == pytest.approx(now, abs=1e-6)


def test_tele_timeline_choice() -> None:
    assert timeline_of(12.5) == SIM_TIME
    assert timeline_of(1.7e9) == WALL_TIME
    assert timeline_of(12.5, "wall_time") == WALL_TIME
    box = footprint(1.0, 2.0, np.pi / 2, 0.58, 0.31)
    assert box.shape == (5, 2) and np.allclose(box[0], box[-1])
    assert np.allclose(box[:4].mean(axis=0), [1.0, 2.0])
    assert np.ptp(box[:, 1]) == pytest.approx(0.58) and np.ptp(box[:, 0]) == pytest.approx(0.31)


def _plan(stamp: float, status: str) -> Plan:
    n = 3
    return Plan(stamp_s=stamp, horizon=np.zeros((n + 1, 4)), inputs=np.zeros((n, 3)),
                beta=np.ones(n), status=status, solver_status="x", iterations=1,
                solve_time_ms=1.0, method="mpcc", s_m=0.0, e_con_m=0.0, source_stamp_s=stamp,
                consecutive_failures=0 if status == "solved" else 1)


def test_tele_warnings_are_rate_limited(recording: Rec) -> None:
    rec, path = recording
    clock = FakeClock(1000.0)
    recorder = Recorder(rec, TelemetrySettings(warn_interval_s=5.0), clock=clock)
    key = "racestack/car0/state"
    for i in range(10):  # one new garbage payload a second for 10 s
        clock.t += 1.0
        recorder.handle(PLAN, _plan(10.0 + i, "fallback"), clock.t)
        recorder.note_rejected({(key, "not_msgpack"): i + 1})
    recorder.note_queue(3, {IMU: 7}, {STATE: 2})
    truth = {"x_m": 0.0, "y_m": 0.0, "yaw_rad": 0.0, "speed_mps": 1.0, "yaw_rate_radps": 0.0,
             "slip_rad": 0.0, "steering_rad": 0.0, "s_m": 1.0, "e_con_m": 0.5, "lap": 0}
    recorder.handle(SIM_TRUTH, SimTruth(stamp_s=21.0, off_track=True, **truth), clock.t)
    recorder.handle(PLAN, _plan(21.5, "solved"), clock.t)
    recorder.handle(VESC_STATE, VescState(stamp_s=22.0, status="fault", fault_code=3,
                                          v_in_v=11.5), clock.t)
    _close(rec, recorder)
    data = report.read_recording(path)
    texts = _texts(data, "events/telemetry")
    rejected = [x for x in texts if x.startswith("rejected messages")]
    assert len(rejected) == 2  # at 1001 s and 1006 s, not ten
    assert "similar" in rejected[1]
    assert len([x for x in texts if x.startswith("solver fallback")]) == 2
    assert any(x.startswith("telemetry overloaded") and "vehicle/imu x7" in x for x in texts)
    assert any(x.startswith("off track") for x in texts)
    assert any(x.startswith("solver recovered") for x in texts)
    assert data.series["telemetry/rejected/racestack_car0_state"][1][-1] >= 6
    assert data.series["telemetry/seq_gaps/state"][1][-1] == 2
    assert data.series["vesc/v_in_v"][1].tolist() == [11.5]
    assert any("fault code 3" in x for x in _texts(data, "events/vesc"))


def test_tele_silence_is_reported_as_stale_input(recording: Rec) -> None:
    rec, path = recording
    clock = FakeClock(1000.0)
    recorder = Recorder(rec, TelemetrySettings(stale_after_s=0.5), clock=clock)
    recorder.handle(PLAN, _plan(5.0, "solved"), clock.t)
    clock.t += 0.3
    recorder.check_silence(clock.t)
    clock.t += 0.5
    recorder.check_silence(clock.t)
    recorder.check_silence(clock.t + 1.0)  # reported once, not again
    recorder.handle(PLAN, _plan(6.0, "solved"), clock.t)
    _close(rec, recorder)
    texts = _texts(report.read_recording(path), "events/telemetry")
    assert len([x for x in texts if x.startswith("stale input: no message on planner/plan")]) == 1
    assert any("messages again" in x for x in texts)


def test_tele_recording_is_readable_while_open(tmp_path: Path, track: Track) -> None:
    """A crash after a periodic flush keeps what was flushed (the file is streamable)."""
    path = tmp_path / "open.rrd"
    rec = open_segment(TelemetrySettings(), path, "open")
    try:
        recorder = Recorder(rec, TelemetrySettings())
        recorder.log_static(track)
        for _t, suffix, msg in lap_stream(track, 0.5, t0_s=10.0):
            recorder.handle(suffix, msg, time.time())
        recorder.flush()
        rec.flush(timeout_sec=5.0)
        data = report.read_recording(path)  # no footer yet
        assert not data.complete
        kept = round(0.5 * TelemetrySettings().series_max_hz)  # 40 Hz decimated
        assert len(data.series["speed/measured"][0]) == kept
        assert "world/track/left" in data.static
    finally:
        rec.disconnect()


# --------------------------------------------------------------------------- helpers
def test_tele_settings_and_helpers(tmp_path: Path) -> None:
    s = TelemetrySettings()
    assert s.serve_bind_ip == "127.0.0.1" and s.serve_port is None and not s.viewer
    assert (s.car_length_m, s.car_width_m) == (0.58, 0.31)
    with pytest.raises(pydantic.ValidationError):
        TelemetrySettings(serve_bind_ip="not-an-ip")
    with pytest.raises(pydantic.ValidationError):
        TelemetrySettings(unknown_key=1)
    with pytest.raises(pydantic.ValidationError):
        TelemetrySettings(serve_port=70000)
    assert connect_url("127.0.0.1", 9876) == "rerun+http://127.0.0.1:9876/proxy"
    assert connect_url("0.0.0.0", 1) == "rerun+http://127.0.0.1:1/proxy"
    assert not display_available({}, "linux")
    assert not display_available({"DISPLAY": ":0", "CI": "1"}, "linux")
    assert display_available({"DISPLAY": ":0"}, "linux")
    a = new_run_dir(tmp_path, now=0.0)
    b = new_run_dir(tmp_path, now=0.0)
    assert a != b and a.is_dir() and b.is_dir()
    assert free_recording_stem(a) == "telemetry"
    (a / "telemetry.rrd").write_bytes(b"x")  # a single-file recording of an older version
    assert free_recording_stem(a) == "telemetry-2"
    (a / "telemetry-2.0000.rrd").write_bytes(b"x")
    assert free_recording_stem(a) == "telemetry-3"
    with pytest.raises(FileNotFoundError):
        report.find_recording(b)
    assert report.main([str(tmp_path / "missing.rrd")]) == 2


def test_tele_serve_port_checks_and_no_viewer_without_display(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as busy:
        busy.bind(("127.0.0.1", 0))
        busy.listen()
        port = busy.getsockname()[1]
        assert "127.0.0.1:" in (serve_problem("127.0.0.1", port) or "")
    assert serve_problem("127.0.0.1", 0) is not None
    assert serve_problem("127.0.0.1", 70000) is not None
    for name in ("DISPLAY", "WAYLAND_DISPLAY"):
        monkeypatch.delenv(name, raising=False)
    monkeypatch.setattr(sys, "platform", "linux")
    assert spawn_viewer("rerun+http://127.0.0.1:1/proxy") is None  # never a viewer here


def test_tele_recorder_logs_opponents_as_boxes_and_a_count(recording: Rec) -> None:
    from shared.keys import OPPONENTS
    from shared.messages import Opponents, OpponentTrack

    rec, path = recording
    recorder = Recorder(rec, TelemetrySettings())
    now = time.time()
    track = OpponentTrack(id=2, x_m=1.0, y_m=0.5, vx_mps=2.0, vy_mps=0.0, yaw_rad=0.0,
                          length_m=0.58, width_m=0.31, cov_xx_m2=1e-4, cov_xy_m2=0.0,
                          cov_yy_m2=1e-4, speed_var_m2ps2=0.01, age_s=0.5, hits=6)
    for i in range(5):
        t = now + 0.05 * i
        tracks = [track] if i else []
        recorder.handle(OPPONENTS, Opponents(stamp_s=t, source_stamp_s=t, tracks=tracks), t)
    _close(rec, recorder)
    data = report.read_recording(path)
    assert recorder.errors == 0 and recorder.counts[OPPONENTS] == 5
    _, n = data.series["opponents/count"]
    assert n[0] == 0 and n[-1] == 1
