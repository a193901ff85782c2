"""The pure SCIP 2.0 modules: encoding, checksum, decoder (incl. fuzz), scans, geometry, clock."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from shared.hokuyo.decoder import ResponseDecoder
from shared.hokuyo.encoding import decode_array, decode_int, encode_int, sum_char
from shared.hokuyo.fake import FakeHokuyoModel
from shared.hokuyo.protocol import Code, ScanRequest, describe_status, scan_stream
from shared.hokuyo.scan import (
    BeamGeometry,
    ScanError,
    SensorParams,
    parse_params,
    parse_scan,
    ranges_m,
)
from shared.hokuyo.timesync import WRAP_MS, SensorClock

UTM = SensorParams("UTM-30LX", 23, 60000, 1440, 0, 1080, 540, 2400)


def golden(n: int = 3, seed: int = 0) -> list[np.ndarray]:
    rng = np.random.default_rng(seed)
    out = [rng.integers(0, 60000, 1081) for _ in range(n)]
    for s in out:
        s[:5] = [0, 1, 19, 20, 21]  # error codes and the first real ranges
    return out


def stream_bytes(model: FakeHokuyoModel, code: str = "MD", scans: int = 3) -> bytes:
    """The fake's answer to an MD/ME request and its next scans."""
    req = ScanRequest(Code(code), 0, 1080, 1, 0, 0)
    out = model.receive(scan_stream(req), 0.0)
    for k in range(scans):
        out += model.due(0.025 * (k + 1) + 1e-6)
    return out


# --------------------------------------------------------------------------- encoding
def test_checksum_and_encodings_match_the_document_examples() -> None:
    assert bytes([sum_char(b"00")]) == b"P"
    assert bytes([sum_char(b"99")]) == b"b"
    assert bytes([sum_char(b"DMIN:20")]) == b"4"  # the ';' is not summed
    assert bytes([sum_char(b"SCAN:600")]) == b"e"
    assert decode_int(b"CB") == 1234
    assert decode_int(b"1Dh") == 5432
    assert decode_int(b"m2@0") == 16_000_000
    assert encode_int(5432, 3) == b"1Dh"
    with pytest.raises(ValueError):
        decode_int(b"\x20AB")
    with pytest.raises(ValueError):
        encode_int(1 << 18, 3)


@given(st.lists(st.integers(0, (1 << 18) - 1), min_size=1, max_size=300))
def test_decode_array_inverts_encode(values: list[int]) -> None:
    data = b"".join(encode_int(v, 3) for v in values)
    assert decode_array(data, 3).tolist() == values


# --------------------------------------------------------------------------- decoder
def test_decoder_any_chunking_gives_the_same_responses() -> None:
    data = stream_bytes(FakeHokuyoModel(golden()))
    whole = ResponseDecoder().feed(data)
    assert [r.status for r in whole] == ["00", "99", "99", "99"]
    for size in (1, 7, 64, 65, 1000):
        d = ResponseDecoder()
        got = []
        for i in range(0, len(data), size):
            got += d.feed(data[i : i + size])
        assert got == whole
        assert d.counters.errors == 0 and d.buffered == 0


def test_decoder_resyncs_after_garbage_bad_checksum_and_truncation() -> None:
    model = FakeHokuyoModel(golden())
    clean = stream_bytes(model, scans=1)
    model.corrupt = 1
    bad = model.due(1.0)
    model.truncate = 1
    cut = model.due(2.0)
    good = model.due(3.0)
    d = ResponseDecoder()
    got = d.feed(b"\xff\x00noise" + clean + b"x\n\nMD\n" + bad + cut + good)
    assert [r.status for r in got] == ["00", "99", "99"]
    c = d.counters
    # noise pieces: the bytes in front of the first echo, the "x" piece, the lone "MD" line
    # in front of the corrupt scan's echo
    assert c.checksum_errors == 1 and c.truncated == 1 and c.no_echo == 3
    assert c.garbage_bytes > 0


def test_decoder_bounds_its_buffer() -> None:
    d = ResponseDecoder(max_response=1024)
    d.feed(b"A" * 5000)
    assert d.counters.overlong == 1 and d.buffered <= 1024
    assert d.feed(b"\n\nBM\n00P\n\n")[-1].code is Code.BM


@settings(max_examples=300, deadline=None)
@given(st.binary(max_size=3000), st.integers(1, 500))
def test_decoder_fuzz_random_bytes_never_raise(data: bytes, chunk: int) -> None:
    d = ResponseDecoder(max_response=2048)
    for i in range(0, len(data), chunk):
        for resp in d.feed(data[i : i + chunk]):
            try:
                parse_scan(resp)
            except ScanError:
                pass
    assert d.buffered <= 2048


@settings(max_examples=100, deadline=None)
@given(st.binary(max_size=200).filter(lambda b: b"\n" not in b))
def test_decoder_finds_a_scan_after_noise_without_line_feeds(noise: bytes) -> None:
    model = FakeHokuyoModel(golden())
    data = stream_bytes(model, scans=1)
    got = ResponseDecoder().feed(noise + data)
    assert [r.status for r in got][-1] == "99"


