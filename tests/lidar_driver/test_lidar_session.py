"""The driver's session against the fake sensor's model in a plain loop (no I/O, no Zenoh)."""

from __future__ import annotations

import numpy as np

from services.lidar_driver.session import (
    LidarSession,
    Note,
    Phase,
    Reconnect,
    ScanReady,
    stream_rate_hz,
)
from shared.config.lidar import LidarDriverSettings
from shared.hokuyo.fake import FakeHokuyoModel

WALL0 = 1_700_000_000.0
#: Transport delay of the loop [s] (each direction).
DELAY_S = 0.001


def golden(n: int = 4) -> list[np.ndarray]:
    rng = np.random.default_rng(7)
    out = [rng.integers(20, 29000, 1081) for _ in range(n)]
    for k, s in enumerate(out):
        s[0] = 1000 + k  # tells the scans apart
        s[1:4] = [0, 5, 19]  # error codes
    return out


class Loop:
    """Session and model on one time line; bytes take ``DELAY_S`` to arrive."""

    def __init__(self, settings: LidarDriverSettings, **model: object) -> None:
        self.scans = golden()
        self.model = FakeHokuyoModel(self.scans, **model)  # type: ignore[arg-type]
        self.session = LidarSession(settings)
        self.t = 0.0
        self.out: list[object] = []
        self.tx = self.session.start(self.t, WALL0)

    def run(self, duration_s: float, dt: float = 0.005) -> list[object]:
        got: list[object] = []
        end = self.t + duration_s
        while self.t < end:
            self.t += dt
            rx = self.model.receive(self.tx, self.t - DELAY_S) + self.model.due(self.t - DELAY_S)
            self.tx, o = self.session.feed(rx, self.t, WALL0 + self.t)
            more, o2 = self.session.tick(self.t, WALL0 + self.t)
            self.tx += more
            got += o + o2
        self.out += got
        return got


def scans_of(items: list[object]) -> list[ScanReady]:
    return [o for o in items if isinstance(o, ScanReady)]


def test_handshake_then_golden_scans_unchanged_with_tm_stamps() -> None:
    loop = Loop(LidarDriverSettings(), clock_start_ms=(1 << 24) - 100)
    got = loop.run(0.5)
    scans = scans_of(got)
    assert loop.session.phase is Phase.STREAMING
    assert len(scans) >= 15
    notes = [o.text for o in got if isinstance(o, Note)]
    assert any("1081 beams" in t and "40.0 Hz" in t for t in notes), notes
    for sc in scans:
        k = round(sc.ranges_m[0] * 1000) - 1000
        expect = (loop.scans[k] / 1000.0).astype(np.float32)
        expect[1:4] = np.inf
        expect[loop.scans[k] > 30000] = np.inf
        assert np.array_equal(sc.ranges_m, expect)
        assert sc.geometry.beams == 1081
    # the stamps are the sensor's acquisition times on the host clock (TM offset), not the
    # receipt: within one loop step (the TM exchange's asymmetry here) of the true time
    start = loop.model.clock_start_ms
    for sc in scans:
        true_s = WALL0 + ((sc.raw.sensor_ms - start) % (1 << 24)) * 1e-3
        assert abs(sc.stamp_s - true_s) <= 0.0065
    gaps = np.diff([sc.stamp_s for sc in scans])
    assert np.allclose(gaps, 0.025, atol=0.0011)
    assert loop.session.clock.wraps == 1  # the 24-bit counter wrapped during the run
    assert loop.session.decoder.counters.errors == 0


def test_min_filter_and_host_stamps() -> None:
    for source in ("min_filter", "host"):
        loop = Loop(LidarDriverSettings(stamp_source=source))
        scans = scans_of(loop.run(0.4))
        assert len(scans) >= 10
        assert not any(b"TM" in r for r in loop.model.requests)
        assert all(sc.stamp_s <= WALL0 + loop.t for sc in scans)


def test_intensity_flip_cluster_and_step_window() -> None:
    s = LidarDriverSettings(
        intensity=True, upside_down=True, cluster=3, first_step=180, last_step=899
    )
    loop = Loop(s)
    scans = scans_of(loop.run(0.3))
    assert scans
    sc = scans[0]
    assert loop.model.requests[-1].startswith(b"ME0180089903")
    assert sc.geometry.beams == 240 and sc.raw.intensities is not None
    assert sc.geometry.angle_increment_rad < 0


def test_garbage_bad_checksums_and_truncated_scans_are_counted_and_survived() -> None:
    loop = Loop(LidarDriverSettings())
    loop.run(0.3)
    before = len(scans_of(loop.out))
    loop.model.garbage = b"\x00\xff\xfe noise\n\n\x10\x11"
    loop.model.corrupt = 2
    loop.run(0.2)
    loop.model.truncate = 2
    loop.run(0.3)
    after = scans_of(loop.out)[before:]
    d, c = loop.session.decoder.counters, loop.session.counters
    assert d.checksum_errors == 2
    assert d.truncated + c.bad_scans >= 2
    assert d.no_echo >= 1
    assert len(after) >= 15  # the stream goes on
    assert loop.session.phase is Phase.STREAMING


def test_a_silent_sensor_asks_for_a_reconnect_and_a_mute_one_fails_the_handshake() -> None:
    s = LidarDriverSettings(silence_timeout_s=0.2, reply_timeout_s=0.1, handshake_attempts=2)
    loop = Loop(s)
    loop.run(0.3)
    loop.model.silent = True
    got = loop.run(0.3)
    assert next(o for o in got if isinstance(o, Reconnect)).reason.startswith("no scan")
    assert loop.session.phase is Phase.IDLE
    loop.tx = loop.session.start(loop.t, WALL0 + loop.t)  # the shell reopened the link
    got = loop.run(0.5)
    (rec,) = [o for o in got if isinstance(o, Reconnect)]
    assert "no answer to QT after 2 tries" in rec.reason
    loop.model.silent = False
    loop.tx = loop.session.start(loop.t, WALL0 + loop.t)
    assert scans_of(loop.run(0.4))


def test_the_stream_rate_follows_the_skip_count() -> None:
    """SCIP 2.0's skip count leaves scans out: 2400 rpm is 40 Hz, skip 1 every other scan
    (20 Hz), skip 3 one in four (10 Hz); the info line says so."""
    assert [stream_rate_hz(2400.0, k) for k in (0, 1, 3)] == [40.0, 20.0, 10.0]
    loop = Loop(LidarDriverSettings(skip=1))
    notes = [o.text for o in loop.run(0.3) if isinstance(o, Note)]
    assert any("20.0 Hz" in t for t in notes), notes


def test_junk_lines_in_front_of_a_scan_are_a_noise_piece() -> None:
    loop = Loop(LidarDriverSettings())
    loop.run(0.2)
    before = len(scans_of(loop.out))
    loop.model.garbage = b"junk line\nmore junk\n"  # no empty line: glued to the next scan
    loop.run(0.2)
    d = loop.session.decoder.counters
    assert d.no_echo == 1 and d.garbage_bytes == len(b"junk line\nmore junk\n")
    assert len(scans_of(loop.out)) > before + 3
