"""Streaming frame decoder: golden frames, each error kind, resynchronisation, properties."""

from __future__ import annotations

import itertools

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from shared.vesc.decoder import DEFAULT_MAX_PAYLOAD, Frame, FrameDecoder
from shared.vesc.protocol import (
    START_LONG,
    START_SHORT,
    CommandId,
    encode_alive,
    encode_frame,
    encode_get_values,
    encode_set_rpm,
)

PROPS = settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])

GET_VALUES = bytes.fromhex("02 01 04 40 84 03")
ALIVE = bytes.fromhex("02 01 1e f3 ff 03")


def feed_all(dec: FrameDecoder, chunks: list[bytes]) -> list[bytes]:
    return [f.payload for chunk in chunks for f in dec.feed(chunk)]


def test_golden_frames_decode() -> None:
    dec = FrameDecoder()
    frames = dec.feed(GET_VALUES + ALIVE)
    assert frames == [Frame(b"\x04"), Frame(b"\x1e")]
    assert frames[0].command is CommandId.GET_VALUES and frames[1].command_id == CommandId.ALIVE
    assert Frame(b"\xee").command is None
    assert dec.counters.frames == 2 and dec.counters.errors == 0 and dec.buffered == 0


def test_byte_by_byte() -> None:
    dec = FrameDecoder()
    stream = encode_set_rpm(9228) + GET_VALUES
    out = feed_all(dec, [bytes((b,)) for b in stream])
    assert out == [bytes.fromhex("08 00 00 24 0c"), b"\x04"]


def test_long_form_decodes() -> None:
    payload = bytes(range(256)) * 2  # 512 bytes
    dec = FrameDecoder()
    assert feed_all(dec, [encode_frame(payload)]) == [payload]


def test_garbage_then_frame() -> None:
    dec = FrameDecoder()
    assert feed_all(dec, [b"\xde\xad\xbe\xef" + ALIVE]) == [b"\x1e"]
    c = dec.counters
    assert (c.garbage_bytes, c.bad_start, c.crc_errors, c.bad_end, c.bad_length) == (4, 1, 0, 0, 0)
    # a second garbage run after a good frame counts again
    assert feed_all(dec, [b"\x55\x66" + ALIVE]) == [b"\x1e"]
    assert dec.counters.bad_start == 2 and dec.counters.garbage_bytes == 6


def test_crc_error_then_resync() -> None:
    bad = bytearray(ALIVE)
    bad[3] ^= 0x01  # corrupt the CRC
    dec = FrameDecoder()
    assert feed_all(dec, [bytes(bad) + GET_VALUES]) == [b"\x04"]
    assert dec.counters.crc_errors == 1
    assert dec.counters.bad_start == 0  # the skipped bytes belong to the CRC error


def test_bad_end_byte_then_resync() -> None:
    bad = bytearray(ALIVE)
    bad[-1] = 0x7E
    dec = FrameDecoder()
    assert feed_all(dec, [bytes(bad) + GET_VALUES]) == [b"\x04"]
    assert dec.counters.bad_end == 1 and dec.counters.crc_errors == 0


@pytest.mark.parametrize(
    "header",
    [
        bytes((START_SHORT, 0)),  # empty payload
        bytes((START_LONG, 0x00, 0x10)),  # long form with a short length
        bytes((START_LONG, 0xFF, 0xFF)),  # longer than the decoder's limit
    ],
)
def test_impossible_length(header: bytes) -> None:
    dec = FrameDecoder()
    assert feed_all(dec, [header + GET_VALUES]) == [b"\x04"]
    assert dec.counters.bad_length == 1


def test_frame_inside_rejected_candidate_is_found() -> None:
    # a start byte with a plausible length swallows the real frame, which is still found
    # once the candidate fails
    dec = FrameDecoder()
    stream = bytes((START_SHORT, 20)) + ALIVE + b"\x00" * 20
    assert feed_all(dec, [stream]) == [b"\x1e"]


