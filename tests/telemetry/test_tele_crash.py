"""A SIGKILL mid-race loses at most the open segment's last second (issue 15).

The real telemetry process records a synthetic race (``services.telemetry.synthetic``) in
segments of ``SEGMENT_S``; it is SIGKILLed (by its PID) while the stream still flows. Then:

* every closed segment passes ``rerun rrd verify`` (footer and manifest present) and
  ``RrdReader.store()`` opens it;
* the open segment has no footer, and is read by streaming as far as it goes;
* every ``State`` sent up to one second before the kill is in what ``racestack report``
  reads from the folder (the segments as one recording), and the report runs.

Also, without a process: a segment cut inside a message (a crash while writing) is read up
to its last complete message, and the forms of a recording ``find_segments`` accepts.
"""

from __future__ import annotations

import os
import signal
import struct
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import rerun as rr

from services.telemetry.recorder import Recorder
from services.telemetry.recording import open_segment, segment_path
from services.telemetry.rrd_files import find_segments, read_store, readable_length
from services.telemetry.synthetic import lap_stream, replay
from services.tools import report
from shared.bus import Bus
from shared.config import load_config
from shared.config.telemetry import TelemetrySettings
from shared.keys import STATE
from shared.messages import State
from shared.track import load_track

ROOT = Path(__file__).resolve().parents[2]
T0_S = 500.0  #: first stamp of the stream [s] (simulation time)
DURATION_S = 4.5  #: stream length [s]: several segments
SEGMENT_S = 1.0  #: [telemetry] segment_interval_s [s]
FLUSH_S = 0.25  #: [telemetry] flush_interval_s and batch_interval_s [s]
LOSS_BOUND_S = 1.0  #: what a kill may lose: the open segment's last second [s]
START_TIMEOUT_S = 25.0


def _rerun_cli() -> str:
    return str(Path(sys.executable).parent / "rerun")


@pytest.fixture(scope="module")
def killed(tmp_path_factory: pytest.TempPathFactory, tele_circle_csv: Path) -> dict:
    """Run the telemetry process, SIGKILL it while the stream flows; what is left."""
    from shared.net import free_loopback_port

    tmp = tmp_path_factory.mktemp("tele-kill")
    port = free_loopback_port()
    toml = tmp / "racestack.toml"
    toml.write_text(
        f'[track]\nsource = "{tele_circle_csv}"\n\n'
        f'[bus]\ncar = "telekill"\nlisten = ["tcp/127.0.0.1:{port}"]\n\n'
        f"[telemetry]\nsegment_interval_s = {SEGMENT_S}\nflush_interval_s = {FLUSH_S}\n"
        f"batch_interval_s = {FLUSH_S}\n"
        "series_max_hz = 0\n",  # every state kept: the loss bound is checked per message
        encoding="utf-8",
    )
    cfg = load_config(toml)
    out = tmp / "run"
    env = {**os.environ, "PYTHONPATH": str(ROOT), "PYTHONUNBUFFERED": "1"}
    log_path = tmp / "telemetry.log"
    sent_states: list[float] = []
    track = load_track(str(tele_circle_csv))
    with Bus(cfg.bus, "test", listen_default=True) as hub, open(log_path, "wb") as log:
        proc = subprocess.Popen(
            [sys.executable, "-m", "services.telemetry", "--config", str(toml),
             "--out", str(out)],
            cwd=str(ROOT), env=env, stdout=log, stderr=subprocess.STDOUT,
        )
        try:
            assert hub.wait_alive(["telemetry"], timeout_s=START_TIMEOUT_S), (
                "telemetry did not come up:\n" + log_path.read_text(errors="replace"))
            probe = hub.publisher(hub.keys.state, State)
            assert probe.wait_matching(5.0)
            probe.undeclare()
            stream = list(lap_stream(track, DURATION_S, t0_s=T0_S))
            sent_states = [m.stamp_s for _t, s, m in stream if s == STATE]
            replay(hub, iter(stream))
            os.kill(proc.pid, signal.SIGKILL)  # at once, while the last messages land
            t_kill = T0_S + DURATION_S
            proc.wait(timeout=10.0)
        finally:
            if proc.poll() is None:
                proc.kill()
                proc.wait(timeout=10.0)
    return {"out": out, "sent_states": sent_states, "t_kill": t_kill, "code": proc.returncode,
            "log": log_path.read_text(errors="replace")}


def test_closed_segments_verify_after_a_sigkill(killed: dict) -> None:
    assert killed["code"] == -signal.SIGKILL
    segments = find_segments(killed["out"])
    assert len(segments) >= 3, (segments, killed["log"])
    closed, open_one = segments[:-1], segments[-1]
    res = subprocess.run([_rerun_cli(), "rrd", "verify", *map(str, closed)],
                         capture_output=True, text=True, timeout=120)
    assert res.returncode == 0, res.stderr + res.stdout
    for path in closed:
        rr.chunk.RrdReader(str(path)).store()  # needs the footer
    _store, complete = read_store(open_one)
    assert not complete, "the open segment of a killed run has no footer"


