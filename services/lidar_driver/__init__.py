"""The Hokuyo lidar driver (SCIP 2.0 over USB serial or TCP), its own process.

The protocol is ``shared.hokuyo`` (commands, the response decoder, scans and geometry, the
clock offset, the fake sensor). The driver's own modules: ``link`` (serial / TCP with
reconnect), ``session`` (handshake and stream as a pure state machine) and ``service``
(the Zenoh shell publishing ``vehicle/scan``).
"""

from services.lidar_driver.link import Link, LinkCounters
from services.lidar_driver.session import (
    LidarSession,
    Note,
    Phase,
    Reconnect,
    ScanReady,
    SessionCounters,
)

__all__ = [
    "LidarSession",
    "Link",
    "LinkCounters",
    "Note",
    "Phase",
    "Reconnect",
    "ScanReady",
    "SessionCounters",
]
