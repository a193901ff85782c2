"""Sensor parameters (``PP``), beam geometry and scans: SCIP responses -> ranges and angles.

Pure functions and records, no I/O.

Geometry (the protocol document's "measurement direction"): the sensor numbers its steps
counter-clockwise seen from above, ``ARES`` steps per turn, step ``AFRT`` on its front
axis. In the car frame (x forward, y left, z up) with the sensor upright, step ``k`` points
at::

    theta(k) = (k - AFRT) * 2 pi / ARES + mount_yaw_rad

A beam that merges ``cluster`` steps ``k0 .. k0 + cluster - 1`` is given the angle of their
centre, ``k0 + (cluster - 1) / 2``. Mounted upside down the sensor turns clockwise in the
car frame: ``theta(k) = -(k - AFRT) * 2 pi / ARES + mount_yaw_rad`` (the beams keep the
sensor's order, the increment is negative).

Ranges: the 3-character numbers are millimetres; values below ``ERROR_CODE_MAX_MM`` (20 mm)
are the sensor's error codes (no echo, too close, reflection too strong, ...), not ranges;
they become ``+inf`` (no return), as do ranges outside the configured window.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from shared.angles import wrap_angle
from shared.hokuyo.decoder import Response
from shared.hokuyo.encoding import decode_array, decode_int
from shared.hokuyo.protocol import DATA_CODES, ScanRequest

__all__ = [
    "ERROR_CODE_MAX_MM",
    "TIMESTAMP_BITS",
    "BeamGeometry",
    "RawScan",
    "ScanError",
    "SensorParams",
    "parse_info",
    "parse_params",
    "parse_scan",
    "parse_time",
    "ranges_m",
]

#: Numbers below this [mm] are error codes, not ranges.
ERROR_CODE_MAX_MM = 20
#: Bits of the sensor's millisecond time stamp (it wraps every 2**24 ms = 4.66 h).
TIMESTAMP_BITS = 24
_TWO_PI = 2.0 * math.pi


class ScanError(ValueError):
    """A response that cannot be a scan or a parameter set (the message says why)."""


def parse_info(resp: Response) -> dict[str, str]:
    """The ``NAME:value`` lines of a ``VV`` / ``PP`` / ``II`` response as a dict."""
    out: dict[str, str] = {}
    for line in resp.lines:
        name, sep, value = line.decode("latin-1").partition(":")
        if sep:
            out[name.strip()] = value.strip()
    return out


@dataclass(frozen=True, slots=True)
class SensorParams:
    """What ``PP`` reports.

    Attributes:
        model: the MODL line.
        dmin_mm, dmax_mm: shortest and longest measurable range [mm].
        ares: steps in a full turn (1440 for the UTM-30LX: 0.25 deg).
        amin, amax: first and last step of the measurement range.
        afrt: step on the sensor's front axis.
        scan_rpm: motor speed [rev/min] (2400 rpm = 40 scans/s).
    """

    model: str
    dmin_mm: int
    dmax_mm: int
    ares: int
    amin: int
    amax: int
    afrt: int
    scan_rpm: int

    def __post_init__(self) -> None:
        if not (
            0 < self.ares <= 65536
            and 0 <= self.amin <= self.amax < 10000
            and 0 <= self.dmin_mm < self.dmax_mm
            and self.scan_rpm > 0
        ):
            raise ScanError(f"implausible sensor parameters {self}")

    @property
    def step_rad(self) -> float:
        """Angle between two steps [rad]: 2 pi / ARES."""
        return _TWO_PI / self.ares

    @property
    def scan_period_s(self) -> float:
        """Time of one turn [s]: 60 / SCAN."""
        return 60.0 / self.scan_rpm


_PP_FIELDS = ("DMIN", "DMAX", "ARES", "AMIN", "AMAX", "AFRT", "SCAN")


def parse_params(resp: Response) -> SensorParams:
    """The ``SensorParams`` of a ``PP`` response.

    Raises:
        ScanError: not a PP response, status not "00", a field missing or not a number.
    """
    if resp.code != "PP" or resp.status != "00":
        raise ScanError(f"not a good PP response: {resp.code} status {resp.status}")
    kv = parse_info(resp)
    vals: dict[str, int] = {}
    for name in _PP_FIELDS:
        text = kv.get(name, "")
        if not text.isdigit():
            raise ScanError(f"PP: {name} missing or not a number ({text!r})")
        vals[name] = int(text)
    return SensorParams(
        model=kv.get("MODL", "?"),
        dmin_mm=vals["DMIN"],
        dmax_mm=vals["DMAX"],
        ares=vals["ARES"],
        amin=vals["AMIN"],
        amax=vals["AMAX"],
        afrt=vals["AFRT"],
        scan_rpm=vals["SCAN"],
    )


@dataclass(frozen=True, slots=True)
class BeamGeometry:
    """The angles of a scan's beams in the car frame.

    Attributes:
        angle_min_rad: angle of beam 0 [rad], wrapped into [-pi, pi).
        angle_increment_rad: angle from beam i to beam i + 1 [rad] (negative upside down).
        beams: number of beams.
    """

    angle_min_rad: float
    angle_increment_rad: float
    beams: int

    @classmethod
    def of(
        cls,
        params: SensorParams,
        req: ScanRequest,
        *,
        mount_yaw_rad: float = 0.0,
        upside_down: bool = False,
    ) -> BeamGeometry:
        """The geometry of ``req``'s beams on a sensor with ``params`` (module docstring)."""
        c = max(1, req.cluster)
        sign = -1.0 if upside_down else 1.0
        centre = req.start_step + 0.5 * (c - 1) - params.afrt
        first = sign * centre * params.step_rad + mount_yaw_rad
        first = wrap_angle(first)
        return cls(first, sign * c * params.step_rad, req.beams)

    def angles_rad(self) -> np.ndarray:
        """(beams,) float64 beam angles [rad]."""
        return self.angle_min_rad + self.angle_increment_rad * np.arange(self.beams)


