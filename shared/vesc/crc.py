"""CRC-16/XMODEM, the checksum of VESC frames (pure, no I/O).

Parameters: polynomial 0x1021, initial value 0x0000, no input or output reflection, no final
xor. The check value of ASCII ``b"123456789"`` is 0x31C3. This is the CRC that
``binascii.crc_hqx`` computes (in C), so the checksum costs no Python loop per byte.
"""

from __future__ import annotations

import binascii

#: Generator polynomial of CRC-16/XMODEM (x^16 + x^12 + x^5 + 1).
CRC16_POLY = 0x1021
#: Initial register value.
CRC16_INIT = 0x0000
#: Check value: the CRC of ``b"123456789"``.
CRC16_CHECK = 0x31C3


def crc16_xmodem(data: bytes | bytearray | memoryview, crc: int = CRC16_INIT) -> int:
    """Return the CRC-16/XMODEM of ``data`` (an int in [0, 0xFFFF]).

    ``crc`` continues a running checksum (pass the previous result to checksum in pieces).
    """
    return binascii.crc_hqx(data, crc)
