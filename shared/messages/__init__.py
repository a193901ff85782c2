"""The message contract of racestack: typed, validated records and their msgpack codec.

Every message is a frozen ``msgspec.Struct`` with ``stamp_s`` (sender's clock [s]) and ``seq``
(sequence number, stamped by the bus publisher), encoded as a msgpack map with a ``"type"``
tag and a ``"v"`` schema version (see ``shared.messages.codec`` for the wire rules, and
``docs/message-contract.md`` for the table of keys and fields). Constructors and decoding
validate types, finiteness, ranges, array dtypes and shapes, and raise only ``MessageError``::

    from shared.messages import DriveCmd, decode, decode_any
    data = DriveCmd(stamp_s=1.5, speed_mps=2.0, steering_rad=0.1).encode()
    cmd = decode(data, DriveCmd)        # MessageError if not a valid DriveCmd
    anything = decode_any(data)         # MessageError if not a valid known message

Python + numpy + msgspec: no zenoh import, usable by the maths and by tests.
"""

from shared.messages.codec import (
    MAX_PAYLOAD_BYTES,
    REASONS,
    REGISTRY,
    Message,
    MessageError,
    decode,
    decode_any,
    encode,
    unpack_map,
)
from shared.messages.records import (
    LAP_KINDS,
    LOG_LEVELS,
    MESSAGE_TYPES,
    PLAN_METHODS,
    PLAN_STATUSES,
    SIM_ACTIONS,
    VESC_STATUSES,
    DriveCmd,
    HorizonCol,
    Imu,
    InputCol,
    LapEvent,
    LogEvent,
    Odom,
    Opponents,
    OpponentTrack,
    Plan,
    Pose,
    PoseAxis,
    Scan,
    SimControl,
    SimTruth,
    State,
    Teleport,
    VescState,
)
from shared.messages.vocab import (
    LapKindName,
    LogLevelName,
    PlanStatusName,
    SimActionName,
    VescStatusName,
)

__all__ = [
    "LAP_KINDS",
    "LOG_LEVELS",
    "MAX_PAYLOAD_BYTES",
    "MESSAGE_TYPES",
    "PLAN_METHODS",
    "PLAN_STATUSES",
    "REASONS",
    "REGISTRY",
    "SIM_ACTIONS",
    "VESC_STATUSES",
    "DriveCmd",
    "HorizonCol",
    "Imu",
    "InputCol",
    "LapEvent",
    "LapKindName",
    "LogEvent",
    "LogLevelName",
    "Message",
    "MessageError",
    "Odom",
    "OpponentTrack",
    "Opponents",
    "Plan",
    "PlanStatusName",
    "Pose",
    "PoseAxis",
    "Scan",
    "SimActionName",
    "SimControl",
    "SimTruth",
    "State",
    "Teleport",
    "VescState",
    "VescStatusName",
    "decode",
    "decode_any",
    "encode",
    "unpack_map",
]
