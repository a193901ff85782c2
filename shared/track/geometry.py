"""A closed race track: arc-length parametrised centreline, widths, boundaries, projection.

Conventions used everywhere in racestack:
- Points are in metres in the map frame; the centreline is a closed loop given by its unique
  points (the first point is NOT repeated at the end); the driving direction is the point order.
- `s` is arc length along the centreline in metres, periodic with period `length_m`.
- `e_con` is the contour error of the paper's MPCC (Liniger et al.), with `phi_ref` the tangent
  heading at the projection: `e_con = sin(phi_ref)(x - x_ref) - cos(phi_ref)(y - y_ref)`,
  i.e. POSITIVE TO THE RIGHT of the centreline (seen in the driving direction). The car is
  inside the track when `-w_left(s) <= e_con <= w_right(s)`.
"""

from __future__ import annotations

import bisect
import math
from dataclasses import dataclass, field

import numpy as np

from shared.track.errors import TrackError

#: Fewest centreline points a track may have.
MIN_POINTS = 10
#: A loop is open when its closing gap exceeds this multiple of the median point spacing.
MAX_CLOSING_GAP_FACTOR = 4.0


@dataclass(frozen=True, eq=False)
class Track:
    """A validated closed track.

    Attributes:
        name: short name (file stem or built-in name).
        xy: (n, 2) centreline points [m], unique, in driving order.
        w_right_m: (n,) distance from centreline to the right boundary [m], > 0.
        w_left_m: (n,) distance from centreline to the left boundary [m], > 0.
        source: where the track came from (a path or ``builtin:NAME``), for messages.
    """

    name: str
    xy: np.ndarray
    w_right_m: np.ndarray
    w_left_m: np.ndarray
    source: str = "<memory>"
    s_m: np.ndarray = field(init=False, repr=False)
    length_m: float = field(init=False)
    heading_rad: np.ndarray = field(init=False, repr=False)
    _closed: tuple = field(init=False, repr=False)
    _segments: tuple = field(init=False, repr=False)
    _near_accept_m2: float = field(init=False, repr=False)

    def __post_init__(self) -> None:
        xy = np.ascontiguousarray(self.xy, dtype=float)
        w_r = np.ascontiguousarray(self.w_right_m, dtype=float).reshape(-1)
        w_l = np.ascontiguousarray(self.w_left_m, dtype=float).reshape(-1)
        validate_loop(xy, w_r, w_l, self.source)
        seg = np.roll(xy, -1, axis=0) - xy
        seg_len = np.hypot(seg[:, 0], seg[:, 1])
        s = np.concatenate([[0.0], np.cumsum(seg_len)[:-1]])
        for name, value in (
            ("xy", xy),
            ("w_right_m", w_r),
            ("w_left_m", w_l),
            ("s_m", s),
            ("length_m", float(seg_len.sum())),
            ("heading_rad", np.arctan2(seg[:, 1], seg[:, 0])),
        ):
            if isinstance(value, np.ndarray):
                value.setflags(write=False)
            object.__setattr__(self, name, value)
        closed = (
            np.append(s, self.length_m),
            np.append(xy[:, 0], xy[0, 0]),
            np.append(xy[:, 1], xy[0, 1]),
            np.unwrap(np.append(self.heading_rad, self.heading_rad[0])),
            np.append(w_r, w_r[0]),
            np.append(w_l, w_l[0]),
        )
        for arr in closed:
            arr.setflags(write=False)
        object.__setattr__(self, "_closed", closed)
        # segment i runs from point i to point i+1 (the last one closes the loop)
        segments = (seg, seg_len * seg_len, seg_len)
        for arr in segments:
            arr.setflags(write=False)
        object.__setattr__(self, "_segments", segments)
        # project_near accepts its answer up to the narrowest half-width (squared) [m^2]
        object.__setattr__(self, "_near_accept_m2", float(min(w_r.min(), w_l.min())) ** 2)

    # ------------------------------------------------------------------ basic geometry
    @property
    def n_points(self) -> int:
        """Number of unique centreline points."""
        return int(self.xy.shape[0])

    @property
    def spacing_m(self) -> float:
        """Mean spacing between centreline points [m]."""
        return self.length_m / self.n_points

    def wrap_s(self, s: np.ndarray | float) -> np.ndarray | float:
        """Arc length wrapped into [0, length_m)."""
        return np.mod(s, self.length_m)

    def tangent_unit(self) -> np.ndarray:
        """(n, 2) unit tangents at the points (central difference, periodic)."""
        d = np.roll(self.xy, -1, axis=0) - np.roll(self.xy, 1, axis=0)
        return d / np.linalg.norm(d, axis=1, keepdims=True)

    def left_normal_unit(self) -> np.ndarray:
        """(n, 2) unit normals pointing to the left of the driving direction."""
        t = self.tangent_unit()
        return np.stack([-t[:, 1], t[:, 0]], axis=1)

    @property
    def left_boundary(self) -> np.ndarray:
        """(n, 2) left boundary points [m]."""
        return self.xy + self.w_left_m[:, None] * self.left_normal_unit()

    @property
    def right_boundary(self) -> np.ndarray:
        """(n, 2) right boundary points [m]."""
        return self.xy - self.w_right_m[:, None] * self.left_normal_unit()

    def signed_curvature(self) -> np.ndarray:
        """(n,) signed curvature [1/m], positive for left turns (central differences on s)."""
        h = self.heading_rad
        dh = np.angle(np.exp(1j * (h - np.roll(h, 1))))  # heading change at each point
        seg = np.hypot(*(np.roll(self.xy, -1, axis=0) - self.xy).T)
        ds = 0.5 * (seg + np.roll(seg, 1))
        return dh / ds

    def closed_arrays(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """(s, x, y, phi) with the first point repeated at s = length_m and phi unwrapped."""
        return self._closed[:4]

    def interp_width(self, s: np.ndarray | float) -> tuple[np.ndarray, np.ndarray]:
        """(w_right, w_left) [m] linearly interpolated at arc length(s) `s` (wrapped)."""
        s_cl, _, _, _, w_r_cl, w_l_cl = self._closed
        sw = np.mod(s, self.length_m)
        return np.interp(sw, s_cl, w_r_cl), np.interp(sw, s_cl, w_l_cl)

    def point_at(self, s: np.ndarray | float) -> np.ndarray:
        """Centreline point(s) [m] at arc length `s` (piecewise linear), shape (..., 2)."""
        s_cl, x, y, _ = self.closed_arrays()
        sw = np.mod(s, self.length_m)
        return np.stack([np.interp(sw, s_cl, x), np.interp(sw, s_cl, y)], axis=-1)

    def heading_at(self, s: np.ndarray | float) -> np.ndarray:
        """Tangent heading [rad] of the segment containing arc length `s`."""
        idx = np.searchsorted(self.s_m, np.mod(s, self.length_m), side="right") - 1
        return self.heading_rad[np.clip(idx, 0, self.n_points - 1)]

    # ------------------------------------------------------------------ projection
    def project(
        self, points: np.ndarray, s_hint: float | None = None, window_m: float = 5.0
    ) -> tuple[np.ndarray, np.ndarray]:
        """Project points to the centreline polyline.

        Args:
            points: (2,) or (m, 2) positions [m].
            s_hint: optional arc length [m] near which to search (for speed and to pick the
                right branch where the track folds back on itself); None searches all.
            window_m: half-width of the search window around `s_hint` [m].

        Returns:
            (s, e_con): arc length [m] in [0, length) and contour error [m] (positive right),
            arrays of shape () for one point or (m,) for many.
        """
        p = np.asarray(points, dtype=float)
        single = p.ndim == 1
        p = np.atleast_2d(p)
        idx = self._window(s_hint, window_m)
        seg_vec, seg_len2, seg_len = self._segments
        if idx is None:
            idx = np.arange(self.n_points)
            a, ab, ab2, ab_len = self.xy, seg_vec, seg_len2, seg_len
        else:
            a, ab, ab2, ab_len = self.xy[idx], seg_vec[idx], seg_len2[idx], seg_len[idx]
        if single:  # the per-tick case: plain vector maths, no (m, n, 2) temporaries
            px, py = float(p[0, 0]), float(p[0, 1])
            ax, ay, bx, by = a[:, 0], a[:, 1], ab[:, 0], ab[:, 1]
            t1 = np.clip(((px - ax) * bx + (py - ay) * by) / ab2, 0.0, 1.0)
            dx = px - (ax + t1 * bx)
            dy = py - (ay + t1 * by)
            k1 = int(np.argmin(dx * dx + dy * dy))
            i = int(idx[k1])
            h = self.heading_rad[i]
            s1 = (self.s_m[i] + t1[k1] * ab_len[k1]) % self.length_m
            return np.float64(s1), np.float64(np.sin(h) * dx[k1] - np.cos(h) * dy[k1])
        s_out = np.empty(p.shape[0])
        e_out = np.empty(p.shape[0])
        for chunk in range(0, p.shape[0], 256):
            q = p[chunk : chunk + 256]
            ap = q[:, None, :] - a[None, :, :]
            t = np.clip(np.einsum("mij,ij->mi", ap, ab) / ab2, 0.0, 1.0)
            closest = a[None] + t[..., None] * ab[None]
            d2 = np.sum((q[:, None, :] - closest) ** 2, axis=2)
            k = np.argmin(d2, axis=1)
            rows = np.arange(q.shape[0])
            seg = idx[k]
            tk = t[rows, k]
            s_out[chunk : chunk + 256] = np.mod(self.s_m[seg] + tk * ab_len[k], self.length_m)
            d = q - closest[rows, k]
            h = self.heading_rad[seg]
            e_out[chunk : chunk + 256] = np.sin(h) * d[:, 0] - np.cos(h) * d[:, 1]
        if single:
            return s_out[0], e_out[0]
        return s_out, e_out

    def project_near(
        self,
        x_m: float,
        y_m: float,
        s_hint: float,
        half_window_m: float = 1.0,
        fallback_window_m: float = 5.0,
    ) -> tuple[float, float]:
        """Project one point near a known arc length: the per-tick case, in plain Python.

        Searches the segments within about `half_window_m` [m] of `s_hint` [m]. Its answer
        stands when the closest segment is inside that window and the point is within the
        narrowest half-width of the track from it (then no other stretch of a valid track
        can be closer); otherwise (the point moved further, the hint is wrong, the car is
        off the track) it is ``project(..., s_hint, fallback_window_m)``. Gives exactly
        what ``project`` gives (ties go to the lower segment index, as there), in about a
        third of the time right after the process slept (no numpy calls).

        Returns:
            (s, e_con): arc length [m] in [0, length) and contour error [m] (positive right).
        """
        if not (math.isfinite(x_m) and math.isfinite(y_m) and math.isfinite(s_hint)):
            s, e = self.project(np.array([x_m, y_m], dtype=float), s_hint=None)
            return float(s), float(e)
        xs, ys, ux, uy, l2, ln, s_m, sin_h, cos_h = self._py_segments()
        n = len(xs)
        L = self.length_m
        i0 = bisect.bisect_right(s_m, s_hint % L) - 1
        k = int(half_window_m / self.spacing_m) + 2
        if 2 * k + 1 >= n:
            s, e = self.project(np.array([x_m, y_m]), s_hint=s_hint, window_m=fallback_window_m)
            return float(s), float(e)
        best, bi, bj, bt, bdx, bdy = math.inf, 0, 0, 0.0, 0.0, 0.0
        for j in range(i0 - k, i0 + k + 1):
            i = j % n
            ax, ay, bx, by = xs[i], ys[i], ux[i], uy[i]
            t = ((x_m - ax) * bx + (y_m - ay) * by) / l2[i]
            t = 0.0 if t < 0.0 else (1.0 if t > 1.0 else t)
            dx = x_m - (ax + t * bx)
            dy = y_m - (ay + t * by)
            d = dx * dx + dy * dy
            if d < best or (d == best and i < bi):
                best, bi, bj, bt, bdx, bdy = d, i, j, t, dx, dy
        if bj in (i0 - k, i0 + k) or best > self._near_accept_m2:
            # the minimum may lie outside the window, or this is the wrong stretch (the
            # point is farther than the narrowest half-width): search as project does
            s, e = self.project(np.array([x_m, y_m]), s_hint=s_hint, window_m=fallback_window_m)
            return float(s), float(e)
        return (s_m[bi] + bt * ln[bi]) % L, sin_h[bi] * bdx - cos_h[bi] * bdy

    def prepare_projection(self) -> None:
        """Build ``project_near``'s tables now, outside any tick (otherwise its first call
        builds them: about 0.5 ms on a 700-point track)."""
        self._py_segments()

    def _py_segments(self) -> tuple[list[float], ...]:
        """The segment data as Python lists (for ``project_near``), built once."""
        cached = self.__dict__.get("_py_segments_cache")
        if cached is None:
            seg_vec, seg_len2, seg_len = self._segments
            cached = tuple(
                a.tolist()
                for a in (
                    self.xy[:, 0],
                    self.xy[:, 1],
                    seg_vec[:, 0],
                    seg_vec[:, 1],
                    seg_len2,
                    seg_len,
                    self.s_m,
                    np.sin(self.heading_rad),
                    np.cos(self.heading_rad),
                )
            )
            object.__setattr__(self, "_py_segments_cache", cached)
        return cached

    def _window(self, s_hint: float | None, window_m: float) -> np.ndarray | None:
        """Indices of the points with arc length within `window_m` of `s_hint` (wrapped),
        None for all points (no hint, a window covering the lap, or no point in it)."""
        if s_hint is None or not 2 * window_m < self.length_m:
            return None
        L = self.length_m
        lo = float(np.mod(s_hint - window_m, L))
        hi = float(np.mod(s_hint + window_m, L))
        i_lo = int(np.searchsorted(self.s_m, lo, side="left"))
        i_hi = int(np.searchsorted(self.s_m, hi, side="right"))
        if lo <= hi:
            idx = np.arange(i_lo, i_hi)
        else:  # the window wraps past the start line (ascending, as ties go to the first)
            idx = np.concatenate([np.arange(0, i_hi), np.arange(i_lo, self.n_points)])
        return idx if idx.size else None

    def is_inside(self, points: np.ndarray, margin_m: float = 0.0) -> np.ndarray:
        """Whether points [m] lie within the boundaries shrunk by `margin_m` [m]."""
        s, e = self.project(points)
        w_r, w_l = self.interp_width(s)
        return (e <= w_r - margin_m) & (e >= -(w_l - margin_m))


def validate_loop(xy: np.ndarray, w_right: np.ndarray, w_left: np.ndarray, source: str) -> None:
    """Raise TrackError naming `source` if the centreline is not a valid closed loop.

    Checks: shape (n, 2) with n >= MIN_POINTS, finite values, positive widths of matching length,
    no repeated consecutive points, closed (closing gap small against the spacing), no
    self-crossing of the centreline. Points in the messages count from 1, as a user reads
    the rows of the file.
    """
    if xy.ndim != 2 or xy.shape[1] != 2:
        raise TrackError(source, f"centreline must have shape (n, 2), got {xy.shape}")
    n = xy.shape[0]
    if n < MIN_POINTS:
        raise TrackError(source, f"only {n} centreline points; at least {MIN_POINTS} are needed")
    if not np.all(np.isfinite(xy)):
        bad = int(np.flatnonzero(~np.isfinite(xy).all(axis=1))[0])
        raise TrackError(source, f"non-finite coordinate (NaN or inf) at point {bad + 1}")
    for label, w in (("right", w_right), ("left", w_left)):
        if w.shape != (n,):
            raise TrackError(source, f"{label} width has {w.size} values for {n} points")
        if not np.all(np.isfinite(w)):
            raise TrackError(
                source, f"non-finite {label} width at point {int(np.argmax(~np.isfinite(w))) + 1}"
            )
        if np.any(w <= 0.0):
            raise TrackError(
                source, f"zero or negative {label} width at point {int(np.argmax(w <= 0.0)) + 1}"
            )
    seg = np.hypot(*np.diff(xy, axis=0).T)
    if np.any(seg <= 1e-9):
        k = int(np.argmax(seg <= 1e-9))
        raise TrackError(source, f"point {k + 2} repeats point {k + 1}")
    gap = float(np.hypot(*(xy[0] - xy[-1])))
    median = float(np.median(seg))
    if gap > MAX_CLOSING_GAP_FACTOR * median:
        raise TrackError(
            source,
            f"open loop: the last point is {gap:.3f} m from the first "
            f"(median spacing {median:.3f} m)",
        )
    crossing = find_self_crossing(xy)
    if crossing is not None:
        i, j = crossing
        raise TrackError(
            source,
            f"self-crossing loop: the segment from point {i + 1} to {i + 2} crosses the "
            f"one from point {j + 1} to {j + 2}",
        )


#: Distance below which a point counts as lying on a segment's line [m].
TOUCH_TOLERANCE_M = 1e-7


def _sign(v: np.ndarray, tol: np.ndarray | float) -> np.ndarray:
    """-1, 0 or +1 with |v| <= tol counted as 0."""
    return np.where(np.abs(v) <= tol, 0, np.sign(v))


#: A broad-phase cell holding more segment ends than this falls back to the all-pairs scan
#: (a loop of a few long segments among many short ones; never a real track).
MAX_CELL_SEGMENTS = 64


def _segment_pairs(xy: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
    """Candidate pairs (i, j), i < j, of closed-polyline segments whose bounding boxes (grown
    by ``1e3 TOUCH_TOLERANCE_M``) share a cell of a uniform grid as large as the longest box
    side: every pair that can cross or touch is among them. None when a cell is too crowded.
    """
    a = xy
    b = np.roll(xy, -1, axis=0)
    pad = 1e3 * TOUCH_TOLERANCE_M
    lo = np.minimum(a, b) - pad
    hi = np.maximum(a, b) + pad
    h = float(np.max(hi - lo))
    c_lo = np.floor((lo - lo.min(axis=0)) / h).astype(np.int64)
    c_hi = np.floor((hi - lo.min(axis=0)) / h).astype(np.int64)
    n = xy.shape[0]
    ncol = int(c_hi[:, 0].max()) + 2
    segs, cells = [], []
    for dx in (0, 1):  # a box no larger than a cell covers at most 2 x 2 cells
        for dy in (0, 1):
            ok = (c_lo[:, 0] + dx <= c_hi[:, 0]) & (c_lo[:, 1] + dy <= c_hi[:, 1])
            k = np.flatnonzero(ok)
            segs.append(k)
            cells.append((c_lo[k, 1] + dy) * ncol + c_lo[k, 0] + dx)
    seg = np.concatenate(segs)
    cell = np.concatenate(cells)
    order = np.lexsort((seg, cell))
    seg, cell = seg[order], cell[order]
    starts = np.flatnonzero(np.r_[True, cell[1:] != cell[:-1]])
    sizes = np.diff(np.r_[starts, cell.size])
    if sizes.max() > MAX_CELL_SEGMENTS:
        return None
    ii, jj = [], []
    for off in range(1, int(sizes.max())):
        same = cell[off:] == cell[:-off]
        ii.append(seg[:-off][same])
        jj.append(seg[off:][same])
    if not ii:
        return np.empty(0, np.int64), np.empty(0, np.int64)
    i = np.concatenate(ii)
    j = np.concatenate(jj)  # i < j: sorted by segment within a cell
    keep = (j - i > 1) & ~((i == 0) & (j == n - 1))  # neighbours share a vertex
    key = np.unique(i[keep] * n + j[keep])
    return key // n, key % n


def _crossing(a: np.ndarray, b: np.ndarray, i: np.ndarray, j: np.ndarray) -> np.ndarray:
    """Whether segment i[k] (a -> b) properly crosses or touches segment j[k], per pair.

    Orientation tests of each segment against the other; a point within TOUCH_TOLERANCE_M
    of the other segment's line counts as on it (float noise on straights must not look like
    a crossing), and touches only if it projects inside that segment.
    """
    d = b - a
    di, dj = d[i], d[j]
    ai, bi, aj, bj = a[i], b[i], a[j], b[j]
    tol_i = TOUCH_TOLERANCE_M * np.hypot(di[:, 0], di[:, 1])
    tol_j = TOUCH_TOLERANCE_M * np.hypot(dj[:, 0], dj[:, 1])

    def cross(r: np.ndarray, p: np.ndarray, q: np.ndarray) -> np.ndarray:
        return r[:, 0] * (p[:, 1] - q[:, 1]) - r[:, 1] * (p[:, 0] - q[:, 0])

    def within(p: np.ndarray, q0: np.ndarray, r: np.ndarray) -> np.ndarray:
        t = np.einsum("ij,ij->i", p - q0, r) / np.einsum("ij,ij->i", r, r)
        return (t > 1e-9) & (t < 1 - 1e-9)

    s_ac = _sign(cross(di, aj, ai), tol_i)
    s_bc = _sign(cross(di, bj, ai), tol_i)
    s_ca = _sign(cross(dj, ai, aj), tol_j)
    s_da = _sign(cross(dj, bi, aj), tol_j)
    proper = (s_ac * s_bc < 0) & (s_ca * s_da < 0)
    touch = ((s_ac == 0) & within(aj, ai, di)) | ((s_bc == 0) & within(bj, ai, di))
    touch |= (s_ca == 0) & within(ai, aj, dj)
    touch |= (s_da == 0) & within(bi, aj, dj)
    return proper | touch


def find_self_crossing(xy: np.ndarray) -> tuple[int, int] | None:
    """First pair (i, j) (smallest i, then j) of non-adjacent closed-polyline segments that
    properly cross or touch, or None.

    A uniform-grid broad phase (``_segment_pairs``) keeps the pairs whose boxes meet, so a
    4000-point loop takes milliseconds instead of seconds; the all-pairs scan
    (``find_self_crossing_all_pairs``) remains for crowded cells.
    """
    xy = np.asarray(xy, dtype=float)
    pairs = _segment_pairs(xy)
    if pairs is None:
        return find_self_crossing_all_pairs(xy)
    i, j = pairs
    hit = _crossing(xy, np.roll(xy, -1, axis=0), i, j)
    if not np.any(hit):
        return None
    k = np.flatnonzero(hit)
    first = k[np.lexsort((j[k], i[k]))[0]]
    return int(i[first]), int(j[first])


def find_self_crossing_all_pairs(xy: np.ndarray) -> tuple[int, int] | None:
    """``find_self_crossing`` by testing every pair (O(n^2), one numpy pass per segment)."""
    a = np.asarray(xy, dtype=float)
    b = np.roll(a, -1, axis=0)
    n = a.shape[0]
    for i in range(n - 2):
        j = np.arange(i + 2, n if i > 0 else n - 1)
        if j.size == 0:
            continue
        hit = _crossing(a, b, np.full(j.size, i), j)
        if np.any(hit):
            return i, int(j[np.argmax(hit)])
    return None