def test_buffer_is_bounded() -> None:
    dec = FrameDecoder(max_payload=DEFAULT_MAX_PAYLOAD)
    dec.feed(bytes((START_LONG,)) + (DEFAULT_MAX_PAYLOAD).to_bytes(2, "big"))
    for _ in range(100):
        dec.feed(b"\x00" * 100)
        assert dec.buffered <= dec.max_frame_len
    dec.reset()
    assert dec.buffered == 0


def test_constructor_bounds() -> None:
    with pytest.raises(ValueError):
        FrameDecoder(max_payload=0)
    with pytest.raises(ValueError):
        FrameDecoder(max_payload=70000)
    assert FrameDecoder(max_payload=100).max_frame_len == 105


# -- properties --------------------------------------------------------------------------------
def chunked(data: bytes, cuts: list[int]) -> list[bytes]:
    points = sorted({c % (len(data) + 1) for c in cuts})
    bounds = [0, *points, len(data)]
    return [data[a:b] for a, b in itertools.pairwise(bounds)]


payloads = st.one_of(
    st.binary(min_size=1, max_size=40),
    st.binary(min_size=250, max_size=DEFAULT_MAX_PAYLOAD),  # both length forms
)
no_start_noise = st.binary(max_size=40).map(
    lambda b: bytes(x for x in b if x not in (START_SHORT, START_LONG))
)
cuts = st.lists(st.integers(min_value=0, max_value=10_000), max_size=30)


@PROPS
@given(data=st.binary(max_size=2000), cut=cuts, max_payload=st.sampled_from([64, 255, 512]))
def test_any_stream_never_raises(data: bytes, cut: list[int], max_payload: int) -> None:
    dec = FrameDecoder(max_payload=max_payload)
    for chunk in chunked(data, cut):
        for frame in dec.feed(chunk):
            assert 1 <= len(frame.payload) <= max_payload
        assert dec.buffered <= dec.max_frame_len
    c = dec.counters
    assert c.bytes_in == len(data)
    assert c.garbage_bytes <= len(data)


@PROPS
@given(
    parts=st.lists(st.tuples(no_start_noise, payloads), min_size=1, max_size=6),
    tail=no_start_noise,
    cut=cuts,
)
def test_frames_in_start_free_noise_all_recovered(
    parts: list[tuple[bytes, bytes]], tail: bytes, cut: list[int]
) -> None:
    stream = b"".join(noise + encode_frame(p) for noise, p in parts) + tail
    dec = FrameDecoder()
    assert feed_all(dec, chunked(stream, cut)) == [p for _, p in parts]
    c = dec.counters
    assert c.crc_errors == c.bad_end == c.bad_length == 0
    assert c.garbage_bytes == sum(len(n) for n, _ in parts) + len(tail)


@PROPS
@given(noise=st.binary(max_size=600), payload=payloads, cut=cuts)
def test_frame_after_arbitrary_noise_recovered(
    noise: bytes, payload: bytes, cut: list[int]
) -> None:
    """After any noise, a gap of one maximal frame of start-free bytes resynchronises."""
    dec = FrameDecoder()
    gap = b"\x00" * dec.max_frame_len
    stream = noise + gap + encode_frame(payload)
    out = feed_all(dec, chunked(stream, cut))
    assert out and out[-1] == payload
    assert dec.buffered == 0


@PROPS
@given(
    payload=st.binary(min_size=1, max_size=64), pos=st.integers(0, 200), flip=st.integers(1, 255)
)
def test_corrupted_frame_is_counted_and_next_frame_recovered(
    payload: bytes, pos: int, flip: int
) -> None:
    frame = bytearray(encode_frame(payload))
    pos %= len(frame)
    frame[pos] ^= flip
    dec = FrameDecoder()
    gap = b"\x00" * dec.max_frame_len
    out = feed_all(dec, [bytes(frame) + gap + encode_alive() + encode_get_values()])
    assert out[-2:] == [b"\x1e", b"\x04"]
    assert dec.counters.errors >= 1 or out[:-2] == [payload]
