"""Car-to-car contact response of the simulator (issue #24): maths only, no I/O.

Two cars of equal mass whose footprints overlap (``shared.vehicle.contact.box_contact``:
depth ``d`` > 0 and unit normal ``n`` from car a to car b) are

1. separated: each moves ``d / 2 + SEPARATION_SLACK_M / 2`` along the normal, away from the
   other, so no interpenetration is left after the response;
2. given an impulse along the normal when they approach there (relative normal velocity
   ``w = (v_b - v_a) . n < 0``): with restitution ``e`` the normal velocities after the
   impact are ``v_a.n + j``, ``v_b.n - j`` with ``j = (1 + e) w / 2`` (momentum along the
   normal is conserved, the relative normal velocity turns into ``-e w``); the tangential
   velocities are kept (no friction between the bodies);
3. slowed: both velocities then lose ``speed_loss`` of their magnitude (tyres scrubbed,
   bodywork), so a contact always costs time: it is never a free pass.

Velocities are those of the centre of gravity in the map frame, ``v (cos(psi + beta),
sin(psi + beta))``; the heading ``psi`` stays, the new velocity is written back as the
speed ``v`` and the slip angle ``beta`` of the single-track state (canonical: ``|beta| <=
pi/2``, a car pushed backwards gets ``v < 0``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from shared.car import CAR
from shared.vehicle.contact import box_contact

__all__ = ["SEPARATION_SLACK_M", "ContactParams", "Motion", "respond"]

#: Extra gap left between two cars after their separation [m].
SEPARATION_SLACK_M = 1e-3


@dataclass(frozen=True)
class ContactParams:
    """The response's settings.

    Attributes:
        restitution: e in [0, 1] (0: plastic, the normal velocities become equal).
        speed_loss: fraction of each car's speed lost at an impact, in [0, 1).
        length_m, width_m: the footprint [m].
    """

    restitution: float = 0.3
    speed_loss: float = 0.2
    length_m: float = CAR.length_m
    width_m: float = CAR.width_m


@dataclass(frozen=True)
class Motion:
    """A car's planar motion: CoG x, y [m], yaw psi [rad], speed v [m/s], slip beta [rad]."""

    x_m: float
    y_m: float
    yaw_rad: float
    speed_mps: float
    slip_rad: float

    @property
    def velocity(self) -> np.ndarray:
        """(2,) map-frame CoG velocity [m/s]."""
        c = self.yaw_rad + self.slip_rad
        return np.array([self.speed_mps * math.cos(c), self.speed_mps * math.sin(c)])

    def with_velocity(self, x_m: float, y_m: float, vel: np.ndarray) -> Motion:
        """This car moved to (x, y) [m] with map-frame velocity `vel` (2,) [m/s], heading
        kept: speed and canonical slip from the velocity in the body frame."""
        c, s = math.cos(self.yaw_rad), math.sin(self.yaw_rad)
        v_long = c * vel[0] + s * vel[1]
        v_lat = -s * vel[0] + c * vel[1]
        speed = math.hypot(v_long, v_lat)
        if speed < 1e-9:
            return Motion(x_m, y_m, self.yaw_rad, 0.0, 0.0)
        beta = math.atan2(v_lat, v_long)
        if beta > 0.5 * math.pi:  # moving backwards: v < 0 and the slip mirrored
            beta, speed = beta - math.pi, -speed
        elif beta < -0.5 * math.pi:
            beta, speed = beta + math.pi, -speed
        return Motion(x_m, y_m, self.yaw_rad, speed, beta)


def respond(
    a: Motion, b: Motion, params: ContactParams = ContactParams()
) -> tuple[Motion, Motion, bool] | None:
    """The two cars after their contact (module docstring), or None when they do not touch.

    Returns:
        (car a, car b, impact): `impact` is True when they approached along the normal
        (impulse and speed loss applied), False when they only overlapped (separated).
    """
    con = box_contact(
        np.array([a.x_m, a.y_m, a.yaw_rad]), np.array([b.x_m, b.y_m, b.yaw_rad]),
        params.length_m, params.width_m,
    )
    depth = float(con.depth_m[0])
    if depth <= 0.0:
        return None
    n = con.normal[0]
    push = 0.5 * (depth + SEPARATION_SLACK_M)
    va, vb = a.velocity, b.velocity
    w = float((vb - va) @ n)
    impact = w < 0.0
    if impact:
        j = 0.5 * (1.0 + params.restitution) * w
        va = va + j * n
        vb = vb - j * n
        keep = 1.0 - params.speed_loss
        va, vb = keep * va, keep * vb
    return (
        a.with_velocity(a.x_m - push * n[0], a.y_m - push * n[1], va),
        b.with_velocity(b.x_m + push * n[0], b.y_m + push * n[1], vb),
        impact,
    )