@dataclass(frozen=True, slots=True)
class RawScan:
    """One scan as the sensor sent it.

    Attributes:
        request: the echoed request (steps, cluster; ``scans`` = scans still to come).
        sensor_ms: the sensor's 24-bit time stamp [ms] (wraps at 2**24).
        ranges_mm: (beams,) int64 ranges [mm] or error codes (< 20).
        intensities: (beams,) int64 intensities (ME/GE) or None.
    """

    request: ScanRequest
    sensor_ms: int
    ranges_mm: np.ndarray
    intensities: np.ndarray | None


def parse_scan(resp: Response) -> RawScan:
    """The scan of an MD/ME/MS (status 99) or GD/GE/GS (status 00) response.

    Raises:
        ScanError: not a scan, an error status, a missing time stamp, or a data length that
            does not match the echoed request (a truncated scan).
    """
    if resp.code not in DATA_CODES:
        raise ScanError(f"{resp.code} carries no scan")
    try:
        req = ScanRequest.from_echo(resp.code, resp.digits)
    except ValueError as exc:
        raise ScanError(str(exc)) from None
    if resp.status not in ("99", "00") or not resp.lines:
        raise ScanError(f"{resp.code} status {resp.status} carries no scan")
    stamp = resp.lines[0]
    if len(stamp) != 4:
        raise ScanError(f"time stamp line of {len(stamp)} characters")
    data = b"".join(resp.lines[1:])
    if len(data) != req.data_len:
        raise ScanError(f"{len(data)} data bytes, the request needs {req.data_len}")
    try:
        sensor_ms = decode_int(stamp)
        values = decode_array(data, req.width)
    except ValueError as exc:
        raise ScanError(str(exc)) from None
    if req.values_per_beam == 2:
        return RawScan(req, sensor_ms, values[0::2], values[1::2])
    return RawScan(req, sensor_ms, values, None)


def ranges_m(ranges_mm: np.ndarray, range_min_m: float, range_max_m: float) -> np.ndarray:
    """(n,) float32 ranges [m]: mm / 1000, and ``+inf`` for error codes (< 20 mm) and for
    ranges outside ``[range_min_m, range_max_m]``."""
    r = ranges_mm.astype(np.float64) * 1e-3
    bad = (ranges_mm < ERROR_CODE_MAX_MM) | (r < range_min_m) | (r > range_max_m)
    out = r.astype(np.float32)
    out[bad] = np.inf
    return out


def parse_time(resp: Response) -> int:
    """The sensor time [ms] (24 bits) of a ``TM1`` answer.

    Raises:
        ScanError: an error status or no 4-character time line.
    """
    if resp.code != "TM" or resp.status != "00" or len(resp.lines) != 1:
        raise ScanError("TM1 answer without a time")
    if len(resp.lines[0]) != 4:
        raise ScanError("TM1 time line is not 4 characters")
    try:
        return decode_int(resp.lines[0])
    except ValueError as exc:
        raise ScanError(str(exc)) from None
