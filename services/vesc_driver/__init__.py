"""The VESC motor-controller driver (core without bus code; the Zenoh shell wraps it).

The protocol is ``shared.vesc`` (CRC-16/XMODEM, framing and encoders, the streaming decoder,
GET_VALUES replies, unit conversions, the fake VESC); its main names are re-exported here.
The driver's own modules: ``conversions`` (``convert_command``: the safety policy of what is
sent), ``watchdog`` (command timeout), ``serial_link`` (reconnecting pyserial port),
``schedule`` (``TickScheduler``: when the serial loop ticks), ``driver`` (``VescDriver`` and
its serial loop) and ``service`` (the Zenoh shell).
"""

from services.vesc_driver.conversions import ActuatorCommand, convert_command
from services.vesc_driver.driver import (
    DriverCounters,
    ImuRecord,
    OdometryRecord,
    TickResult,
    VescDriver,
    VescStateRecord,
)
from services.vesc_driver.schedule import TickReason, TickScheduler
from services.vesc_driver.serial_link import LinkCounters, LinkState, SerialLink
from services.vesc_driver.watchdog import CommandWatchdog, WatchdogState
from shared.vesc import (
    CommandId,
    DecoderCounters,
    Frame,
    FrameDecoder,
    VescValues,
    encode_frame,
    parse_values,
)

__all__ = [
    "ActuatorCommand",
    "CommandId",
    "CommandWatchdog",
    "DecoderCounters",
    "DriverCounters",
    "Frame",
    "FrameDecoder",
    "ImuRecord",
    "LinkCounters",
    "LinkState",
    "OdometryRecord",
    "SerialLink",
    "TickReason",
    "TickResult",
    "TickScheduler",
    "VescDriver",
    "VescStateRecord",
    "VescValues",
    "WatchdogState",
    "convert_command",
    "encode_frame",
    "parse_values",
]
