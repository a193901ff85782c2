"""Opponent cars from a lidar scan (issue #24): detection and tracking, maths only (no I/O).

Detection, per scan (``OpponentDetector.detect``), with the sensor pose known in the map frame:

1. beam end points the map does not explain: a return inside range whose end point is more
   than ``unexplained_m`` from the nearest wall surface of the map (the same free / blocked
   border distance as the particle filter's likelihood field, ``wall_distance_m``) and lies
   on a free cell (inside the track; points behind walls are map noise, not cars). Within
   ``tracked_radius_m`` of a car already tracked (``detect``'s `tracked_xy`: the tracker's
   confirmed tracks predicted to the scan) the distance is ``tracked_unexplained_m`` (at
   least one map cell) instead: a car on the racing line runs its side within centimetres
   of the wall at every apex, and with the wall's 15 cm taken off, the piece of its rear
   left is too small to be a car (the track died and the car behind, seeing nobody, drove
   into it: the lidar-view contacts of the bench); so the track keeps it, and a car first
   seen against a wall is found when it leaves it;
2. clustered in beam order: consecutive unexplained beams are one cluster while the beam
   index step is at most ``max_beam_gap`` and the end points are within ``cluster_gap_m``;
3. fitted with a car-sized box: the heading of the cluster's rectangle by the search-based
   L-shape fit (angles over 90 deg, the closeness criterion: points near the two nearest
   edges score high), the edges as robust extremes (the median of the projections within
   ``edge_band_m`` of each extreme); the car's footprint (``length_m`` along the axis the
   points span longer than the width, else the one nearer the track's direction there when
   the detector has the track, else the one nearer the line of sight: a car seen from
   behind shows its width) is then placed per axis against the edge facing the sensor
   when the sensor lies outside the cluster's span on that axis (only that face is seen),
   else centred on the span (both ends seen), except that an edge made by an occluder (the
   neighbouring beam returns nearer) is never an anchor: the opposite edge is;
4. clusters that do not look like a car are rejected: fewer than ``min_points`` points, a span
   longer than the car's diagonal plus ``size_tol_m`` or a side longer than the car's length
   plus ``size_tol_m``, or spans smaller than ``min_extent_m`` on both axes.

Tracking (``OpponentTracker``): a constant-velocity Kalman filter per track, state
``[x, y, vx, vy]`` (map frame, m and m/s), white-acceleration process noise
(``accel_std_mps2``), position measurements with ``meas_std_m``; association by gated
(chi-square 2-dof ``gate_chi2``) Mahalanobis distance, nearest pairs first; a detection's
box heading adds the pseudo-measurement "no velocity across the car" (``update``); a detection
without a track starts a tentative one (confirmed after ``confirm_hits`` hits); a track is
dropped after ``max_misses`` scans in a row without a detection (coasting through occlusion
keeps its id). Two cars cannot overlap: a detection left over by the gated association
whose centre lies within ``merge_m`` (a car's width) of a track's is that car, not a new one
(it corrects that track when the track had no detection this scan, and is dropped as a
duplicate when it had: one car's points split into two clusters), and of two tracks that
come within ``merge_m`` of each other the younger is dropped (the older id is kept). (Seen
from the side within 0.5 m, the box fit drifts 0.1-0.2 m and the gate, a few centimetres at
this noise, let a second track be born beside the first: the id switches of an overtake.)

What the scan could not see is not a miss (``ScanView``): a confirmed track whose predicted
centre lies outside the lidar's fan (behind the car: 270 deg sensors see nothing in the rear
90 deg), beyond ``max_range_m``, or behind a nearer return on its beam (occluded by a wall or
another car, by more than half a car length) coasts without counting misses, for at most
``max_coast_s`` since its last detection; seen again within the gate it keeps its id. (Before,
a car the ego had just passed left the field of view, its track died after 8 scans and was
born again, unconfirmed for 3 scans, as the ego merged back in front of it.)
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import numpy as np

from services.localization_bridge.likelihood_field import wall_distance_m
from shared.car import CAR
from shared.track import Track
from shared.track.occupancy import OccupancyGrid
from shared.track.raycast import blocked_cells, to_grid_frame

__all__ = [
    "Detection",
    "DetectorParams",
    "OpponentDetector",
    "OpponentTrack",
    "OpponentTracker",
    "ScanView",
    "TrackerParams",
    "fit_car_box",
]


@dataclass(frozen=True)
class DetectorParams:
    """Settings of the detector (module docstring; lengths [m])."""

    length_m: float = CAR.length_m
    width_m: float = CAR.width_m
    unexplained_m: float = 0.15
    tracked_unexplained_m: float = 0.05
    tracked_radius_m: float = 0.5
    cluster_gap_m: float = 0.15
    max_beam_gap: int = 3
    min_points: int = 4
    min_extent_m: float = 0.08
    size_tol_m: float = 0.10
    edge_band_m: float = 0.04
    angle_step_deg: float = 1.0
    distance_cap_m: float = 1.0


@dataclass(frozen=True)
class Detection:
    """One car-sized cluster.

    Attributes:
        x_m, y_m: centre of the fitted footprint (map frame) [m].
        yaw_rad: heading of its long axis [rad], modulo pi (the scan cannot tell front from
            back).
        n_points: beams in the cluster.
        range_m: range from the sensor to the cluster's nearest point [m].
        points: (n, 2) the cluster's end points (map frame) [m].
    """

    x_m: float
    y_m: float
    yaw_rad: float
    n_points: int
    range_m: float
    points: np.ndarray = field(repr=False)


def _robust_edges(u: np.ndarray, band_m: float) -> tuple[float, float]:
    """Low and high edge [m] of projections `u` (n,): the median within `band_m` of each
    extreme (range noise pushes the bare extremes outwards)."""
    lo, hi = float(u.min()), float(u.max())
    return float(np.median(u[u <= lo + band_m])), float(np.median(u[u >= hi - band_m]))


def fit_car_box(
    points: np.ndarray,
    sensor_xy: tuple[float, float],
    params: DetectorParams = DetectorParams(),
    heading_hint_rad: float | None = None,
    occluded_ends: tuple[bool, bool] = (False, False),
) -> tuple[float, float, float] | None:
    """The car footprint fitted to one cluster (steps 3-4 of the module docstring).

    Args:
        points: (n, 2) end points [m] (map frame), n >= 2.
        sensor_xy: the sensor's position [m].
        params: footprint and tolerances.
        heading_hint_rad: the likely heading of the car [rad] (the track's direction there);
            when the points span no more than a width, the long axis is the one nearer it
            (without a hint: the one nearer the line of sight).
        occluded_ends: whether the first / last point (in beam order) is cut off by something
            nearer the sensor (the car goes on behind it): on an axis where exactly one edge
            is such a cut end, the footprint is anchored on the other edge (the axis of a
            cut end is the one its last ``CUT_RUN_M`` of points run along towards it).

    Returns:
        (x m, y m, yaw rad) of the footprint's centre and long axis, or None when the cluster
        is not car-sized.
    """
    p = np.asarray(points, dtype=float)
    if p.shape[0] < max(2, params.min_points):
        return None
    centre = p.mean(axis=0)
    q = p - centre
    th = np.deg2rad(np.arange(0.0, 90.0, params.angle_step_deg))
    e1 = np.stack([np.cos(th), np.sin(th)], -1)  # (A, 2)
    c1 = q @ e1.T  # (n, A)
    c2 = q @ np.stack([-e1[:, 1], e1[:, 0]], -1).T
    d1 = np.minimum(c1 - c1.min(0), c1.max(0) - c1)
    d2 = np.minimum(c2 - c2.min(0), c2.max(0) - c2)
    score = (1.0 / np.maximum(np.minimum(d1, d2), 0.01)).sum(axis=0)
    k = int(np.argmax(score))
    ax = np.array([e1[k], [-e1[k, 1], e1[k, 0]]])  # (2, 2) rows: the two axes
    proj = q @ ax.T  # (n, 2)
    edges = [_robust_edges(proj[:, i], params.edge_band_m) for i in range(2)]
    span = np.array([hi - lo for lo, hi in edges])
    length, width, tol = params.length_m, params.width_m, params.size_tol_m
    if span.max() > length + tol or math.hypot(*span) > math.hypot(length, width) + tol:
        return None
    if span.max() < params.min_extent_m:
        return None
    s = (np.asarray(sensor_xy, dtype=float) - centre) @ ax.T  # sensor on the two axes
    if span.max() > width + tol:
        long_i = int(np.argmax(span))
    elif heading_hint_rad is not None:  # a width's worth seen: the axis nearer the hint
        h = np.array([math.cos(heading_hint_rad), math.sin(heading_hint_rad)])
        long_i = int(np.argmax(np.abs(ax @ h)))
    else:  # ... or the one nearer the line of sight
        long_i = int(np.argmax(np.abs(s)))
    sizes = (length, width) if long_i == 0 else (width, length)
    mid = np.zeros(2)
    # a cut end continues the scan's run along the face it lies on: that axis, that way
    # (the principal direction of the points within ``CUT_RUN_M`` of the end: at close range
    # the last few beams lie millimetres apart and their run is the range noise's, which
    # flipped the box to the sensor's side of a car seen from beside; a window in beam order
    # reached round the corner of a short cluster instead)
    run = np.array([_end_run(p), _end_run(p[::-1])]) @ ax.T  # (2 ends, 2 axes)
    cut_axis = np.argmax(np.abs(run), axis=1)
    cut_sign = run[np.arange(2), cut_axis]
    for i in range(2):
        lo, hi = edges[i]
        cut_lo = cut_hi = False
        for j, cut in enumerate(occluded_ends):
            if cut and cut_axis[j] == i:
                cut_lo |= cut_sign[j] < 0.0
                cut_hi |= cut_sign[j] > 0.0
        at_lo, at_hi = lo + 0.5 * sizes[i], hi - 0.5 * sizes[i]
        if cut_lo != cut_hi:  # one end hidden behind an occluder: the other one is real
            mid[i] = at_hi if cut_lo else at_lo
        elif s[i] < lo:  # the sensor faces the low edge
            mid[i] = at_lo
        elif s[i] > hi:
            mid[i] = at_hi
        else:  # both ends of this axis are seen
            mid[i] = 0.5 * (lo + hi)
    xy = centre + mid @ ax
    yaw = float(math.atan2(ax[long_i, 1], ax[long_i, 0]))
    return float(xy[0]), float(xy[1]), yaw


#: Deeper than this inside a wall of the map no car's centre can be (``free_at``) [m].
WALL_DEPTH_M = 0.1
#: The run of a cluster's end is taken over its last points within this distance [m].
CUT_RUN_M = 0.08


def _end_run(p: np.ndarray) -> np.ndarray:
    """(2,) [m]: the run of the points `p` (n, 2) into their end ``p[0]``, along the face
    it lies on: the principal direction of the points within ``CUT_RUN_M`` of it, pointing
    to it (fewer than three there: from the third point on to the end)."""
    end = p[0]
    near = p[np.hypot(*(p - end).T) <= CUT_RUN_M]
    if near.shape[0] < 3:
        return end - p[min(3, p.shape[0] - 1)]
    mean = near.mean(axis=0)
    _, vecs = np.linalg.eigh(np.cov((near - mean).T))
    u = vecs[:, -1]
    return u * float((end - mean) @ u)


class OpponentDetector:
    """Car-sized clusters of the beams the map does not explain (module docstring).

    Args:
        grid: the map (the one the particle filter uses).
        params: the detector's settings.
        unknown_is_occupied: UNKNOWN cells count as walls.
        track: optional; its direction at a cluster is the heading hint of ``fit_car_box``.
    """

    def __init__(
        self,
        grid: OccupancyGrid,
        params: DetectorParams = DetectorParams(),
        unknown_is_occupied: bool = True,
        track: Track | None = None,
    ) -> None:
        self.grid = grid
        self.track = track
        self.params = params
        blocked = blocked_cells(grid, unknown_is_occupied)
        self._blocked = blocked
        self._dist = wall_distance_m(blocked, float(grid.resolution_m), params.distance_cap_m)
        self._rows, self._cols = blocked.shape

    def unexplained(
        self, xy: np.ndarray, tracked_xy: Sequence[tuple[float, float]] = ()
    ) -> np.ndarray:
        """(n,) bool: points (n, 2) [m] on free cells farther than ``unexplained_m`` from
        every wall (outside the map: False); within ``tracked_radius_m`` of a centre of
        `tracked_xy` (m, m) farther than ``tracked_unexplained_m`` (at least one cell)."""
        gx, gy = to_grid_frame(self.grid, xy[:, 0], xy[:, 1])
        r = float(self.grid.resolution_m)
        col = np.floor(gx / r).astype(np.int64)
        row = np.floor(gy / r).astype(np.int64)
        inside = (col >= 0) & (col < self._cols) & (row >= 0) & (row < self._rows)
        p = self.params
        need = np.full(xy.shape[0], p.unexplained_m)
        if len(tracked_xy):
            c = np.asarray(tracked_xy, dtype=float).reshape(-1, 2)
            d2 = ((xy[:, None, :] - c[None, :, :]) ** 2).sum(axis=2).min(axis=1)
            low = min(p.unexplained_m, max(p.tracked_unexplained_m, r))
            need = np.where(d2 <= p.tracked_radius_m**2, low, need)
        out = np.zeros(xy.shape[0], dtype=bool)
        ri, ci = row[inside], col[inside]
        out[inside] = ~self._blocked[ri, ci] & (self._dist[ri, ci] > need[inside])
        return out

    def free_at(self, x_m: float, y_m: float) -> bool:
        """Whether a car's centre can be at (`x_m`, `y_m`) [m]: with the track, no more than
        half a car's width beyond its boundaries (a car that left the track is still a
        car); without it, not deeper than ``WALL_DEPTH_M`` inside a wall of the map, nor off
        the map (a real map's stray occupied pixels inside the track are no wall: a car's
        track there was dropped)."""
        if self.track is not None:
            inside = self.track.is_inside(np.array([x_m, y_m]), -0.5 * self.params.width_m)
            return bool(np.ravel(inside)[0])
        gx, gy = to_grid_frame(self.grid, np.array([x_m]), np.array([y_m]))
        r = float(self.grid.resolution_m)
        col, row = int(np.floor(gx[0] / r)), int(np.floor(gy[0] / r))
        if not (0 <= col < self._cols and 0 <= row < self._rows):
            return False
        return not (bool(self._blocked[row, col]) and self._dist[row, col] > WALL_DEPTH_M)

    def detect(
        self,
        ranges_m: np.ndarray,
        angle_min_rad: float,
        angle_increment_rad: float,
        range_max_m: float,
        sensor_pose: tuple[float, float, float],
        tracked_xy: Sequence[tuple[float, float]] = (),
    ) -> list[Detection]:
        """Opponents in one scan.

        Args:
            ranges_m: (K,) ranges [m], beams counter-clockwise from `angle_min_rad` [rad] by
                `angle_increment_rad` [rad]; returns at or beyond `range_max_m` (and
                non-finite or non-positive ones) are no returns.
            sensor_pose: (x m, y m, yaw rad) of the sensor in the map frame.
            tracked_xy: centres [m] of the cars tracked so far, predicted to this scan
                (``OpponentTracker.predicted_centres``): near them a point need only be
                ``tracked_unexplained_m`` from a wall (module docstring, step 1).

        Returns:
            the detections, in beam order.
        """
        r = np.asarray(ranges_m, dtype=float).ravel()
        x0, y0, yaw0 = (float(v) for v in sensor_pose)
        valid = np.isfinite(r) & (r > 0.0) & (r < float(range_max_m))
        idx = np.flatnonzero(valid)
        if idx.size == 0:
            return []
        ang = yaw0 + angle_min_rad + angle_increment_rad * idx
        xy = np.column_stack([x0 + r[idx] * np.cos(ang), y0 + r[idx] * np.sin(ang)])
        keep = self.unexplained(xy, tracked_xy)
        idx, xy = idx[keep], xy[keep]
        if idx.size == 0:
            return []
        p = self.params
        step = np.hypot(*np.diff(xy, axis=0).T)
        breaks = (np.diff(idx) > p.max_beam_gap) | (step > p.cluster_gap_m)
        starts = np.concatenate([[0], np.flatnonzero(breaks) + 1, [idx.size]])
        out: list[Detection] = []
        for a, b in itertools.pairwise(starts.tolist()):
            pts = xy[a:b]
            hint = None
            if self.track is not None and pts.shape[0] >= p.min_points:
                s_here, _ = self.track.project(pts.mean(axis=0))
                hint = float(self.track.heading_at(float(s_here)))
            cut = (
                self._cut(r, idx[a], idx[a] - 1, valid),
                self._cut(r, idx[b - 1], idx[b - 1] + 1, valid),
            )
            box = fit_car_box(pts, (x0, y0), p, hint, cut)
            if box is None:
                continue
            out.append(
                Detection(
                    x_m=box[0],
                    y_m=box[1],
                    yaw_rad=box[2],
                    n_points=int(b - a),
                    range_m=float(r[idx[a:b]].min()),
                    points=pts,
                )
            )
        return out

    def _cut(self, r: np.ndarray, end: int, beside: int, valid: np.ndarray) -> bool:
        """Whether a cluster's end beam `end` is not the car's end: the beam `beside` it
        returns nearer, ``cluster_gap_m`` or more in front (an occluder), or there is no
        beam beside it: the scan's fan ends there and the car may go on beyond it (beside
        and behind the sensor, the rear of a car just passed is out of the fan) [beam
        indices]."""
        if beside < 0 or beside >= r.size:
            return True
        if not valid[beside]:
            return False
        return bool(r[beside] < r[end] - self.params.cluster_gap_m)


@dataclass(frozen=True)
class ScanView:
    """What one scan could see (module docstring): the sensor's pose and the scan's beams.

    Args:
        ranges_m: (K,) ranges [m] (non-finite, non-positive or at or beyond `range_max_m`:
            no return); angle_min_rad, angle_increment_rad: the beams [rad];
        range_max_m: the farthest return that counts [m];
        sensor_pose: (x m, y m, yaw rad) of the sensor in the map frame;
        occlusion_m: a point is hidden when its beam returns nearer than its distance less
            this [m] (default: half an F1TENTH car's length).
    """

    ranges_m: np.ndarray
    angle_min_rad: float
    angle_increment_rad: float
    range_max_m: float
    sensor_pose: tuple[float, float, float]
    occlusion_m: float = 0.5 * CAR.length_m

    def sees(self, x_m: float, y_m: float) -> bool:
        """Whether a car centred at (`x_m`, `y_m`) [m] was in view: inside the fan and the
        range and not behind a nearer return on the beam towards it."""
        x0, y0, yaw0 = self.sensor_pose
        d = math.hypot(x_m - x0, y_m - y0)
        if not d < self.range_max_m:
            return False
        r = np.asarray(self.ranges_m, dtype=float).ravel()
        bearing = math.remainder(math.atan2(y_m - y0, x_m - x0) - yaw0, 2.0 * math.pi)
        k = round((bearing - self.angle_min_rad) / self.angle_increment_rad)
        if k < 0 or k >= r.size:  # wrap: a fan that ends past +pi starts below -pi
            k = round((bearing + 2.0 * math.pi - self.angle_min_rad) / self.angle_increment_rad)
            if k < 0 or k >= r.size:
                return False
        hit = float(r[k])
        if math.isfinite(hit) and 0.0 < hit < self.range_max_m:
            return hit >= d - self.occlusion_m
        return True  # no return on that beam: nothing nearer hid it


@dataclass(frozen=True)
class TrackerParams:
    """Settings of the tracker (module docstring); ``max_coast_s`` [s]: the longest a
    confirmed track the scans cannot see coasts since its last detection; ``merge_m`` [m]:
    closer than this, a detection and a track, or two tracks, are one car;
    ``tentative_max_misses``: a track not yet confirmed is dropped after more scans than
    this in a row without a detection (its gate grows with every miss, and a stale one
    took a misfit box 0.25 m off for its third hit); ``confirm_speed_std_mps`` [m/s]: a
    track is confirmed only once its speed is known this well too (the largest standard
    deviation of its velocity), not on its hits alone; ``yaw_gate_rad`` [rad],
    ``yaw_gate_speed_mps`` [m/s]: a box's axis whose direction is off a confirmed track's
    motion by more than this (once it moves faster than the speed) is not used
    (``_correct``)."""

    accel_std_mps2: float = 8.0
    meas_std_m: float = 0.02
    init_speed_std_mps: float = 3.0
    gate_chi2: float = 13.8
    lateral_speed_std_mps: float = 0.15
    confirm_hits: int = 3
    tentative_max_misses: int = 2
    confirm_speed_std_mps: float = 1.0
    yaw_gate_rad: float = 0.5
    yaw_gate_speed_mps: float = 1.0
    max_misses: int = 8
    max_coast_s: float = 1.0
    merge_m: float = CAR.width_m


@dataclass
class OpponentTrack:
    """One tracked opponent.

    Attributes:
        track_id: kept for the track's life (1, 2, ... in birth order).
        x: (4,) state [x m, y m, vx m/s, vy m/s] (map frame).
        P: (4, 4) its covariance.
        t_s: time of the state [s].
        hits: detections associated so far; misses: scans in a row without one that
            could have seen it.
        seen_t_s: time of its last detection [s].
    """

    track_id: int
    x: np.ndarray
    P: np.ndarray
    t_s: float
    hits: int = 1
    misses: int = 0
    confirmed: bool = False
    seen_t_s: float = -math.inf

    @property
    def position(self) -> tuple[float, float]:
        """(x, y) [m]."""
        return float(self.x[0]), float(self.x[1])

    @property
    def velocity(self) -> tuple[float, float]:
        """(vx, vy) [m/s]."""
        return float(self.x[2]), float(self.x[3])


class OpponentTracker:
    """Constant-velocity Kalman tracks of detections (module docstring).

    Args:
        params: the tracker's settings.
    """

    def __init__(self, params: TrackerParams = TrackerParams()) -> None:
        self.params = params
        self.tracks: list[OpponentTrack] = []
        #: detections refused so far (a non-finite value or fewer than two).
        self.dropped = 0
        #: detections dropped as a second cluster of a car already detected this scan, and
        #: tracks dropped as a younger duplicate of an older one (``merge_m``).
        self.duplicates = 0
        self.merged = 0
        #: tracks dropped for a centre inside a wall or off the map (``update``'s `free`).
        self.walled = 0
        self._next_id = 1
        self._H = np.array([[1.0, 0.0, 0.0, 0.0], [0.0, 1.0, 0.0, 0.0]])
        self._R = np.eye(2) * params.meas_std_m**2

    def _predict(self, tr: OpponentTrack, t_s: float) -> None:
        dt = max(0.0, t_s - tr.t_s)
        F = np.eye(4)
        F[0, 2] = F[1, 3] = dt
        q = self.params.accel_std_mps2**2
        g = np.array([0.5 * dt * dt, dt])
        Q1 = q * np.outer(g, g)  # (2, 2) per axis: [pos, vel]
        Q = np.zeros((4, 4))
        Q[np.ix_([0, 2], [0, 2])] = Q1
        Q[np.ix_([1, 3], [1, 3])] = Q1
        tr.x = F @ tr.x
        tr.P = F @ tr.P @ F.T + Q
        tr.t_s = t_s

    def predicted_centres(self, t_s: float) -> list[tuple[float, float]]:
        """Centres [m] of the tracks, tentative ones too, predicted to `t_s` [s] at their
        velocity (the tracks are not changed): the `tracked_xy` of
        ``OpponentDetector.detect``. A tentative track counts: a car seen from behind along
        a wall is a short cluster once its wall side is cut at 15 cm; with the confirmed
        ones alone its track was born and died for 2 s behind it, unconfirmed, and the
        follower ran into it (Oschersleben seed 607, ``--source lidar``)."""
        out = []
        for tr in self.tracks:
            dt = max(0.0, t_s - tr.t_s)
            out.append((float(tr.x[0] + tr.x[2] * dt), float(tr.x[1] + tr.x[3] * dt)))
        return out

    def update(
        self,
        t_s: float,
        detections: list[tuple[float, ...]],
        view: ScanView | None = None,
        free: Callable[[float, float], bool] | None = None,
    ) -> list[OpponentTrack]:
        """Advance every track to `t_s` [s] and take this scan's detections.

        Args:
            t_s: the scan's time [s].
            detections: (x m, y m) or (x m, y m, yaw rad) each; with a yaw (the box's long
                axis, modulo pi) the velocity across it is also measured as 0 with
                ``lateral_speed_std_mps`` (a car moves along its axis: the pseudo-measurement
                that keeps the constant-velocity model from lagging through bends).
                Detections with a non-finite value are dropped and counted (``dropped``).
            view: what the scan could see (None: everything): a confirmed track it could
                not see counts no miss, for at most ``max_coast_s`` since its detection.
            free: whether a car's centre can be at a point [m] (``OpponentDetector.free_at``:
                on the track or within half a car of it; None: anywhere): a track whose centre
                cannot is dropped (counted in ``walled``). A track coasting through a bend
                at constant velocity drifted out through the outer wall, hidden "behind" it
                and so kept, and the car behind planned round a car 0.5-1.4 m off the track.

        Returns:
            the confirmed tracks after the update.
        """
        p = self.params
        for tr in self.tracks:
            self._predict(tr, t_s)
        rows = [tuple(float(v) for v in d) for d in detections]
        rows = [r for r in rows if len(r) >= 2 and all(math.isfinite(v) for v in r)]
        self.dropped += len(detections) - len(rows)
        z = np.array([r[:2] for r in rows], dtype=float).reshape(-1, 2)
        yaws = [r[2] if len(r) > 2 else None for r in rows]
        n_t, n_d = len(self.tracks), z.shape[0]
        cost = np.full((n_t, n_d), np.inf)
        for i, tr in enumerate(self.tracks):
            S = self._H @ tr.P @ self._H.T + self._R
            Si = np.linalg.inv(S)
            nu = z - tr.x[:2]
            m2 = np.einsum("nj,jk,nk->n", nu, Si, nu)
            cost[i] = np.where(m2 <= p.gate_chi2, m2, np.inf)
        used_t, used_d = set(), set()
        order = np.argsort(cost, axis=None)
        for flat in order:
            i, j = divmod(int(flat), max(n_d, 1))
            if not np.isfinite(cost[i, j]):
                break
            if i in used_t or j in used_d:
                continue
            used_t.add(i)
            used_d.add(j)
            self._correct(self.tracks[i], z[j], yaws[j])
        for j in range(n_d):  # left over: within a car's width of a track, that car
            if j in used_d or not self.tracks:
                continue
            gaps = [math.hypot(z[j, 0] - tr.x[0], z[j, 1] - tr.x[1]) for tr in self.tracks]
            i = int(np.argmin(gaps))
            if gaps[i] >= p.merge_m:
                continue
            used_d.add(j)
            if i in used_t:
                self.duplicates += 1
            else:
                used_t.add(i)
                self._correct(self.tracks[i], z[j], yaws[j])
        kept = []
        for i, tr in enumerate(self.tracks):
            if i not in used_t:
                hidden = tr.confirmed and view is not None and not view.sees(*tr.position)
                if hidden and t_s - tr.seen_t_s > p.max_coast_s:
                    continue  # coasted out of sight for too long
                if not hidden:
                    tr.misses += 1
            limit = p.max_misses if tr.confirmed else min(p.max_misses, p.tentative_max_misses)
            if free is not None and not free(*tr.position):
                self.walled += 1
                continue
            if tr.misses <= limit:
                kept.append(tr)
        self.tracks = self._coalesce(kept)
        for j in range(n_d):
            if j not in used_d:
                P0 = np.diag([p.meas_std_m**2] * 2 + [p.init_speed_std_mps**2] * 2)
                x0 = np.array([z[j, 0], z[j, 1], 0.0, 0.0])
                self.tracks.append(OpponentTrack(self._next_id, x0, P0, float(t_s),
                                                 seen_t_s=float(t_s)))
                self._next_id += 1
        for tr in self.tracks:
            tr.confirmed = tr.confirmed or (
                tr.hits >= p.confirm_hits
                and float(np.linalg.eigvalsh(tr.P[2:, 2:])[-1]) <= p.confirm_speed_std_mps**2)
        return [tr for tr in self.tracks if tr.confirmed]

    def _coalesce(self, tracks: list[OpponentTrack]) -> list[OpponentTrack]:
        """`tracks` without the younger of any two within ``merge_m`` (counted in
        ``merged``); the older keeps its id (tracks are in birth order)."""
        out: list[OpponentTrack] = []
        for tr in tracks:
            if any(math.hypot(tr.x[0] - o.x[0], tr.x[1] - o.x[1]) < self.params.merge_m
                   for o in out):
                self.merged += 1
                if tr.confirmed:  # the older one stands for it now
                    for o in out:
                        if math.hypot(tr.x[0] - o.x[0], tr.x[1] - o.x[1]) < self.params.merge_m:
                            o.confirmed = True
                            break
                continue
            out.append(tr)
        return out

    def _correct(self, tr: OpponentTrack, z: np.ndarray, yaw: float | None = None) -> None:
        """Kalman correction by position `z` (2,) [m] and, with `yaw` [rad], the zero
        velocity across the car's axis (Joseph form). The axis is used only where it agrees
        with the track's motion (within ``yaw_gate_rad``, modulo pi, once the track moves
        faster than ``yaw_gate_speed_mps``): a box fitted the wrong way round (a car seen
        from behind at 1 m, a corner split off) turned a confirmed track's velocity by 90
        degrees, and the car behind braked for a car crossing its path."""
        H, R = self._H, self._R
        p = self.params
        vx, vy = float(tr.x[2]), float(tr.x[3])
        if yaw is not None and tr.confirmed and math.hypot(vx, vy) > p.yaw_gate_speed_mps:
            off = abs(math.remainder(yaw - math.atan2(vy, vx), math.pi))
            if off > p.yaw_gate_rad:
                yaw = None
        if yaw is not None:
            lat = np.array([[0.0, 0.0, -math.sin(yaw), math.cos(yaw)]])
            H = np.vstack([H, lat])
            R = np.diag([R[0, 0], R[1, 1], p.lateral_speed_std_mps**2])
            z = np.array([z[0], z[1], 0.0])
        S = H @ tr.P @ H.T + R
        K = tr.P @ H.T @ np.linalg.inv(S)
        tr.x = tr.x + K @ (z - H @ tr.x)
        ikh = np.eye(4) - K @ H
        tr.P = ikh @ tr.P @ ikh.T + K @ R @ K.T
        tr.hits += 1
        tr.misses = 0
        tr.seen_t_s = tr.t_s
