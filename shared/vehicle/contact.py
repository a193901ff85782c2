"""Car-to-car contact from footprints (issue #24): overlap, depth, normal, incidents (no I/O).

A car's footprint is the rectangle ``length_m x width_m`` centred on its position, its long
axis along the yaw (``[vehicle] length_m`` / ``width_m``, default ``shared.car.CAR``). Poses
are ``[x m, y m, yaw rad]`` in the map frame.

Overlap test (separating axis theorem): two convex rectangles are apart if and only if their
projections are disjoint on one of the four face normals (two per box). On axis ``u`` the
projections overlap by ``o(u) = h_a(u) + h_b(u) - |(c_b - c_a) . u|`` with ``h(u)`` a box's
half extent on ``u``; the boxes overlap when ``min_u o(u) > 0``. That minimum is the
penetration depth [m] (the shortest push along a face normal that separates them) and its
axis, signed to point from car a to car b, the contact normal. When they are apart,
``-min_u o(u)`` (the *gap*) is the largest face-normal separation: exact when the closest
features are face to face (side by side, nose to tail), otherwise a lower bound on the true
distance (corner to corner).

Who hit whom (the striker of an episode, decided when it starts):

1. the car whose front is in the other's body: a car is the striker when one of its two front
   corners lies inside (or on) the other's footprint and none of the other's front corners
   lies inside its own;
2. otherwise (side by side, both noses in, corners outside): the car that closes faster along
   the contact normal, ``v_a . n`` against ``-v_b . n`` (the faster one from behind in a
   rear-end; the one steering in on a side swipe); within ``tie_mps`` neither (``-1``).

An episode (incident) starts when a pair's depth exceeds ``enter_depth_m`` and ends when its
gap exceeds ``leave_gap_m`` (hysteresis: rubbing along a wall of the other car is one
incident, not one per scan).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from shared.car import CAR

__all__ = [
    "BoxContact",
    "ContactMonitor",
    "Incident",
    "box_contact",
    "footprint_corners",
    "striker",
]


def footprint_corners(
    poses: np.ndarray, length_m: float = CAR.length_m, width_m: float = CAR.width_m
) -> np.ndarray:
    """Corners [m] of the footprints of `poses` ((N, 3) or (3,)).

    Returns:
        (N, 4, 2): front-left, front-right, rear-right, rear-left (clockwise).
    """
    p = np.atleast_2d(np.asarray(poses, dtype=float))
    c, s = np.cos(p[:, 2]), np.sin(p[:, 2])
    hl, hw = 0.5 * length_m, 0.5 * width_m
    local = np.array([[hl, hw], [hl, -hw], [-hl, -hw], [-hl, hw]])  # (4, 2)
    x = p[:, None, 0] + c[:, None] * local[:, 0] - s[:, None] * local[:, 1]
    y = p[:, None, 1] + s[:, None] * local[:, 0] + c[:, None] * local[:, 1]
    return np.stack([x, y], axis=-1)


@dataclass(frozen=True)
class BoxContact:
    """Contact of P pairs of footprints (see the module docstring).

    Attributes:
        overlapping: (P,) bool, depth > 0.
        depth_m: (P,) the minimum face-normal overlap [m]; > 0 penetration, <= 0 apart (its
            negative is the gap).
        normal: (P, 2) unit contact normal from car a to car b (the axis of `depth_m`).
    """

    overlapping: np.ndarray
    depth_m: np.ndarray
    normal: np.ndarray

    @property
    def gap_m(self) -> np.ndarray:
        """(P,) face-normal separation [m] (``-depth_m``; <= 0 when overlapping)."""
        return -self.depth_m


def box_contact(
    pose_a: np.ndarray,
    pose_b: np.ndarray,
    length_m: float = CAR.length_m,
    width_m: float = CAR.width_m,
) -> BoxContact:
    """Separating-axis overlap of footprint pairs, vectorised.

    Args:
        pose_a, pose_b: (P, 3) or (3,) poses [x m, y m, yaw rad]; broadcast against each other.
        length_m, width_m: footprint of both cars [m].

    Returns:
        BoxContact over the P pairs. Identical poses: depth = width, normal = car a's left.
    """
    a = np.atleast_2d(np.asarray(pose_a, dtype=float))
    b = np.atleast_2d(np.asarray(pose_b, dtype=float))
    a, b = np.broadcast_arrays(a, b)
    hl, hw = 0.5 * length_m, 0.5 * width_m
    d = b[:, :2] - a[:, :2]  # (P, 2)
    # axes: a's long, a's lateral, b's long, b's lateral -> (P, 4, 2)
    ca, sa, cb, sb = np.cos(a[:, 2]), np.sin(a[:, 2]), np.cos(b[:, 2]), np.sin(b[:, 2])
    axes = np.stack(
        [
            np.stack([ca, sa], -1),
            np.stack([-sa, ca], -1),
            np.stack([cb, sb], -1),
            np.stack([-sb, cb], -1),
        ],
        axis=1,
    )
    a_long, a_lat = axes[:, 0], axes[:, 1]
    b_long, b_lat = axes[:, 2], axes[:, 3]

    def half(long_ax: np.ndarray, lat_ax: np.ndarray) -> np.ndarray:
        """(P, 4) half extent of one box on the four axes."""
        dl = np.abs(np.einsum("pkj,pj->pk", axes, long_ax))
        dw = np.abs(np.einsum("pkj,pj->pk", axes, lat_ax))
        return hl * dl + hw * dw

    proj = np.einsum("pkj,pj->pk", axes, d)  # (P, 4)
    overlap = half(a_long, a_lat) + half(b_long, b_lat) - np.abs(proj)
    k = np.argmin(overlap, axis=1)
    rows = np.arange(a.shape[0])
    depth = overlap[rows, k]
    sign = np.where(proj[rows, k] >= 0.0, 1.0, -1.0)
    normal = axes[rows, k] * sign[:, None]
    return BoxContact(overlapping=depth > 0.0, depth_m=depth, normal=normal)


def _points_in_box(
    points: np.ndarray, pose: np.ndarray, length_m: float, width_m: float, tol_m: float = 1e-9
) -> np.ndarray:
    """(P, M) bool: points (P, M, 2) inside (or on) the footprint of pose (P, 3)."""
    c, s = np.cos(pose[:, 2])[:, None], np.sin(pose[:, 2])[:, None]
    dx = points[..., 0] - pose[:, 0, None]
    dy = points[..., 1] - pose[:, 1, None]
    lon = c * dx + s * dy
    lat = -s * dx + c * dy
    return (np.abs(lon) <= 0.5 * length_m + tol_m) & (np.abs(lat) <= 0.5 * width_m + tol_m)


def striker(
    pose_a: np.ndarray,
    pose_b: np.ndarray,
    vel_a: np.ndarray,
    vel_b: np.ndarray,
    normal: np.ndarray,
    length_m: float = CAR.length_m,
    width_m: float = CAR.width_m,
    tie_mps: float = 0.05,
) -> np.ndarray:
    """(P,) int: 0 when car a hit car b, 1 when b hit a, -1 undecided (module docstring rule).

    Args:
        pose_a, pose_b: (P, 3) poses; vel_a, vel_b: (P, 2) map-frame velocities [m/s];
        normal: (P, 2) contact normal from a to b; tie_mps: closing-speed tie band [m/s].
    """
    pa, pb = np.atleast_2d(pose_a).astype(float), np.atleast_2d(pose_b).astype(float)
    fa = footprint_corners(pa, length_m, width_m)[:, :2]  # front corners of a
    fb = footprint_corners(pb, length_m, width_m)[:, :2]
    a_in = _points_in_box(fa, pb, length_m, width_m).any(axis=1)
    b_in = _points_in_box(fb, pa, length_m, width_m).any(axis=1)
    closing_a = np.einsum("pj,pj->p", np.atleast_2d(vel_a), normal)
    closing_b = -np.einsum("pj,pj->p", np.atleast_2d(vel_b), normal)
    by_speed = np.where(
        closing_a > closing_b + tie_mps, 0, np.where(closing_b > closing_a + tie_mps, 1, -1)
    )
    return np.where(a_in & ~b_in, 0, np.where(b_in & ~a_in, 1, by_speed))


@dataclass(frozen=True)
class Incident:
    """One contact episode as it starts.

    Attributes:
        t_s: time of the first touching update [s].
        car_a, car_b: indices of the pair (car_a < car_b).
        striker: the index of the car that hit the other, or -1 (undecided).
        depth_m: penetration at the start [m].
        normal: (2,) contact normal from car_a to car_b.
    """

    t_s: float
    car_a: int
    car_b: int
    striker: int
    depth_m: float
    normal: tuple[float, float]


@dataclass
class ContactMonitor:
    """Counts car-to-car contacts once per touching episode (hysteresis of the docstring).

    Args:
        n_cars: number of cars (>= 2).
        length_m, width_m: footprint [m].
        enter_depth_m: a pair starts touching above this depth [m] (>= 0).
        leave_gap_m: a touching pair lets go above this gap [m] (>= 0).
        tie_mps: closing-speed tie band of the striker rule [m/s].

    Attributes:
        incidents: every episode so far, in order.
        touching: pairs (a, b) currently in an episode.
    """

    n_cars: int
    length_m: float = CAR.length_m
    width_m: float = CAR.width_m
    enter_depth_m: float = 0.0
    leave_gap_m: float = 0.02
    tie_mps: float = 0.05
    incidents: list[Incident] = field(default_factory=list)
    touching: set[tuple[int, int]] = field(default_factory=set)

    def __post_init__(self) -> None:
        if self.n_cars < 2 or self.enter_depth_m < 0.0 or self.leave_gap_m < 0.0:
            raise ValueError("need n_cars >= 2, enter_depth_m >= 0 and leave_gap_m >= 0")
        ia, ib = np.triu_indices(self.n_cars, k=1)
        self._ia, self._ib = ia, ib

    def count_between(self, a: int, b: int) -> int:
        """Incidents so far between cars a and b (either order)."""
        lo, hi = min(a, b), max(a, b)
        return sum(1 for i in self.incidents if (i.car_a, i.car_b) == (lo, hi))

    def update(self, t_s: float, poses: np.ndarray, velocities: np.ndarray) -> list[Incident]:
        """Advance with every car's pose (N, 3) and map-frame velocity (N, 2) [m/s].

        Returns:
            the incidents that start at this update (already appended to `incidents`).
        """
        p = np.asarray(poses, dtype=float).reshape(self.n_cars, 3)
        v = np.asarray(velocities, dtype=float).reshape(self.n_cars, 2)
        ia, ib = self._ia, self._ib
        con = box_contact(p[ia], p[ib], self.length_m, self.width_m)
        who = striker(
            p[ia], p[ib], v[ia], v[ib], con.normal, self.length_m, self.width_m, self.tie_mps
        )
        new: list[Incident] = []
        for k, (a, b) in enumerate(zip(ia.tolist(), ib.tolist(), strict=True)):
            pair = (a, b)
            depth = float(con.depth_m[k])
            if pair in self.touching:
                if -depth > self.leave_gap_m:
                    self.touching.discard(pair)
            elif depth > self.enter_depth_m:
                self.touching.add(pair)
                s = int(who[k])
                inc = Incident(
                    t_s=float(t_s),
                    car_a=a,
                    car_b=b,
                    striker=-1 if s < 0 else (a, b)[s],
                    depth_m=depth,
                    normal=(float(con.normal[k, 0]), float(con.normal[k, 1])),
                )
                new.append(inc)
        self.incidents.extend(new)
        return new
