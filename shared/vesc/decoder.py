"""Streaming decoder of VESC frames: bytes in any chunking -> whole, checked frames.

The decoder hunts for a start byte, reads the length, waits until the whole frame is
buffered, then checks the end byte and the CRC. On any error it drops only the start byte of
the rejected candidate and hunts again from the next byte, so a real frame that begins inside
a rejected candidate (or inside noise) is still found. It never raises on input.
"""

from __future__ import annotations

from dataclasses import dataclass, fields

from shared.vesc.crc import crc16_xmodem
from shared.vesc.protocol import (
    END_BYTE,
    LONG_HEADER_LEN,
    MAX_LONG_PAYLOAD,
    MAX_SHORT_PAYLOAD,
    SHORT_HEADER_LEN,
    START_LONG,
    START_SHORT,
    TRAILER_LEN,
    CommandId,
)

#: Default largest payload [bytes] the decoder accepts (the VESC firmware's own packet
#: buffer is 512 bytes; a COMM_GET_VALUES reply is 74 bytes). Longer declared lengths count
#: as ``bad_length`` and the decoder resynchronises instead of waiting for them.
DEFAULT_MAX_PAYLOAD = 512

_START_BYTES = (START_SHORT, START_LONG)


@dataclass(frozen=True, slots=True)
class Frame:
    """One decoded frame.

    Attributes:
        payload: the payload bytes (command id first), without header, CRC and end byte.
    """

    payload: bytes

    @property
    def command_id(self) -> int:
        """The first payload byte (compare with ``CommandId``)."""
        return self.payload[0]

    @property
    def command(self) -> CommandId | None:
        """The command id as a ``CommandId``, or None when racestack does not know it."""
        try:
            return CommandId(self.payload[0])
        except ValueError:
            return None


@dataclass(slots=True)
class DecoderCounters:
    """What the decoder saw, each error kind counted separately.

    Attributes:
        frames: valid frames decoded.
        bytes_in: bytes fed in total.
        garbage_bytes: bytes discarded while hunting for a start byte (noise, and the
            remainder of rejected candidates).
        bad_start: times a non-start byte stood where a frame should begin after a good
            frame or at the beginning of the stream (one count per run of such bytes; bytes
            skipped after another error are attributed to that error).
        bad_length: impossible lengths (zero, a long-form length that fits the short
            form, or more than the decoder's payload limit).
        bad_end: candidates whose byte after the CRC is not the end byte.
        crc_errors: candidates with the right end byte but a wrong CRC.
    """

    frames: int = 0
    bytes_in: int = 0
    garbage_bytes: int = 0
    bad_start: int = 0
    bad_length: int = 0
    bad_end: int = 0
    crc_errors: int = 0

    @property
    def errors(self) -> int:
        """All error events (bad_start + bad_length + bad_end + crc_errors)."""
        return self.bad_start + self.bad_length + self.bad_end + self.crc_errors

    def as_dict(self) -> dict[str, int]:
        """The counters as a plain dict (for logs and telemetry)."""
        return {f.name: getattr(self, f.name) for f in fields(self)}


class FrameDecoder:
    """Incremental VESC frame decoder; ``feed`` accepts any chunking of the byte stream.

    The internal buffer never holds more than one maximal frame
    (``max_payload + 6`` bytes): anything before the current candidate is consumed.
    """

    def __init__(self, max_payload: int = DEFAULT_MAX_PAYLOAD) -> None:
        """Create a decoder accepting payloads of 1..``max_payload`` bytes (<= 65535)."""
        if not 1 <= max_payload <= MAX_LONG_PAYLOAD:
            raise ValueError(f"max_payload must be in [1, {MAX_LONG_PAYLOAD}], got {max_payload}")
        self.max_payload = max_payload
        self.counters = DecoderCounters()
        self._buf = bytearray()
        # True after an error until the next good frame: skipped bytes belong to that error.
        self._resyncing = False

    @property
    def max_frame_len(self) -> int:
        """Largest frame [bytes] the decoder accepts (and bound of its buffer)."""
        header = SHORT_HEADER_LEN if self.max_payload <= MAX_SHORT_PAYLOAD else LONG_HEADER_LEN
        return header + self.max_payload + TRAILER_LEN

    @property
    def buffered(self) -> int:
        """Bytes held waiting for the rest of a frame."""
        return len(self._buf)

    def reset(self) -> None:
        """Drop buffered bytes (e.g. after the serial port was reopened); counters stay."""
        self._buf.clear()
        self._resyncing = False

    def feed(self, data: bytes | bytearray | memoryview) -> list[Frame]:
        """Add received bytes; return the frames completed by them, in stream order."""
        if not data:
            return []
        self.counters.bytes_in += len(data)
        buf = self._buf
        buf += data
        frames: list[Frame] = []
        pos = 0
        n = len(buf)
        c = self.counters
        while pos < n:
            start = buf[pos]
            if start not in _START_BYTES:
                nxt = _find_start(buf, pos)
                end = n if nxt < 0 else nxt
                c.garbage_bytes += end - pos
                if not self._resyncing:
                    c.bad_start += 1
                    self._resyncing = True
                pos = end
                continue
            if start == START_SHORT:
                if n - pos < SHORT_HEADER_LEN:
                    break
                length = buf[pos + 1]
                header = SHORT_HEADER_LEN
                impossible = length == 0
            else:
                if n - pos < LONG_HEADER_LEN:
                    break
                length = (buf[pos + 1] << 8) | buf[pos + 2]
                header = LONG_HEADER_LEN
                impossible = length <= MAX_SHORT_PAYLOAD
            if impossible or length > self.max_payload:
                c.bad_length += 1
                pos = self._reject(pos)
                continue
            total = header + length + TRAILER_LEN
            if n - pos < total:
                break
            body_end = pos + header + length
            if buf[body_end + 2] != END_BYTE:
                c.bad_end += 1
                pos = self._reject(pos)
                continue
            payload = bytes(buf[pos + header : body_end])
            if crc16_xmodem(payload) != (buf[body_end] << 8) | buf[body_end + 1]:
                c.crc_errors += 1
                pos = self._reject(pos)
                continue
            frames.append(Frame(payload))
            c.frames += 1
            self._resyncing = False
            pos += total
        del buf[:pos]
        return frames

    def _reject(self, pos: int) -> int:
        """Drop the start byte of a rejected candidate; hunting resumes at the next byte."""
        self.counters.garbage_bytes += 1
        self._resyncing = True
        return pos + 1


def _find_start(buf: bytearray, pos: int) -> int:
    """Index of the first start byte at or after ``pos``, or -1."""
    a = buf.find(START_SHORT, pos)
    b = buf.find(START_LONG, pos)
    if a < 0:
        return b
    if b < 0:
        return a
    return min(a, b)
