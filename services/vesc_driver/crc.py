"""CRC-16/XMODEM, the checksum of VESC frames.

Parameters: polynomial 0x1021, initial value 0x0000, no input or output reflection, no final
xor. The check value of ASCII ``b"123456789"`` is 0x31C3.
"""

from __future__ import annotations

#: Generator polynomial of CRC-16/XMODEM (x^16 + x^12 + x^5 + 1).
CRC16_POLY = 0x1021
#: Initial register value.
CRC16_INIT = 0x0000
#: Check value: the CRC of ``b"123456789"``.
CRC16_CHECK = 0x31C3

_MASK16 = 0xFFFF


def _make_table() -> tuple[int, ...]:
    table = []
    for byte in range(256):
        reg = byte << 8
        for _ in range(8):
            reg = ((reg << 1) ^ CRC16_POLY) if reg & 0x8000 else (reg << 1)
            reg &= _MASK16
        table.append(reg)
    return tuple(table)


_TABLE = _make_table()


def crc16_xmodem(data: bytes | bytearray | memoryview, crc: int = CRC16_INIT) -> int:
    """Return the CRC-16/XMODEM of ``data`` (an int in [0, 0xFFFF]).

    ``crc`` continues a running checksum (pass the previous result to checksum in pieces).
    """
    table = _TABLE
    for byte in bytes(data):
        crc = ((crc << 8) & _MASK16) ^ table[((crc >> 8) ^ byte) & 0xFF]
    return crc
