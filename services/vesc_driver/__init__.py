"""The VESC motor-controller driver (core without bus code; the Zenoh shell wraps it).

Modules: ``crc`` (CRC-16/XMODEM), ``protocol`` (command ids, framing, encoders), ``decoder``
(streaming frame decoder), ``values`` (GET_VALUES replies), ``conversions`` (m/s, rad <->
ERPM, servo), ``watchdog`` (command timeout), ``serial_link`` (reconnecting pyserial port),
``driver`` (``VescDriver``), ``fake_vesc`` (a VESC on a pty for tests).
"""

from services.vesc_driver.conversions import ActuatorCommand, convert_command
from services.vesc_driver.decoder import DecoderCounters, Frame, FrameDecoder
from services.vesc_driver.driver import (
    DriverCounters,
    OdometryRecord,
    TickResult,
    VescDriver,
    VescStateRecord,
)
from services.vesc_driver.protocol import CommandId, encode_frame
from services.vesc_driver.serial_link import LinkCounters, LinkState, SerialLink
from services.vesc_driver.values import VescValues, parse_values
from services.vesc_driver.watchdog import CommandWatchdog, WatchdogState

__all__ = [
    "ActuatorCommand",
    "CommandId",
    "CommandWatchdog",
    "DecoderCounters",
    "DriverCounters",
    "Frame",
    "FrameDecoder",
    "LinkCounters",
    "LinkState",
    "OdometryRecord",
    "SerialLink",
    "TickResult",
    "VescDriver",
    "VescStateRecord",
    "VescValues",
    "WatchdogState",
    "convert_command",
    "encode_frame",
    "parse_values",
]
