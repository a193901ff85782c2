"""Zenoh keys of ROS 2 topics and rmw_zenoh's sample attachment (pure, no I/O).

The key naming (``zenoh_key``: ``bridge_ros2dds`` and ``rmw_zenoh``) lives in
``shared.ros2_keys``, where the hub's access rules use it too; it is re-exported here.

rmw_zenoh publishers attach 33 bytes to every sample, which its subscribers require::

    sequence number  int64 little endian (per publisher, from 1)
    source timestamp int64 little endian [ns since the Unix epoch]
    GID length       uint8 = 16
    GID              16 bytes (one random id per publisher)
"""

from __future__ import annotations

import struct
from dataclasses import dataclass

from shared.config.ros2 import Ros2Settings, Ros2Topic
from shared.ros2_keys import HUMBLE_TYPE_HASH, dds_type_name, type_hash, zenoh_key

__all__ = [
    "ATTACHMENT_LEN",
    "GID_LEN",
    "HUMBLE_TYPE_HASH",
    "Attachment",
    "dds_type_name",
    "parse_attachment",
    "type_hash",
    "uses_attachment",
    "zenoh_key",
]

#: Size of a publisher GID in rmw_zenoh's attachment [bytes].
GID_LEN = 16
ATTACHMENT_LEN = 8 + 8 + 1 + GID_LEN


def uses_attachment(topic: Ros2Topic, settings: Ros2Settings) -> bool:
    """Whether outbound samples of this topic carry rmw_zenoh's attachment."""
    return (topic.scheme or settings.scheme) == "rmw_zenoh"


@dataclass(frozen=True, slots=True)
class Attachment:
    """rmw_zenoh's sample attachment (see the module docstring).

    Attributes:
        sequence: per-publisher sequence number (from 1).
        source_time_ns: the publisher's clock at publication [ns since the Unix epoch].
        gid: the publisher's 16-byte id.
    """

    sequence: int
    source_time_ns: int
    gid: bytes

    def encode(self) -> bytes:
        """The 33 bytes on the wire."""
        if len(self.gid) != GID_LEN:
            raise ValueError(f"a GID has {GID_LEN} bytes, got {len(self.gid)}")
        return struct.pack("<qqB", self.sequence, self.source_time_ns, GID_LEN) + self.gid


def parse_attachment(data: bytes) -> Attachment | None:
    """Decode an rmw_zenoh attachment (None: not one)."""
    if len(data) != ATTACHMENT_LEN or data[16] != GID_LEN:
        return None
    seq, t_ns = struct.unpack_from("<qq", data, 0)
    return Attachment(sequence=seq, source_time_ns=t_ns, gid=bytes(data[17:]))
