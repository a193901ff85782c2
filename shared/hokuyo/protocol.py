"""SCIP 2.0 commands and status codes (pure, no I/O), as the Hokuyo protocol document says.

A request is ASCII ending in a line feed (LF, 0x0A): a command code, its parameters and an
optional ``;string`` tag (at most 16 characters) that the sensor echoes back. Every response
is::

    echo LF                       the request line as received (MD/ME: remaining scans)
    status sum LF                 2 characters + their checksum ("00P", "99b")
    [line sum LF]...              data lines (time stamp, 64-character blocks, info lines)
    LF                            an empty line ends the response

Status "00" means the command was accepted; "99" marks each scan of a running MD/ME/MS
stream; other values are the command's own error codes (``describe_status``). The one
exception is the switch ``SCIP2.0``, whose status may come without a checksum.

Encoders of the commands racestack sends: ``scip2``, ``version`` (VV), ``parameters``
(PP), ``info`` (II), ``laser_on`` (BM), ``laser_off`` (QT), ``reset`` (RS), ``time_mode``
(TM0/TM1/TM2), ``scan_stream`` (MD / ME / MS: continuous) and ``scan_once`` (GD / GE / GS).
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import IntEnum, StrEnum

__all__ = [
    "BLOCK_LEN",
    "DATA_CODES",
    "MAX_TAG_LEN",
    "STATUS_OK",
    "STATUS_SCAN",
    "Code",
    "ScanRequest",
    "TimeMode",
    "describe_status",
    "info",
    "laser_off",
    "laser_on",
    "parameters",
    "reset",
    "scan_once",
    "scan_stream",
    "scip2",
    "time_mode",
    "version",
]

LF = b"\n"
#: Data bytes per block line (each followed by its checksum and LF; the last may be shorter).
BLOCK_LEN = 64
#: Longest ``;string`` tag a request may carry [characters].
MAX_TAG_LEN = 16
#: Status "command accepted".
STATUS_OK = "00"
#: Status of every scan of a running MD/ME/MS stream.
STATUS_SCAN = "99"
#: Largest step index the 4-digit step fields can carry.
MAX_STEP = 9999


class Code(StrEnum):
    """Command codes (the first characters of a request and of its echo)."""

    SCIP2 = "SCIP2.0"
    VV = "VV"
    PP = "PP"
    II = "II"
    BM = "BM"
    QT = "QT"
    RS = "RS"
    TM = "TM"
    MD = "MD"  # ranges, 3 characters, continuous
    ME = "ME"  # ranges + intensities, 3 characters each, continuous
    MS = "MS"  # ranges, 2 characters (<= 4095 mm), continuous
    GD = "GD"  # ranges, 3 characters, one scan
    GE = "GE"  # ranges + intensities, one scan
    GS = "GS"  # ranges, 2 characters, one scan


#: Codes whose responses carry a scan (time stamp line + data blocks).
DATA_CODES = frozenset({Code.MD, Code.ME, Code.MS, Code.GD, Code.GE, Code.GS})
#: Continuous codes (echo: start, end, cluster, skip, remaining scans).
STREAM_CODES = frozenset({Code.MD, Code.ME, Code.MS})
#: Codes whose data lines are ``NAME:value;sum`` (the ``;`` is not summed).
INFO_CODES = frozenset({Code.VV, Code.PP, Code.II})


class TimeMode(IntEnum):
    """Control codes of ``TM``: enter the time-adjust mode, read the time, leave it."""

    ENTER = 0
    READ = 1
    LEAVE = 2


def _request(body: str, tag: str = "") -> bytes:
    if len(tag) > MAX_TAG_LEN or any(not 0x21 <= ord(c) <= 0x7E or c == ";" for c in tag):
        raise ValueError(f"a tag is at most {MAX_TAG_LEN} printable characters without ';'")
    return (body + (f";{tag}" if tag else "")).encode("ascii") + LF


def scip2() -> bytes:
    """``SCIP2.0``: switch a SCIP 1.1 sensor to SCIP 2.0 (harmless on a SCIP 2.0 sensor)."""
    return _request(Code.SCIP2)


def version(tag: str = "") -> bytes:
    """``VV``: vendor, product, firmware, protocol and serial number."""
    return _request(Code.VV, tag)


def parameters(tag: str = "") -> bytes:
    """``PP``: model, DMIN, DMAX, ARES, AMIN, AMAX, AFRT, SCAN (``shared.hokuyo.params``)."""
    return _request(Code.PP, tag)


def info(tag: str = "") -> bytes:
    """``II``: the sensor's state (laser, motor speed, time, status text)."""
    return _request(Code.II, tag)


def laser_on(tag: str = "") -> bytes:
    """``BM``: switch the laser on (status 00, or 02 when it already is)."""
    return _request(Code.BM, tag)


def laser_off(tag: str = "") -> bytes:
    """``QT``: stop any scan stream and switch the laser off."""
    return _request(Code.QT, tag)


def reset(tag: str = "") -> bytes:
    """``RS``: stop streams, laser off, settings back to their defaults."""
    return _request(Code.RS, tag)


def time_mode(mode: TimeMode, tag: str = "") -> bytes:
    """``TM0`` / ``TM1`` / ``TM2``: enter the adjust mode, read the sensor time, leave it."""
    return _request(f"{Code.TM}{int(TimeMode(mode))}", tag)


