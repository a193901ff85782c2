"""Particle poses: the column names of an (N, 3) pose array and angle wrapping."""

from __future__ import annotations

from enum import IntEnum

import numpy as np


class PoseIndex(IntEnum):
    """Columns of an (N, 3) particle array: rear-axle x [m], y [m], yaw [rad], map frame."""

    X = 0
    Y = 1
    YAW = 2


def wrap(angle_rad: np.ndarray | float) -> np.ndarray:
    """Angles [rad] wrapped into [-pi, pi)."""
    return (np.asarray(angle_rad) + np.pi) % (2.0 * np.pi) - np.pi
