"""The Hokuyo SCIP 2.0 protocol (pure: no I/O except the fake's shell ``fake_io``).

``encoding`` (6-bit characters, the line checksum), ``protocol`` (commands, status codes,
``ScanRequest``), ``decoder`` (``ResponseDecoder``: bytes -> checked responses, resyncing
after noise), ``scan`` (``SensorParams`` from PP, ``BeamGeometry``, ``parse_scan``,
``ranges_m``), ``timesync`` (``SensorClock``: the 24-bit ms counter on the host clock),
``fake`` (a fake sensor's model with its own encoder) and ``fake_io`` (it on a pty / TCP).
"""

from shared.hokuyo.decoder import DecoderCounters, Response, ResponseDecoder
from shared.hokuyo.encoding import decode_array, decode_int, encode_int, sum_char
from shared.hokuyo.protocol import Code, ScanRequest, TimeMode, describe_status
from shared.hokuyo.scan import (
    BeamGeometry,
    RawScan,
    ScanError,
    SensorParams,
    parse_params,
    parse_scan,
    parse_time,
    ranges_m,
)
from shared.hokuyo.timesync import SensorClock

__all__ = [
    "BeamGeometry",
    "Code",
    "DecoderCounters",
    "RawScan",
    "Response",
    "ResponseDecoder",
    "ScanError",
    "ScanRequest",
    "SensorClock",
    "SensorParams",
    "TimeMode",
    "decode_array",
    "decode_int",
    "describe_status",
    "encode_int",
    "parse_params",
    "parse_scan",
    "parse_time",
    "ranges_m",
    "sum_char",
]
