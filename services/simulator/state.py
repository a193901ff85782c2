"""State layout of the simulated car and the small value types around it.

State vector (map frame, SI units), the CommonRoad / F1TENTH single-track layout:

====  ==========  =====================================================================
idx   name        meaning
====  ==========  =====================================================================
0     X           CoG x [m] (map frame)
1     Y           CoG y [m]
2     DELTA       front road-wheel steering angle [rad], positive to the left
3     V           speed of the CoG [m/s] (signed, along the velocity direction psi + beta)
4     PSI         yaw [rad], from the map x axis, counter-clockwise; continuous (not wrapped)
5     PSI_DOT     yaw rate [rad/s]
6     BETA        slip angle at the CoG [rad]: velocity direction minus yaw
====  ==========  =====================================================================
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from enum import IntEnum
from typing import NamedTuple

from shared.angles import wrap_angle


def rear_axle(x_m: float, y_m: float, yaw_rad: float, lr_m: float) -> tuple[float, float, float]:
    """Rear-axle pose (x [m], y [m], yaw [rad]) of a car whose CoG is at (x, y), lr behind it."""
    return x_m - lr_m * math.cos(yaw_rad), y_m - lr_m * math.sin(yaw_rad), yaw_rad


class StateIndex(IntEnum):
    """Index of each element of the 7-element state (see the module docstring)."""

    X = 0
    Y = 1
    DELTA = 2
    V = 3
    PSI = 4
    PSI_DOT = 5
    BETA = 6


#: Number of state elements.
NX = len(StateIndex)

#: The element names in index order. The hot-path code unpacks state tuples positionally as
#: ``x, y, delta, v, psi, psi_dot, beta``; this guard keeps that in step with the enum.
STATE_ORDER = ("X", "Y", "DELTA", "V", "PSI", "PSI_DOT", "BETA")
_ORDERED = sorted(StateIndex)
if tuple(i.name for i in _ORDERED) != STATE_ORDER or [int(i) for i in _ORDERED] != list(
    range(NX)
):  # pragma: no cover - only fails when someone edits the layout
    raise ImportError("StateIndex no longer matches the positional unpacking in the simulator")

#: A state as a plain tuple of 7 floats in ``StateIndex`` order (the integrator's hot path).
StateTuple = tuple[float, float, float, float, float, float, float]


class Pose2D(NamedTuple):
    """A planar pose in the map frame: position [m] and yaw [rad]."""

    x_m: float
    y_m: float
    yaw_rad: float


class Command(NamedTuple):
    """A drive command: target speed [m/s] and target front steering angle [rad]."""

    speed_mps: float
    steering_rad: float


@dataclass(frozen=True, slots=True)
class VehicleState:
    """The true state of the simulated car (fields in ``StateIndex`` order, SI units)."""

    x_m: float
    y_m: float
    delta_rad: float
    v_mps: float
    yaw_rad: float
    yaw_rate_radps: float
    slip_rad: float

    @classmethod
    def from_tuple(cls, s: StateTuple) -> VehicleState:
        """From a tuple/array in ``StateIndex`` order."""
        return cls(*(float(v) for v in s))

    def as_tuple(self) -> StateTuple:
        """The state as a tuple in ``StateIndex`` order."""
        return (
            self.x_m,
            self.y_m,
            self.delta_rad,
            self.v_mps,
            self.yaw_rad,
            self.yaw_rate_radps,
            self.slip_rad,
        )

    @property
    def pose(self) -> Pose2D:
        """CoG pose with the yaw wrapped into [-pi, pi)."""
        return Pose2D(self.x_m, self.y_m, wrap_angle(self.yaw_rad))

    @property
    def vx_body_mps(self) -> float:
        """Longitudinal velocity in the body frame ``v cos(beta)`` [m/s]."""
        return self.v_mps * math.cos(self.slip_rad)

    @property
    def vy_body_mps(self) -> float:
        """Lateral velocity in the body frame ``v sin(beta)`` [m/s] (positive to the left)."""
        return self.v_mps * math.sin(self.slip_rad)
