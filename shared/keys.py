"""Every Zenoh key expression of racestack, in one place.

All keys live under ``racestack/<car>/`` where ``<car>`` is ``BusSettings.car`` (default
``car0``). Services build their keys with ``Keys(car)``, never by formatting strings::

    keys = Keys("car0")
    keys.drive_cmd          # "racestack/car0/cmd/drive"
    keys.alive("planner")   # "racestack/car0/alive/planner" (liveliness token)

``TOPIC_TYPES`` maps each data key's suffix to the ``"type"`` tag of the one message type
published on it (see ``shared.messages`` and ``docs/message-contract.md``). This module
imports nothing heavy (no zenoh, no numpy) so configuration code can use it.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from types import MappingProxyType

#: The root of every racestack key.
ROOT = "racestack"
#: The car name used when the configuration does not give one.
DEFAULT_CAR = "car0"
#: A safe key chunk: a car or service name (no "/", no wildcards, no "$", no spaces).
SAFE_CHUNK_PATTERN = r"^[A-Za-z0-9_-]+$"
_SAFE_CHUNK = re.compile(SAFE_CHUNK_PATTERN)
#: Longest car or service name accepted [characters].
MAX_CHUNK_LEN = 64

# Key suffixes below racestack/<car>/ (the single source of truth for topic names).
POSE = "vehicle/pose"
IMU = "vehicle/imu"
ODOM = "vehicle/odom"
SCAN = "vehicle/scan"
STATE = "state"
DRIVE_CMD = "cmd/drive"
PLAN = "planner/plan"
LAP = "lap"
VESC_STATE = "vesc/state"
SIM_TRUTH = "sim/truth"
SIM_CONTROL = "sim/control"
TELEPORT = "vehicle/teleport"
OPPONENTS = "opponents"
EVENTS_LOG = "events/log"
#: Liveliness tokens: racestack/<car>/alive/<service>.
ALIVE = "alive"

#: Suffix -> "type" tag of the message published on that key.
TOPIC_TYPES: MappingProxyType[str, str] = MappingProxyType(
    {
        POSE: "pose",
        IMU: "imu",
        ODOM: "odom",
        SCAN: "scan",
        STATE: "state",
        DRIVE_CMD: "drive_cmd",
        PLAN: "plan",
        LAP: "lap_event",
        VESC_STATE: "vesc_state",
        SIM_TRUTH: "sim_truth",
        SIM_CONTROL: "sim_control",
        TELEPORT: "teleport",
        OPPONENTS: "opponents",
        EVENTS_LOG: "log_event",
    }
)


def check_chunk(name: str, what: str = "name") -> str:
    """Return `name` if it is a safe key chunk (``[A-Za-z0-9_-]+``), else raise ValueError."""
    if not isinstance(name, str) or not _SAFE_CHUNK.match(name) or len(name) > MAX_CHUNK_LEN:
        raise ValueError(
            f"{what} {name!r} is not a safe key chunk "
            f"([A-Za-z0-9_-], 1 to {MAX_CHUNK_LEN} characters)"
        )
    return name


@dataclass(frozen=True)
class Keys:
    """The key expressions of one car (``racestack/<car>/...``)."""

    car: str = DEFAULT_CAR

    def __post_init__(self) -> None:
        check_chunk(self.car, "car name")

    @property
    def prefix(self) -> str:
        """``racestack/<car>`` (no trailing slash)."""
        return f"{ROOT}/{self.car}"

    def key(self, suffix: str) -> str:
        """The full key of a suffix such as ``"vehicle/pose"`` (ValueError if unknown)."""
        if suffix not in TOPIC_TYPES:
            raise ValueError(f"unknown topic suffix {suffix!r}; known: {sorted(TOPIC_TYPES)}")
        return f"{self.prefix}/{suffix}"

    @property
    def pose(self) -> str:
        """Pose from a localiser or the simulator (``Pose``)."""
        return self.key(POSE)

    @property
    def imu(self) -> str:
        """IMU yaw rate and accelerations (``Imu``)."""
        return self.key(IMU)

    @property
    def odom(self) -> str:
        """Wheel speed and steering from the VESC driver or the simulator (``Odom``)."""
        return self.key(ODOM)

    @property
    def scan(self) -> str:
        """2D lidar scan (``Scan``)."""
        return self.key(SCAN)

    @property
    def state(self) -> str:
        """Fused state from the localization bridge (``State``)."""
        return self.key(STATE)

    @property
    def drive_cmd(self) -> str:
        """Speed and steering commanded by the planner (``DriveCmd``)."""
        return self.key(DRIVE_CMD)

    @property
    def plan(self) -> str:
        """Predicted horizon, beta and solver statistics (``Plan``)."""
        return self.key(PLAN)

    @property
    def lap(self) -> str:
        """Lap and off-track events (``LapEvent``)."""
        return self.key(LAP)

    @property
    def vesc_state(self) -> str:
        """Motor controller values (``VescState``)."""
        return self.key(VESC_STATE)

    @property
    def sim_truth(self) -> str:
        """Simulator ground truth (``SimTruth``)."""
        return self.key(SIM_TRUTH)

    @property
    def sim_control(self) -> str:
        """Reset / pause / resume requests to the simulator (``SimControl``)."""
        return self.key(SIM_CONTROL)

    @property
    def teleport(self) -> str:
        """The car put elsewhere: a simulator reset or an operator (``Teleport``)."""
        return self.key(TELEPORT)

    @property
    def opponents(self) -> str:
        """Opponents tracked from the lidar by the localization bridge (``Opponents``)."""
        return self.key(OPPONENTS)

    @property
    def events_log(self) -> str:
        """Warnings and text log records of any service (``LogEvent``)."""
        return self.key(EVENTS_LOG)

    @property
    def all_data(self) -> str:
        """Wildcard matching every data key of this car (``racestack/<car>/**``)."""
        return f"{self.prefix}/**"

    def alive(self, service: str) -> str:
        """Liveliness token key of one service: ``racestack/<car>/alive/<service>``."""
        return f"{self.prefix}/{ALIVE}/{check_chunk(service, 'service name')}"

    @property
    def alive_any(self) -> str:
        """Wildcard matching the liveliness token of every service of this car."""
        return f"{self.prefix}/{ALIVE}/*"

    def service_of_alive_key(self, key: str) -> str | None:
        """The service name of a liveliness key of this car, None for any other key."""
        head = f"{self.prefix}/{ALIVE}/"
        if not key.startswith(head):
            return None
        name = key[len(head) :]
        return name if _SAFE_CHUNK.match(name) else None

    def topics(self) -> dict[str, str]:
        """Full key -> message ``"type"`` tag, for every data key of this car."""
        return {self.key(suffix): tag for suffix, tag in TOPIC_TYPES.items()}

    def suffix_of(self, key: str) -> str | None:
        """The topic suffix of a full key of this car (``"vehicle/pose"``), None otherwise."""
        head = f"{self.prefix}/"
        if key.startswith(head) and key[len(head) :] in TOPIC_TYPES:
            return key[len(head) :]
        return None
