"""Particle poses: the column names of an (N, 3) pose array (angles are wrapped with
``shared.angles.wrap_angle_shifted``)."""

from __future__ import annotations

from enum import IntEnum


class PoseIndex(IntEnum):
    """Columns of an (N, 3) particle array: rear-axle x [m], y [m], yaw [rad], map frame."""

    X = 0
    Y = 1
    YAW = 2
