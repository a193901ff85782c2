"""SCIP 2.0 character encoding and the line checksum (pure functions, no I/O).

SCIP 2.0 sends numbers as printable characters carrying 6 bits each: a value is split into
6-bit groups, most significant first, and each group ``g`` is sent as the byte ``g + 0x30``
(so every data byte lies in ``0x30..0x6F``)::

    value = sum_k (c_k - 0x30) << 6 (n - 1 - k)        n = 2, 3 or 4 characters

2 characters hold 0..4095 (MS/GS ranges), 3 characters 0..262143 (MD/GD ranges [mm] and
intensities), 4 characters 0..16777215 (the 24-bit time stamp [ms]).

The checksum of a line is one character: the low 6 bits of the sum of the line's bytes,
plus 0x30 (``sum_char``). It covers the bytes before it: the status (2 bytes), the time
stamp (4 bytes) or a data block (up to 64 bytes). In the ``VV``/``PP``/``II`` info lines
``NAME:value;S`` the ``;`` separator is not summed.
"""

from __future__ import annotations

import numpy as np

__all__ = [
    "CHAR_OFFSET",
    "decode_array",
    "decode_int",
    "encode_int",
    "sum_char",
]

#: Offset of the 6-bit groups: byte = group + 0x30.
CHAR_OFFSET = 0x30
_BITS = 6
_MASK = 0x3F


def sum_char(data: bytes | bytearray | memoryview) -> int:
    """The checksum byte of ``data``: ``(sum(data) & 0x3F) + 0x30``."""
    return (sum(data) & _MASK) + CHAR_OFFSET


def decode_int(chars: bytes | bytearray | memoryview) -> int:
    """The value of one number of ``len(chars)`` characters (each ``0x30..0x6F``).

    Raises:
        ValueError: a character outside ``0x30..0x6F``.
    """
    value = 0
    for c in bytes(chars):
        g = c - CHAR_OFFSET
        if not 0 <= g <= _MASK:
            raise ValueError(f"byte 0x{c:02x} is not a SCIP data character")
        value = (value << _BITS) | g
    return value


def encode_int(value: int, width: int) -> bytes:
    """``value`` as ``width`` SCIP characters (the inverse of ``decode_int``).

    Raises:
        ValueError: ``value`` does not fit in ``6 * width`` bits or is negative.
    """
    if not 0 <= value < 1 << (_BITS * width):
        raise ValueError(f"{value} does not fit in {width} SCIP characters")
    return bytes(
        ((value >> (_BITS * (width - 1 - k))) & _MASK) + CHAR_OFFSET for k in range(width)
    )


def decode_array(data: bytes | bytearray | memoryview, width: int) -> np.ndarray:
    """All numbers of a data field: (len(data) // width,) int64, ``width`` chars each.

    ``data`` is the concatenation of a scan's data blocks without their checksums and line
    feeds (a number may straddle two blocks).

    Raises:
        ValueError: ``len(data)`` is not a multiple of ``width``, or a byte is outside
            ``0x30..0x6F``.
    """
    raw = np.frombuffer(bytes(data), dtype=np.uint8)
    if raw.size % width:
        raise ValueError(f"{raw.size} data bytes are not a multiple of {width}")
    groups = raw.astype(np.int64) - CHAR_OFFSET
    if groups.size and (groups.min() < 0 or groups.max() > _MASK):
        raise ValueError("data byte outside 0x30..0x6F")
    groups = groups.reshape(-1, width)
    out = np.zeros(groups.shape[0], dtype=np.int64)
    for k in range(width):
        out = (out << _BITS) | groups[:, k]
    return out