def test_rows_up_to_the_last_second_before_the_kill_are_read(killed: dict) -> None:
    data = report.read_recording(killed["out"])
    assert not data.complete and len(data.segments) >= 3
    t, _v = data.series["state/x_m"]
    got = set(np.round(t, 6))
    must = [s for s in killed["sent_states"] if s <= killed["t_kill"] - LOSS_BOUND_S]
    missing = [s for s in must if round(s, 6) not in got]
    assert not missing, f"{len(missing)} of {len(must)} states lost: {missing[:5]}"
    assert "world/track/left" in data.static
    assert [e["kind"] for e in report.lap_events(data)][:1] == ["start"]


def test_report_reads_the_killed_run(killed: dict, tmp_path: Path) -> None:
    code = report.main([str(killed["out"]), "--no-figures", "--out", str(tmp_path / "rep")])
    assert code == 0
    assert (tmp_path / "rep" / "results.json").is_file()


# --------------------------------------------------------------------------- no process
def _write_segment(path: Path, track, t0: float, duration_s: float) -> None:
    rec = open_segment(TelemetrySettings(), path, "unit")
    recorder = Recorder(rec, TelemetrySettings())
    recorder.log_static(track)
    for _t, suffix, msg in lap_stream(track, duration_s, t0_s=t0):
        recorder.handle(suffix, msg, time.time())
    recorder.close()
    rec.flush(timeout_sec=5.0)
    rec.disconnect()


def _mid_message(data: bytes, share: float) -> int:
    """An offset in the middle of the payload of the message found at `share` of `data`
    (the 0.41 framing: 12-byte stream header, 16-byte message headers)."""
    off = 12
    while True:
        kind, length = struct.unpack("<QQ", data[off:off + 16])
        assert kind != 0, "reached the end of the stream"
        if off + 16 + length > share * len(data) and length > 16:
            return off + 16 + length // 2
        off += 16 + length


def test_a_segment_cut_inside_a_message_is_read_up_to_there(
    tmp_path: Path, tele_circle_csv: Path
) -> None:
    track = load_track(str(tele_circle_csv))
    whole = tmp_path / "telemetry.0000.rrd"
    _write_segment(whole, track, 10.0, 2.0)
    assert readable_length(whole) == (whole.stat().st_size, True)
    data = whole.read_bytes()
    cut = tmp_path / "cut" / "telemetry.0000.rrd"
    cut.parent.mkdir()
    cut.write_bytes(data[: _mid_message(data, 0.5)])  # inside a message, no footer
    # (0.5: the footer, an index of every chunk, is about 30 % of a 2 s segment)
    length, whole_file = readable_length(cut)
    assert not whole_file and 0 < length < cut.stat().st_size
    with pytest.raises(RuntimeError):  # the SDK alone rejects the file
        rr.chunk.RrdReader(str(cut)).stream().collect()
    store, complete = read_store(cut)
    assert not complete
    n_part = sum(1 for _ in store.stream())
    n_full = sum(1 for _ in read_store(whole)[0].stream())
    assert 0 < n_part < n_full
    assert not report.read_recording(cut).complete  # the report reads it too


def test_find_segments_forms(tmp_path: Path, tele_circle_csv: Path) -> None:
    track = load_track(str(tele_circle_csv))
    run = tmp_path / "run"
    run.mkdir()
    for i in range(3):
        _write_segment(segment_path(run, "telemetry", i), track, 10.0 + i, 0.5)
    names = ["telemetry.0000.rrd", "telemetry.0001.rrd", "telemetry.0002.rrd"]
    assert [p.name for p in find_segments(run)] == names
    assert [p.name for p in find_segments(run / "telemetry.0001.rrd")] == names
    assert [p.name for p in find_segments(run / "telemetry.rrd")] == names  # what `up` prints
    data = report.read_recording(run)
    t = data.series["state/x_m"][0]
    assert t.min() < 10.5 and t.max() > 12.0 and np.all(np.diff(t) >= 0)
    old = tmp_path / "old"
    old.mkdir()
    _write_segment(old / "telemetry.rrd", track, 10.0, 0.5)  # a run of before segments
    assert [p.name for p in find_segments(old)] == ["telemetry.rrd"]
    assert report.read_recording(old).complete
    with pytest.raises(FileNotFoundError):
        find_segments(tmp_path / "nothing")
    (tmp_path / "empty").mkdir()
    with pytest.raises(FileNotFoundError):
        find_segments(tmp_path / "empty")


def test_a_segment_cut_inside_its_footer_keeps_every_message(
    tmp_path: Path, tele_circle_csv: Path
) -> None:
    """A file cut after its end-of-stream marker (inside the footer: a closed file truncated)
    is read without the footer, every message kept, and said to be cut."""
    track = load_track(str(tele_circle_csv))
    whole = tmp_path / "telemetry.0000.rrd"
    _write_segment(whole, track, 10.0, 2.0)
    data = whole.read_bytes()
    off = 12
    while True:  # the end-of-stream marker (kind 0)
        kind, length = struct.unpack("<QQ", data[off:off + 16])
        if kind == 0:
            break
        off += 16 + length
    assert length > 32, "the footer is large enough to cut inside"
    cut = tmp_path / "cut" / "telemetry.0000.rrd"
    cut.parent.mkdir()
    cut.write_bytes(data[: off + 16 + length // 2])
    assert readable_length(cut) == (off, False)
    store, complete = read_store(cut)
    assert not complete
    n_full = sum(1 for _ in read_store(whole)[0].stream())
    assert sum(1 for _ in store.stream()) == n_full
