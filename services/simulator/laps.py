"""Lap timing by arc length and track-limit detection by the car's footprint.

Progress: every pose is projected to the centreline near the previous arc length ``s`` and
the wrapped change ``ds`` (in [-L/2, L/2)) is added to an unwrapped arc length ``S`` (L =
track length). The start line is ``s = 0``; line ``k`` is crossed when ``S`` first reaches
``k L``. Only the furthest line counts, so jitter backwards and forwards over the line and
reverse driving count nothing, and consecutive crossings are a full length of forward
progress apart. Crossing times are interpolated linearly between the two samples around it.
Timing starts at the first crossing (event ``start``); each later crossing completes a lap
(event ``lap``). For a standing start place the car just behind the line (s slightly
below L).

Track limits: the footprint is the ``length x width`` rectangle centred on the CoG, aligned
with the yaw. A corner is outside when its contour error ``e_con`` (positive right, at its
own projection) exceeds ``w_right`` or is below ``-w_left`` there. ``off_track`` is reported
when the first corner leaves, ``back_on_track`` when all four are inside again.

Projection is local (a window around the previous segment, exactly the formulas of
``Track.project`` / ``Track.interp_width``) and falls back to a global search when the best
segment lies on the window's edge (the car jumped).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from services.simulator.state import Pose2D
from shared.car import CAR
from shared.messages.vocab import LapKindName
from shared.track.geometry import Track


@dataclass(frozen=True, slots=True)
class LapEvent:
    """A lap-timer event (field names as in ``shared.messages.LapEvent``).

    Attributes:
        kind: ``start`` (first line crossing: timing starts), ``lap`` (a lap completed),
            ``off_track``, ``back_on_track``.
        t_s: time [s] (interpolated for line crossings, the sample time otherwise).
        s_m: arc length of the CoG [m] (0 for line crossings).
        lap: completed laps; for ``lap`` the number of the lap just completed (1-based).
        off_track_events: ``off_track`` events during the lap (so far; for ``lap`` the
            whole lap; events before timing started count towards nothing).
        max_abs_e_con_m: largest |e_con| of the CoG during the lap so far [m].
        lap_time_s: ``lap`` only: time between its two line crossings [s].
        mean_speed_mps: ``lap`` only: track length / lap time [m/s] (centreline speed).
        mean_car_speed_mps: ``lap`` only: time-weighted mean of the fed speed [m/s].
    """

    kind: LapKindName
    t_s: float
    s_m: float
    lap: int
    off_track_events: int = 0
    max_abs_e_con_m: float = 0.0
    lap_time_s: float | None = None
    mean_speed_mps: float | None = None
    mean_car_speed_mps: float | None = None


def centreline_pose(track: Track, s_m: float) -> Pose2D:
    """Pose on the centreline at arc length `s_m` [m], heading along the track."""
    x, y = (float(v) for v in track.point_at(s_m))
    return Pose2D(x, y, float(track.heading_at(s_m)))


class _LocalProjector:
    """Track.project + interp_width for a few points near a known segment (fast path)."""

    def __init__(self, track: Track, window_m: float) -> None:
        self.track = track
        self.n = track.n_points
        a = np.asarray(track.xy, dtype=float)
        b = np.roll(a, -1, axis=0)
        self.a = a
        self.ab = b - a
        self.ab2 = np.einsum("ij,ij->i", self.ab, self.ab)
        self.seg_len = np.sqrt(self.ab2)
        self.s = np.asarray(track.s_m, dtype=float)
        self.sin_h = np.sin(track.heading_rad)
        self.cos_h = np.cos(track.heading_rad)
        w_r = np.asarray(track.w_right_m, dtype=float)
        w_l = np.asarray(track.w_left_m, dtype=float)
        self.w_r0, self.w_r1 = w_r, np.roll(w_r, -1)
        self.w_l0, self.w_l1 = w_l, np.roll(w_l, -1)
        half = math.ceil(window_m / max(float(self.seg_len.min()), 1e-6)) + 1
        half = min(half, (self.n - 1) // 2)
        self.offsets = np.arange(-half, half + 1)
        self.length = track.length_m

    def project(
        self, pts: np.ndarray, seg_hint: int | None
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """(s, e_con, w_right, w_left, segment) of (m, 2) points; local search near seg_hint."""
        if seg_hint is None:
            idx = np.arange(self.n)
        else:
            idx = (seg_hint + self.offsets) % self.n
        a = self.a[idx]
        ab = self.ab[idx]
        ab2 = self.ab2[idx]
        ap = pts[:, None, :] - a[None, :, :]
        t = np.einsum("mij,ij->mi", ap, ab) / ab2
        np.clip(t, 0.0, 1.0, out=t)
        d = ap - t[..., None] * ab[None]
        d2 = np.einsum("mij,mij->mi", d, d)
        k = np.argmin(d2, axis=1)
        if seg_hint is not None and (k.min() == 0 or k.max() == idx.size - 1):
            return self.project(pts, None)
        rows = np.arange(pts.shape[0])
        seg = idx[k]
        tk = t[rows, k]
        dk = d[rows, k]
        s = np.mod(self.s[seg] + tk * self.seg_len[seg], self.length)
        e = self.sin_h[seg] * dk[:, 0] - self.cos_h[seg] * dk[:, 1]
        w_r = self.w_r0[seg] + tk * (self.w_r1[seg] - self.w_r0[seg])
        w_l = self.w_l0[seg] + tk * (self.w_l1[seg] - self.w_l0[seg])
        return s, e, w_r, w_l, seg


class LapTimer:
    """Lap timing and track limits from a stream of poses (see the module docstring).

    Args:
        track: the track (start line at s = 0, driving direction = point order).
        width_m: car width for the footprint [m].
        length_m: car length for the footprint [m].
        window_m: half-width of the local projection window [m]; larger than the distance
            travelled between two updates.
    """

    def __init__(
        self,
        track: Track,
        width_m: float = CAR.width_m,
        length_m: float = CAR.length_m,
        window_m: float = 1.0,
    ) -> None:
        if not (width_m > 0.0 and length_m > 0.0 and window_m > 0.0):
            raise ValueError("width_m, length_m and window_m must be > 0")
        self.track = track
        self.length_track_m = track.length_m
        self._proj = _LocalProjector(track, window_m)
        hl, hw = 0.5 * length_m, 0.5 * width_m
        self._half_length, self._half_width = hl, hw
        #: footprint corners in the body frame (x ahead, y left) [m], (4, 2)
        self.corners_body = np.array([[hl, hw], [hl, -hw], [-hl, -hw], [-hl, hw]])
        self.events: list[LapEvent] = []
        self.reset()

    def reset(self) -> None:
        """Forget everything (the next update is a fresh start)."""
        self.events.clear()
        self._seg: int | None = None
        self._t_prev: float | None = None
        self._v_prev = 0.0
        self.s_m = 0.0
        self.progress_m = 0.0  # unwrapped arc length S [m]
        self.e_con_m = 0.0
        self.off_track = False
        self.laps_completed = 0
        self.lap_start_s: float | None = None  # time of the last line crossing [s]
        self._next_line = 1
        self._lap_speed_integral = 0.0
        self._lap_off_count = 0
        self._lap_max_e = 0.0

    def count_from_behind_line(self) -> None:
        """After the first update of a car placed BEHIND the start line (in the lap's second
        half): its progress counts from one lap before, so it drives an out lap over the line
        and a full lap before timing starts, as a car placed past the line does."""
        if self.progress_m > 0.5 * self.length_track_m and self._next_line == 1:
            self.progress_m -= self.length_track_m

    @property
    def timing(self) -> bool:
        """Whether the first line crossing happened (laps are being timed)."""
        return self.lap_start_s is not None

    def footprint(self, x_m: float, y_m: float, yaw_rad: float) -> np.ndarray:
        """(4, 2) map-frame corners [m] of the car at this pose."""
        c, s = math.cos(yaw_rad), math.sin(yaw_rad)
        rot = np.array([[c, -s], [s, c]])
        return self.corners_body @ rot.T + np.array([x_m, y_m])

    def update(
        self, t_s: float, x_m: float, y_m: float, yaw_rad: float, speed_mps: float
    ) -> list[LapEvent]:
        """Feed one pose (time [s], CoG [m], yaw [rad], speed [m/s]); returns new events."""
        c, sn = math.cos(yaw_rad), math.sin(yaw_rad)
        hl, hw = self._half_length, self._half_width
        ax, ay = c * hl, sn * hl  # half-length along the yaw
        bx, by = -sn * hw, c * hw  # half-width to the left
        pts = np.array(
            [
                (x_m, y_m),
                (x_m + ax + bx, y_m + ay + by),
                (x_m + ax - bx, y_m + ay - by),
                (x_m - ax - bx, y_m - ay - by),
                (x_m - ax + bx, y_m - ay + by),
            ]
        )
        s, e, w_r, w_l, seg = self._proj.project(pts, self._seg)
        self._seg = int(seg[0])
        s_now = float(s[0])
        e_now = float(e[0])
        out: list[LapEvent] = []
        speed = float(speed_mps)
        if self._t_prev is None:
            self.s_m, self.progress_m = s_now, s_now
            self._t_prev, self._v_prev = float(t_s), speed
        else:
            L = self.length_track_m
            ds = (s_now - self.s_m + 0.5 * L) % L - 0.5 * L
            p_prev = self.progress_m
            p_now = p_prev + ds
            t_prev, v_prev = self._t_prev, self._v_prev
            dt = float(t_s) - t_prev
            frac_done = 0.0
            while p_now >= self._next_line * L:
                line = self._next_line * L
                f = (line - p_prev) / (p_now - p_prev) if p_now > p_prev else 1.0
                t_cross = t_prev + f * dt
                self._accumulate_speed(v_prev, speed, dt, frac_done, f)
                frac_done = f
                out.append(self._cross_line(t_cross))
                self._next_line += 1
            self._accumulate_speed(v_prev, speed, dt, frac_done, 1.0)
            self.s_m, self.progress_m = s_now, p_now
            self._t_prev, self._v_prev = float(t_s), speed
        self.e_con_m = e_now
        if self.timing:
            self._lap_max_e = max(self._lap_max_e, abs(e_now))
        corners_out = bool(((e[1:] > w_r[1:]) | (e[1:] < -w_l[1:])).any())
        if corners_out != self.off_track:
            self.off_track = corners_out
            kind = LapKindName.OFF_TRACK if corners_out else LapKindName.BACK_ON_TRACK
            if corners_out:
                self._lap_off_count += 1
            out.append(
                LapEvent(
                    kind,
                    float(t_s),
                    s_now,
                    self.laps_completed,
                    off_track_events=self._lap_off_count,
                    max_abs_e_con_m=self._lap_max_e,
                )
            )
        self.events.extend(out)
        return out

    # ------------------------------------------------------------------ internals
    def _accumulate_speed(self, v0: float, v1: float, dt: float, f0: float, f1: float) -> None:
        """Add the speed integral over the fraction [f0, f1] of the last interval."""
        if self.timing and f1 > f0:
            va = v0 + f0 * (v1 - v0)
            vb = v0 + f1 * (v1 - v0)
            self._lap_speed_integral += 0.5 * (va + vb) * (f1 - f0) * dt

    def _cross_line(self, t_cross: float) -> LapEvent:
        if self.lap_start_s is None:
            event = LapEvent(LapKindName.START, t_cross, 0.0, 0)
        else:
            self.laps_completed += 1
            lap_time = t_cross - self.lap_start_s
            event = LapEvent(
                LapKindName.LAP,
                t_cross,
                0.0,
                self.laps_completed,
                lap_time_s=lap_time,
                mean_speed_mps=self.length_track_m / lap_time if lap_time > 0 else 0.0,
                mean_car_speed_mps=self._lap_speed_integral / lap_time if lap_time > 0 else 0.0,
                off_track_events=self._lap_off_count,
                max_abs_e_con_m=self._lap_max_e,
            )
        self.lap_start_s = t_cross
        self._lap_speed_integral = 0.0
        self._lap_off_count = 0
        self._lap_max_e = 0.0
        return event
