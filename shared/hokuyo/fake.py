"""A fake Hokuyo (SCIP 2.0), the pure model: request bytes in, response bytes out.

Written from the protocol document, not from the driver: it has its own encoder (``_enc``,
``_sum``, ``_blocks``) and shares no code with ``shared.hokuyo``'s decoder. The I/O shell
(a pty or a loopback TCP port) is ``shared.hokuyo.fake_io``.

It answers ``SCIP2.0`` (status 0E: already SCIP 2.0), ``VV``, ``PP``, ``II``, ``BM``,
``QT``, ``RS``, ``TM0/1/2``, ``MD``/``ME``/``MS`` (then streams a scan every
``scan_period_s``: echo with the scans still to come, status 99, time stamp, 64-byte
blocks) and ``GD``/``GE``/``GS``; anything else gets status 0E. The golden scans
(``ranges_mm`` per step AMIN..AMAX, optional intensities) are sent in turn.

Faults to inject: ``garbage`` (bytes before the next scan), ``corrupt`` (the next scans get
a wrong checksum), ``truncate`` (the next scans are cut in half, the following scan comes
right after), ``silent`` (no answer and no scan at all while set).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

#: The UTM-30LX's PP answer (the paper's car).
UTM30LX = {
    "MODL": "UTM-30LX",
    "DMIN": 23,
    "DMAX": 60000,
    "ARES": 1440,
    "AMIN": 0,
    "AMAX": 1080,
    "AFRT": 540,
    "SCAN": 2400,
}
_WRAP = 1 << 24


def _sum(data: bytes) -> bytes:
    """The checksum character: low 6 bits of the byte sum, + 0x30."""
    return bytes([(sum(data) & 0x3F) + 0x30])


def _enc(value: int, width: int) -> bytes:
    """``value`` in ``width`` characters of 6 bits (+ 0x30), most significant first."""
    out = bytearray()
    for k in reversed(range(width)):
        out.append(((int(value) >> (6 * k)) & 0x3F) + 0x30)
    return bytes(out)


def _line(data: bytes) -> bytes:
    return data + _sum(data) + b"\n"


def _info_line(name: str, value: object) -> bytes:
    body = f"{name}:{value}".encode("latin-1")
    return body + b";" + _sum(body) + b"\n"


def _blocks(data: bytes) -> bytes:
    """Data cut into lines of 64 bytes, each with its checksum and LF."""
    return b"".join(_line(data[i : i + 64]) for i in range(0, len(data), 64))


@dataclass(slots=True)
class _Stream:
    code: str
    start: int
    end: int
    cluster: int
    skip: int
    left: int  # scans still to send; -1: until QT
    next_s: float
    echo_tail: bytes  # the ";tag" of the request, echoed back


class FakeHokuyoModel:
    """The sensor's behaviour (module docstring); all methods take the time ``now_s`` [s].

    Args:
        scans: golden scans, each (AMAX - AMIN + 1,) ranges [mm] of steps AMIN..AMAX.
        intensities: matching intensities (None: a fixed pattern).
        params: the PP values (default ``UTM30LX``).
        scan_period_s: time between two streamed scans [s] (None: 60 / SCAN).
        clock_start_ms: the sensor's counter at ``now_s = 0`` (to exercise the 24-bit wrap).
    """

    def __init__(
        self,
        scans: Sequence[np.ndarray],
        *,
        intensities: Sequence[np.ndarray] | None = None,
        params: dict[str, object] | None = None,
        scan_period_s: float | None = None,
        clock_start_ms: int = 0,
    ) -> None:
        self.params = dict(UTM30LX if params is None else params)
        n = int(self.params["AMAX"]) - int(self.params["AMIN"]) + 1  # type: ignore[arg-type]
        if not scans or any(len(s) != n for s in scans):
            raise ValueError(f"every golden scan needs {n} ranges")
        self.scans = [np.asarray(s, dtype=np.int64) for s in scans]
        self.intensities = (
            [np.asarray(i, dtype=np.int64) for i in intensities]
            if intensities is not None
            else [np.arange(n, dtype=np.int64) % 4000 + 100 for _ in scans]
        )
        self.scan_period_s = (
            60.0 / float(self.params["SCAN"])  # type: ignore[arg-type]
            if scan_period_s is None
            else scan_period_s
        )
        self.clock_start_ms = clock_start_ms
        self.laser_on = False
        self.adjust_mode = False
        self.silent = False
        self.garbage = b""
        self.corrupt = 0
        self.truncate = 0
        self.scans_sent = 0  #: scans streamed or sent once so far
        self.last_scan_index = -1  #: index into ``scans`` of the newest scan sent
        self.requests: list[bytes] = []  #: request lines received
        self._rx = bytearray()
        self._stream: _Stream | None = None

    # -- time ---------------------------------------------------------------------------------
    def sensor_ms(self, now_s: float) -> int:
        """The sensor's 24-bit counter [ms] at ``now_s``."""
        return (self.clock_start_ms + math.floor(now_s * 1000.0)) % _WRAP

    @property
    def streaming(self) -> bool:
        """True while an MD/ME/MS stream runs."""
        return self._stream is not None

    def next_due_s(self) -> float | None:
        """When the next scan of the stream is due [s] (None: no stream)."""
        return None if self._stream is None or self.silent else self._stream.next_s

    def reset_link(self) -> None:
        """A new connection: drop half-received requests (the stream goes on, as on USB)."""
        self._rx.clear()

    # -- requests ----------------------------------------------------------------------------
    def receive(self, data: bytes, now_s: float) -> bytes:
        """Feed received bytes; the answers to the complete request lines among them."""
        self._rx += data
        out = bytearray()
        while True:
            cut = [i for i in (self._rx.find(b"\n"), self._rx.find(b"\r")) if i >= 0]
            if not cut:
                break
            i = min(cut)
            line = bytes(self._rx[:i])
            del self._rx[: i + 1]
            if not line:
                continue
            self.requests.append(line)
            if not self.silent:
                out += self._answer(line, now_s)
        if len(self._rx) > 4096:
            self._rx.clear()
        return bytes(out)

    def _answer(self, line: bytes, now_s: float) -> bytes:
        text = line.decode("latin-1")
        head, _, tag = text.partition(";")
        tail = f";{tag}".encode("latin-1") if _ else b""
        echo = line + b"\n"
        p = self.params

        def status(s: str) -> bytes:
            return echo + _line(s.encode("ascii")) + b"\n"

        if head == "SCIP2.0":
            return status("0E")
        if head == "VV":
            return echo + _line(b"00") + b"".join(
                _info_line(k, v)
                for k, v in (
                    ("VEND", "Hokuyo Automatic Co.,Ltd."),
                    ("PROD", f"SOKUIKI Sensor {p['MODL']}"),
                    ("FIRM", "1.0.0(fake)"),
                    ("PROT", "SCIP 2.0"),
                    ("SERI", "H0000001"),
                )
            ) + b"\n"
        if head == "PP":
            body = b"".join(_info_line(k, p[k]) for k in UTM30LX)
            return echo + _line(b"00") + body + b"\n"
        if head == "II":
            state = "ON" if self.laser_on else "OFF"
            body = b"".join(
                _info_line(k, v)
                for k, v in (
                    ("MODL", p["MODL"]),
                    ("LASR", state),
                    ("SCSP", f"Initial({p['SCAN']}[rpm])"),
                    ("MESM", "Measuring" if self._stream else "Idle"),
                    ("SBPS", "USB only"),
                    ("TIME", _enc(self.sensor_ms(now_s), 4).decode()),
                    ("STAT", "Sensor works well."),
                )
            )
            return echo + _line(b"00") + body + b"\n"
        if head == "BM":
            was, self.laser_on = self.laser_on, True
            return status("02" if was else "00")
        if head in ("QT", "RS"):
            self._stream = None
            self.laser_on = False
            self.adjust_mode = head == "QT" and self.adjust_mode
            return status("00")
        if head in ("TM0", "TM1", "TM2"):
            if head == "TM0":
                was, self.adjust_mode = self.adjust_mode, True
                self._stream, self.laser_on = None, False
                return status("02" if was else "00")
            if head == "TM2":
                was, self.adjust_mode = self.adjust_mode, False
                return status("00" if was else "03")
            if not self.adjust_mode:
                return status("04")
            return echo + _line(b"00") + _line(_enc(self.sensor_ms(now_s), 4)) + b"\n"
        if head[:2] in ("MD", "ME", "MS", "GD", "GE", "GS"):
            return self._scan_request(head, tail, now_s)
        return status("0E")

    def _scan_request(self, head: str, tail: bytes, now_s: float) -> bytes:
        code, digits = head[:2], head[2:]
        stream = code[0] == "M"
        echo = head.encode("latin-1") + tail + b"\n"

        def status(s: str) -> bytes:
            return echo + _line(s.encode("ascii")) + b"\n"

        need = 13 if stream else 10
        for k, (a, b) in enumerate(((0, 4), (4, 8), (8, 10), (10, 11), (11, 13))):
            if a >= need:
                break
            if len(digits) < b or not digits[a:b].isdigit():
                return status(f"0{k + 1}" if k < 3 else f"0{k + 3}")
        if len(digits) != need:
            return status("0F" if len(digits) > need else "0C")
        start, end, cluster = int(digits[0:4]), int(digits[4:8]), int(digits[8:10])
        amin, amax = int(self.params["AMIN"]), int(self.params["AMAX"])  # type: ignore[arg-type]
        if end > amax or start < amin:
            return status("04")
        if end < start:
            return status("05")
        if self.adjust_mode:
            return status("0B")
        if stream:
            skip, count = int(digits[10:11]), int(digits[11:13])
            self.laser_on = True
            self._stream = _Stream(
                code, start, end, max(1, cluster), skip, count if count else -1,
                now_s + self.scan_period_s, tail,
            )
            return status("00")
        if not self.laser_on:
            return status("10")
        return self._scan_bytes(echo, "00", code, start, end, max(1, cluster), now_s)

    # -- scans ---------------------------------------------------------------------------------
    def due(self, now_s: float) -> bytes:
        """The scan (and injected garbage) due by ``now_s``; b"" when none is due."""
        st = self._stream
        if st is None or self.silent or now_s < st.next_s:
            return b""
        st.next_s += self.scan_period_s * (1 + st.skip)
        if st.next_s < now_s:  # far behind (the fake was paused): do not burst
            st.next_s = now_s + self.scan_period_s
        if st.left > 0:
            st.left -= 1
        remaining = max(st.left, 0)
        head = f"{st.code}{st.start:04d}{st.end:04d}{st.cluster:02d}{st.skip:01d}{remaining:02d}"
        echo = head.encode("ascii") + st.echo_tail + b"\n"
        data = self._scan_bytes(echo, "99", st.code, st.start, st.end, st.cluster, now_s)
        if st.left == 0:
            self._stream = None
        out = self.garbage + data
        self.garbage = b""
        return out

    def _scan_bytes(
        self, echo: bytes, status: str, code: str, start: int, end: int, cluster: int, now_s: float
    ) -> bytes:
        k = self.scans_sent % len(self.scans)
        self.scans_sent += 1
        self.last_scan_index = k
        amin = int(self.params["AMIN"])  # type: ignore[arg-type]
        rng = self.scans[k][start - amin : end - amin + 1]
        inten = self.intensities[k][start - amin : end - amin + 1]
        groups = range(0, len(rng), cluster)
        width = 2 if code[1] == "S" else 3
        data = bytearray()
        for g in groups:
            r = int(rng[g : g + cluster].min())
            if width == 2:
                r = r if r <= 4095 else 0
            data += _enc(r, width)
            if code[1] == "E":
                data += _enc(int(inten[g : g + cluster].max()), 3)
        body = _line(_enc(self.sensor_ms(now_s), 4)) + _blocks(bytes(data))
        out = bytearray(echo + _line(status.encode("ascii")) + body + b"\n")
        if self.corrupt > 0:
            self.corrupt -= 1
            at = len(echo) + 4 + 6 + 64  # the checksum of the first data block
            out[at] = 0x30 + ((out[at] - 0x30 + 1) & 0x3F)
        if self.truncate > 0:
            self.truncate -= 1
            del out[len(out) // 2 :]
        return bytes(out)