@dataclass(frozen=True, slots=True)
class ScanRequest:
    """The parameters of an MD/ME/MS/GD/GE/GS request (and of its echo).

    Attributes:
        code: the command code.
        start_step, end_step: first and last step measured (0..9999, start <= end).
        cluster: steps merged into one beam (1..99; the sensor reports the smallest range
            of the group). The echo writes 0 as well as 1 for "no merging".
        skip: scans skipped between two sent ones (0..9; continuous codes only).
        scans: scans to send (0: until QT; continuous codes only); in a scan's echo, the
            scans still to come.
    """

    code: Code
    start_step: int
    end_step: int
    cluster: int = 1
    skip: int = 0
    scans: int = 0

    def __post_init__(self) -> None:
        if self.code not in DATA_CODES:
            raise ValueError(f"{self.code} is not a scan command")
        if not 0 <= self.start_step <= self.end_step <= MAX_STEP:
            raise ValueError(f"need 0 <= start <= end <= {MAX_STEP}")
        if not 0 <= self.cluster <= 99 or not 0 <= self.skip <= 9 or not 0 <= self.scans <= 99:
            raise ValueError("cluster in 0..99, skip in 0..9, scans in 0..99")

    @property
    def beams(self) -> int:
        """Beams per scan: ceil((end - start + 1) / cluster)."""
        c = max(1, self.cluster)
        return -(-(self.end_step - self.start_step + 1) // c)

    @property
    def width(self) -> int:
        """Characters per number: 2 (MS/GS) or 3."""
        return 2 if self.code in (Code.MS, Code.GS) else 3

    @property
    def values_per_beam(self) -> int:
        """Numbers per beam: 2 (range, intensity: ME/GE) or 1."""
        return 2 if self.code in (Code.ME, Code.GE) else 1

    @property
    def data_len(self) -> int:
        """Data bytes of one scan (without checksums and line feeds)."""
        return self.beams * self.values_per_beam * self.width

    def body(self) -> str:
        """The request line without LF."""
        head = f"{self.code}{self.start_step:04d}{self.end_step:04d}{self.cluster:02d}"
        if self.code in STREAM_CODES:
            head += f"{self.skip:01d}{self.scans:02d}"
        return head

    @classmethod
    def from_echo(cls, code: Code, digits: bytes) -> ScanRequest:
        """Parse the digits after the code of an echo (13 for MD/ME/MS, 10 for GD/GE/GS).

        Raises:
            ValueError: wrong number of digits or values out of range.
        """
        d = digits.decode("ascii")
        stream = code in STREAM_CODES
        if len(d) != (13 if stream else 10) or not d.isdigit():
            raise ValueError(f"bad {code} echo digits {d!r}")
        return cls(
            code,
            int(d[0:4]),
            int(d[4:8]),
            int(d[8:10]),
            int(d[10:11]) if stream else 0,
            int(d[11:13]) if stream else 0,
        )


def scan_stream(req: ScanRequest, tag: str = "") -> bytes:
    """``MD`` / ``ME`` / ``MS``: stream ``req.scans`` scans (0: until ``QT``)."""
    if req.code not in STREAM_CODES:
        raise ValueError(f"{req.code} is not a continuous scan command")
    return _request(req.body(), tag)


def scan_once(req: ScanRequest, tag: str = "") -> bytes:
    """``GD`` / ``GE`` / ``GS``: the newest scan, once."""
    if req.code in STREAM_CODES:
        raise ValueError(f"{req.code} is a continuous scan command")
    return _request(req.body(), tag)


_SCAN_STATUS = {
    "00": "command received",
    "01": "starting step has a non-numeric value",
    "02": "end step has a non-numeric value",
    "03": "cluster count has a non-numeric value",
    "04": "end step is out of range",
    "05": "end step is smaller than the starting step",
    "06": "scan interval has a non-numeric value",
    "07": "number of scans has a non-numeric value",
    "10": "the laser is off",
    "98": "resumed after confirming normal laser operation",
    "99": "scan data",
}
_GENERIC_STATUS = {
    "0A": "unable to create a transmission buffer or string too long",
    "0B": "buffer shortage or command repeated",
    "0C": "command with insufficient parameters",
    "0D": "undefined control code",
    "0E": "undefined command",
    "0F": "command with too many parameters",
    "0G": "string too long",
    "0H": "string has an invalid character",
}


def describe_status(code: str, status: str) -> str:
    """A readable meaning of ``status`` in the response to command ``code``."""
    if status in _GENERIC_STATUS:
        return _GENERIC_STATUS[status]
    if code in {c.value for c in DATA_CODES} and status in _SCAN_STATUS:
        return _SCAN_STATUS[status]
    if code == Code.BM and status == "01":
        return "unable to switch the laser on (laser malfunction)"
    if code == Code.BM and status == "02":
        return "the laser was already on"
    if code == Code.TM and status in ("01", "02", "03", "04"):
        return {
            "01": "invalid control code",
            "02": "adjust mode already on",
            "03": "adjust mode already off",
            "04": "adjust mode is off",
        }[status]
    if status == STATUS_OK:
        return "command received"
    if status.isdigit() and 21 <= int(status) <= 49:
        return "processing stopped to verify an error"
    if status.isdigit() and 50 <= int(status) <= 97:
        return "hardware trouble (laser or motor malfunction)"
    return "unknown status"