# --------------------------------------------------------------------------- scans, geometry
def test_pp_parameters_and_the_utm30lx_geometry() -> None:
    model = FakeHokuyoModel(golden())
    (resp,) = ResponseDecoder().feed(model.receive(b"PP\n", 0.0))
    p = parse_params(resp)
    assert p == UTM
    assert p.scan_period_s == pytest.approx(0.025)
    g = BeamGeometry.of(p, ScanRequest(Code.MD, 0, 1080))
    assert g.beams == 1081
    assert g.angle_min_rad == pytest.approx(-math.radians(135.0))
    assert g.angle_increment_rad == pytest.approx(math.radians(0.25))
    assert g.angles_rad()[540] == pytest.approx(0.0)  # AFRT is straight ahead
    flipped = BeamGeometry.of(p, ScanRequest(Code.MD, 0, 1080), upside_down=True)
    assert flipped.angle_min_rad == pytest.approx(math.radians(135.0))
    assert flipped.angle_increment_rad == pytest.approx(-math.radians(0.25))
    grouped = BeamGeometry.of(p, ScanRequest(Code.MD, 0, 1079, cluster=4))
    assert grouped.beams == 270
    assert grouped.angle_min_rad == pytest.approx(math.radians(-135.0 + 1.5 * 0.25))


def test_scans_decode_to_the_golden_ranges_with_error_codes_as_inf() -> None:
    scans = golden()
    model = FakeHokuyoModel(scans, clock_start_ms=1234)
    resps = ResponseDecoder().feed(stream_bytes(model, "ME", scans=2))
    raw = parse_scan(resps[1])
    assert raw.ranges_mm.tolist() == scans[0].tolist()
    assert raw.intensities is not None and raw.intensities.shape == (1081,)
    assert raw.sensor_ms == 1234 + 25
    r = ranges_m(raw.ranges_mm, 0.0, 30.0)
    assert r.dtype == np.float32
    assert np.isinf(r[:3]).all() and r[3] == np.float32(0.02)
    expect = scans[0] / 1000.0
    ok = (scans[0] >= 20) & (expect <= 30.0)
    assert np.array_equal(r[ok], expect[ok].astype(np.float32))
    assert np.isinf(r[~ok]).all()


def test_a_scan_shorter_than_its_echo_says_is_rejected() -> None:
    model = FakeHokuyoModel(golden())
    data = stream_bytes(model, scans=1)
    resp = ResponseDecoder().feed(data)[1]
    from dataclasses import replace

    with pytest.raises(ScanError, match="data bytes"):
        parse_scan(replace(resp, lines=resp.lines[:-1]))
    assert "hardware" in describe_status("MD", "55")


# --------------------------------------------------------------------------- clock
def test_sensor_clock_unwraps_and_maps_to_the_host() -> None:
    c = SensorClock(window_s=1.0)
    assert c.unwrap_s(WRAP_MS - 10) == pytest.approx((WRAP_MS - 10) * 1e-3)
    assert c.unwrap_s(5) == pytest.approx((WRAP_MS + 5) * 1e-3)
    assert c.wraps == 1
    c.reset()
    # TM: true offset 100 s, 2 ms each way; the shortest round trip wins
    c.add_round_trip(100.010, 100.018, 12)  # rtt 8 ms
    c.add_round_trip(100.100, 100.104, 102)  # rtt 4 ms, midpoint exactly 100 + 0.102
    assert c.offset_s() == pytest.approx(100.0)
    assert c.stamp(0.2, not_after_s=200.0) == pytest.approx(100.2)
    assert c.stamp(0.2, not_after_s=100.1) == 100.1  # never after the receipt
    # min-filter: receipts 3..9 ms late -> offset + 3 ms
    m = SensorClock(window_s=1.0, prefer_round_trip=False)
    for k, late in enumerate([0.009, 0.003, 0.007, 0.005]):
        m.add_receipt(50.0 + 0.025 * k + late, 0.025 * k)
    assert m.offset_s() == pytest.approx(50.003)
    m.unwrap_s(100_000)
    m.unwrap_s(10)  # back by 100 s: a restart, not a wrap
    assert m.restarts == 1 and m.offset_s() is None


def test_single_scans_gd_and_two_character_ms() -> None:
    scans = golden()
    model = FakeHokuyoModel(scans)
    d = ResponseDecoder()
    (off,) = d.feed(model.receive(b"GD0000108001\n", 0.0))
    assert off.status == "10" and "laser is off" in describe_status("GD", off.status)
    d.feed(model.receive(b"BM\n", 0.0))
    (gd,) = d.feed(model.receive(b"GD0000108001;x1\n", 0.5))
    raw = parse_scan(gd)
    assert raw.ranges_mm.tolist() == scans[0].tolist() and raw.request.scans == 0
    ms = ScanRequest(Code.MS, 0, 1080, 2)
    resps = d.feed(model.receive(scan_stream(ms), 1.0) + model.due(1.03))
    raw = parse_scan(resps[-1])
    pairs = [*scans[1][:1080].reshape(-1, 2).min(axis=1).tolist(), int(scans[1][1080])]
    assert raw.ranges_mm.tolist() == [v if v <= 4095 else 0 for v in pairs]
    assert d.counters.errors == 0
