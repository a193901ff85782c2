"""The particle filter's motion model: odometry speed and IMU yaw rate at the rear axle.

Every particle ``(x, y, psi)`` (rear axle, map frame) moves over ``dt`` [s] by the measured
speed ``v`` [m/s] (wheel odometry: the longitudinal speed, the same at the rear axle as at the
CoG) and yaw rate ``r`` [rad/s] (IMU), plus white noise: a random walk whose standard
deviations grow with ``sqrt(dt)`` (so the spread does not depend on the call rate)::

    dpsi = r dt + sqrt(dt) (a_yaw + b_yaw |r|) n_1
    ds   = v dt + sqrt(dt) (a_long + b_long |v|) n_2          (along the mid-step heading)
    dl   =        sqrt(dt) (a_lat + b_lat |v|) n_3            (across it: rear-axle slip)
    psi_m = psi + dpsi / 2
    x += ds cos psi_m - dl sin psi_m,   y += ds sin psi_m + dl cos psi_m,   psi += dpsi

(midpoint integration, exact to O(dt^3) for constant v and r).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from services.localization_bridge.poses import PoseIndex
from shared.angles import wrap_angle_shifted


@dataclass(frozen=True)
class MotionNoise:
    """Random-walk intensities (see the module docstring).

    Attributes:
        long_m_rts, lat_m_rts: a_long, a_lat [m/sqrt(s)].
        long_per_speed_rts, lat_per_speed_rts: b_long, b_lat [sqrt(s)].
        yaw_rad_rts: a_yaw [rad/sqrt(s)]; yaw_per_rate_rts: b_yaw [sqrt(s)].
    """

    long_m_rts: float
    long_per_speed_rts: float
    lat_m_rts: float
    lat_per_speed_rts: float
    yaw_rad_rts: float
    yaw_per_rate_rts: float


def propagate(
    poses: np.ndarray,
    dt_s: float,
    speed_mps: float,
    yaw_rate_radps: float,
    noise: MotionNoise,
    rng: np.random.Generator,
) -> None:
    """Move (N, 3) `poses` [x m, y m, yaw rad] in place by one motion step of `dt_s` [s]."""
    n = poses.shape[0]
    rt = math.sqrt(dt_s)
    v, r = float(speed_mps), float(yaw_rate_radps)
    z = rng.standard_normal((3, n))
    dpsi = r * dt_s + rt * (noise.yaw_rad_rts + noise.yaw_per_rate_rts * abs(r)) * z[0]
    ds = v * dt_s + rt * (noise.long_m_rts + noise.long_per_speed_rts * abs(v)) * z[1]
    dl = rt * (noise.lat_m_rts + noise.lat_per_speed_rts * abs(v)) * z[2]
    yaw = poses[:, PoseIndex.YAW]
    mid = yaw + 0.5 * dpsi
    c, s = np.cos(mid), np.sin(mid)
    poses[:, PoseIndex.X] += ds * c - dl * s
    poses[:, PoseIndex.Y] += ds * s + dl * c
    poses[:, PoseIndex.YAW] = wrap_angle_shifted(yaw + dpsi)
