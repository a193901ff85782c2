"""Streaming decoder of SCIP 2.0 responses: bytes in any chunking -> whole, checked responses.

A response ends with an empty line (``LF LF``). The decoder cuts the stream at each
``LF LF`` and, in the piece before it, looks for the LAST line that ends with a valid echo
(a known command code with its parameters, see ``ECHO``) followed by a valid status line
(2 characters + their checksum). Bytes before that echo are noise or the rest of a response
that was cut short (a truncated scan followed by the next one): they are counted and
dropped. Every line after the status must carry the right checksum (``encoding.sum_char``;
for ``VV``/``PP``/``II`` lines ``NAME:value;S`` the ``;`` is not summed), else the whole
response is dropped and counted. A piece longer than ``max_response`` bytes without an end
is dropped as well, so the buffer stays bounded. It never raises on input.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, fields

from shared.hokuyo.encoding import sum_char
from shared.hokuyo.protocol import INFO_CODES, Code

__all__ = ["DEFAULT_MAX_RESPONSE", "ECHO", "DecoderCounters", "Response", "ResponseDecoder"]

#: Largest response [bytes] the decoder waits for: ME over 1440 steps is 1440 * 6 data bytes
#: plus 2 bytes per 64-byte block (~8.9 kB); 32 KiB leaves room for any SCIP 2.0 sensor.
DEFAULT_MAX_RESPONSE = 32 * 1024

#: A valid echo at the end of a line: the code, its exact digits, an optional ``;tag``.
ECHO = re.compile(
    rb"(?P<code>M[DES]|G[DES]|PP|VV|II|BM|QT|RS|TM|SCIP2\.0)"
    rb"(?P<digits>(?<=M[DES])\d{13}|(?<=G[DES])\d{10}|(?<=TM)[0-2]|)"
    rb"(?:;[\x21-\x7e]{0,16})?$"
)
_END = b"\n\n"


@dataclass(frozen=True, slots=True)
class Response:
    """One checked response.

    Attributes:
        code: the command code of the echo.
        echo: the echo line (without LF), e.g. ``b"MD0000108001000"``.
        digits: the echo's parameters after the code (``b""`` for none; TM: ``b"0"``..).
        status: the status (``"00"``, ``"99"``, an error code; ``SCIP2.0`` may give ``"0"``).
        lines: the data lines after the status, checksums removed (info lines:
            ``NAME:value``).
    """

    code: Code
    echo: bytes
    digits: bytes
    status: str
    lines: tuple[bytes, ...]


@dataclass(slots=True)
class DecoderCounters:
    """What the decoder saw.

    Attributes:
        responses: valid responses decoded.
        bytes_in: bytes fed in total.
        garbage_bytes: bytes dropped: noise, cut-short responses, rejected responses.
        no_echo: noise pieces: pieces (up to an empty line) without a valid echo and status,
            and runs of junk (lines, bytes) in front of a response's echo.
        truncated: responses cut short by the next one (a valid echo and status earlier
            in the same piece).
        checksum_errors: responses dropped because a line's checksum was wrong.
        overlong: pieces longer than the limit without an end, dropped.
    """

    responses: int = 0
    bytes_in: int = 0
    garbage_bytes: int = 0
    no_echo: int = 0
    truncated: int = 0
    checksum_errors: int = 0
    overlong: int = 0

    @property
    def errors(self) -> int:
        """All error events (no_echo + truncated + checksum_errors + overlong)."""
        return self.no_echo + self.truncated + self.checksum_errors + self.overlong

    def as_dict(self) -> dict[str, int]:
        """The counters as a plain dict."""
        return {f.name: getattr(self, f.name) for f in fields(self)}


def _status_ok(line: bytes, code: Code) -> str | None:
    """The status of a status line, or None when it is not one."""
    if len(line) == 3 and sum_char(line[:2]) == line[2]:
        return line[:2].decode("latin-1")
    if code is Code.SCIP2 and len(line) in (1, 2) and line[:1].isalnum():
        return line.decode("latin-1")  # the switch may answer "0" (no checksum)
    return None


def _check_line(line: bytes, info: bool) -> bytes | None:
    """The line without its checksum, or None when the checksum is wrong."""
    if info:
        if len(line) < 2 or line[-2] != 0x3B or sum_char(line[:-2]) != line[-1]:
            return None
        return line[:-2]
    if not line or sum_char(line[:-1]) != line[-1]:
        return None
    return line[:-1]


class ResponseDecoder:
    """Incremental SCIP 2.0 response decoder; ``feed`` accepts any chunking."""

    def __init__(self, max_response: int = DEFAULT_MAX_RESPONSE) -> None:
        """Create a decoder holding at most ``max_response`` bytes of an open response."""
        if max_response < 16:
            raise ValueError("max_response must be >= 16 bytes")
        self.max_response = max_response
        self.counters = DecoderCounters()
        self._buf = bytearray()

    @property
    def buffered(self) -> int:
        """Bytes held waiting for the end of a response."""
        return len(self._buf)

    def reset(self) -> None:
        """Drop buffered bytes (after a reconnect); the counters stay."""
        self._buf.clear()

    def feed(self, data: bytes | bytearray | memoryview) -> list[Response]:
        """Add received bytes; return the responses they completed, in stream order."""
        if not data:
            return []
        c = self.counters
        c.bytes_in += len(data)
        buf = self._buf
        # an end may straddle the chunks: search from one byte before the new data
        search_from = max(0, len(buf) - 1)
        buf += data
        out: list[Response] = []
        pos = 0
        while True:
            end = buf.find(_END, max(pos, search_from))
            if end < 0:
                break
            piece = bytes(buf[pos : end + 1])  # the lines, each with its LF
            pos = end + 2
            resp = self._piece(piece)
            if resp is not None:
                out.append(resp)
        del buf[:pos]
        if len(buf) > self.max_response:
            c.overlong += 1
            cut = buf.rfind(b"\n")
            keep = len(buf) - cut - 1 if cut >= 0 else 0
            if keep > self.max_response // 2:
                keep = 0
            c.garbage_bytes += len(buf) - keep
            del buf[: len(buf) - keep]
        return out

    def _piece(self, piece: bytes) -> Response | None:
        c = self.counters
        lines = piece.split(b"\n")[:-1]
        found: tuple[int, int, re.Match[bytes], str] | None = None
        offset = 0
        offsets = []
        for line in lines:
            offsets.append(offset)
            offset += len(line) + 1
        earlier = 0
        for i in range(len(lines) - 1):
            m = ECHO.search(lines[i])
            if m is None:
                continue
            status = _status_ok(lines[i + 1], Code(m["code"].decode("ascii")))
            if status is None:
                continue
            if found is not None:
                earlier += 1
            found = (i, offsets[i] + m.start(), m, status)
        if found is None:
            c.no_echo += 1
            c.garbage_bytes += len(piece) + 1
            return None
        i, start, m, status = found
        c.truncated += earlier
        c.garbage_bytes += start
        if start and not earlier:  # junk lines or bytes before the echo: one noise piece
            c.no_echo += 1
        code = Code(m["code"].decode("ascii"))
        info = code in INFO_CODES
        body: list[bytes] = []
        for line in lines[i + 2 :]:
            content = _check_line(line, info)
            if content is None:
                c.checksum_errors += 1
                c.garbage_bytes += len(piece) + 1 - start
                return None
            body.append(content)
        c.responses += 1
        return Response(code, m[0].split(b";")[0], m["digits"], status, tuple(body))
