"""A track (centreline and widths) extracted from a ROS occupancy map: pure maths, no files.

``track_from_grid(grid, options)`` turns a ``shared.track.occupancy.OccupancyGrid`` (e.g. a
Cartographer or slam_toolbox map loaded by ``load_ros_map``) into a ``Track``:

1. **Free space**: the cells whose occupancy is below ``free_thresh`` (``FREE``); unknown cells
   are not free. Components are 4-connected, so a free region never leaks through a diagonal
   of a thin wall.
2. **The track's region**: the free component that is a *ring* (it encloses a hole of at
   least ``min_hole_m2``: the infield). Components touching the image border are taken only
   when no other one is a ring (maps whose outside is free: the F1TENTH maps; maps whose
   outside is unknown: SLAM maps). Of the rings, the one enclosing the largest hole wins;
   rings lying inside it (an infield with an obstacle) are ignored; another separate ring
   with at least ``TWO_LOOPS_HOLE_FRACTION`` of that hole area is an error (``two loops``)
   unless ``start_xy_m`` picks one. Holes other than the largest (obstacles, noise in the
   track) are filled, so the region is topologically an annulus.
3. **Skeleton**: ``skimage.morphology.skeletonize`` of the region; spurs are pruned
   (end pixels removed until none is left), which leaves the one closed loop of the skeleton
   graph around the infield; it is ordered as the shortest closed path of the 8-connected
   pixel graph through one of its pixels (``scipy.sparse.csgraph.dijkstra``).
4. **Smoothing**: the pixel loop is resampled every half cell and fitted with a periodic
   cubic smoothing spline (``scipy.interpolate.splprep``, ``per=1``) allowed to depart from
   it by an RMS of ``smoothing_cells`` cells (default 0.3: about the RMS of a pixel's
   quantisation, 1/sqrt(12) cell), the fewest knots that stay within that. A moving-window
   filter (Savitzky-Golay over 1 m) left the pixel staircase of long, slightly slanted
   straights in the line - neighbouring points jittered by ~1 mm, a median |kappa| of
   0.14-0.22 1/m on the F1TENTH maps against 0.003-0.014 1/m for their published lines;
   the spline gives 0.003-0.017 1/m with the line within 0.3-0.6 cells RMS of the
   published one (``benchmarks/map_to_track.py``). The spline is then resampled every
   ``spacing_m`` of arc length starting at the point nearest ``start_xy_m`` (default: the
   map frame's origin (0, 0), where SLAM usually started), in the driving direction
   ``direction``.
5. **Widths**: ``w = d - cell/2`` with ``d`` the Euclidean distance (``distance_transform_edt``,
   bilinear between cell centres) from the point to the nearest cell outside the region on
   that side: the infield side (the largest hole) is the left for counter-clockwise driving,
   the right for clockwise.

Every failure raises ``TrackError(grid.source, problem)`` with one line saying what to do.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np

from shared.track.errors import TrackError
from shared.track.geometry import Track
from shared.track.occupancy import FREE, OccupancyGrid

Direction = Literal["cw", "ccw"]
#: Another separate ring whose hole is at least this fraction of the chosen one's: "two loops".
TWO_LOOPS_HOLE_FRACTION = 0.25
#: 8-neighbour offsets (row, col) with their lengths [cells].
_HALF_OFFSETS = ((0, 1, 1.0), (1, 0, 1.0), (1, 1, np.sqrt(2.0)), (1, -1, np.sqrt(2.0)))


@dataclass(frozen=True)
class MapTrackOptions:
    """How a track is extracted from a map.

    Attributes:
        direction: driving direction around the infield, "ccw" (counter-clockwise, infield
            on the left) or "cw".
        spacing_m: spacing of the resampled centreline points [m].
        smoothing_cells: RMS distance [cells] the periodic smoothing spline may keep from
            the pixel loop (0: a spline through every half-cell point, no smoothing).
        start_xy_m: (x, y) [m] in the map frame: the first point is the centreline point
            nearest it, and it picks the ring when the map has several; None: the map
            frame's origin (0, 0) for the first point.
        min_hole_m2: smallest infield area that makes a free region a loop [m^2].
    """

    direction: Direction = "ccw"
    spacing_m: float = 0.1
    smoothing_cells: float = 0.3
    start_xy_m: tuple[float, float] | None = None
    min_hole_m2: float = 1.0

    def __post_init__(self) -> None:
        if self.direction not in ("cw", "ccw"):
            raise ValueError(f"direction must be 'cw' or 'ccw', got {self.direction!r}")
        if not (np.isfinite(self.spacing_m) and 0.0 < self.spacing_m <= 5.0):
            raise ValueError(f"spacing_m must be in (0, 5] m, got {self.spacing_m}")
        if not (np.isfinite(self.smoothing_cells) and 0.0 <= self.smoothing_cells <= 5.0):
            raise ValueError(
                f"smoothing_cells must be in [0, 5] cells, got {self.smoothing_cells}"
            )
        if self.start_xy_m is not None and not np.all(np.isfinite(self.start_xy_m)):
            raise ValueError(f"start_xy_m must be finite, got {self.start_xy_m}")
        if not (np.isfinite(self.min_hole_m2) and self.min_hole_m2 >= 0.0):
            raise ValueError(f"min_hole_m2 must be >= 0, got {self.min_hole_m2}")


@dataclass(frozen=True, eq=False)
class RingRegion:
    """The track's free region in a crop of the grid.

    Attributes:
        region: (h, w) bool, the ring of free space (small holes filled).
        hole: (h, w) bool, the infield (the ring's largest hole).
        offset_rc: (row, col) of the crop's cell (0, 0) in the grid.
    """

    region: np.ndarray
    hole: np.ndarray
    offset_rc: tuple[int, int]


# ---------------------------------------------------------------------- grid <-> world
def cell_to_world(grid: OccupancyGrid, rc: np.ndarray) -> np.ndarray:
    """(..., 2) fractional (row, col) cell indices -> (..., 2) map-frame points [m].

    The centre of cell (r, c) is ``origin + R(yaw) @ ((c + 0.5) res, (r + 0.5) res)``.
    """
    rc = np.asarray(rc, dtype=float)
    local = np.stack([(rc[..., 1] + 0.5), (rc[..., 0] + 0.5)], axis=-1) * grid.resolution_m
    if grid.origin_yaw_rad:
        c, s = np.cos(grid.origin_yaw_rad), np.sin(grid.origin_yaw_rad)
        local = np.stack(
            [c * local[..., 0] - s * local[..., 1], s * local[..., 0] + c * local[..., 1]], -1
        )
    return local + grid.origin_xy_m


def world_to_cell_frac(grid: OccupancyGrid, xy: np.ndarray) -> np.ndarray:
    """(..., 2) map-frame points [m] -> (..., 2) fractional (row, col) (cell centres integer)."""
    p = np.asarray(xy, dtype=float) - grid.origin_xy_m
    if grid.origin_yaw_rad:
        c, s = np.cos(-grid.origin_yaw_rad), np.sin(-grid.origin_yaw_rad)
        p = np.stack([c * p[..., 0] - s * p[..., 1], s * p[..., 0] + c * p[..., 1]], -1)
    return np.stack([p[..., 1], p[..., 0]], axis=-1) / grid.resolution_m - 0.5


# ---------------------------------------------------------------------- the ring region
def _holes(mask: np.ndarray) -> tuple[np.ndarray, int]:
    """Label the holes of `mask` (8-connected components of its complement that do not touch
    the border). Returns (labels, count); label 0 is the mask or the outside."""
    from scipy import ndimage

    labels, n = ndimage.label(~mask, structure=np.ones((3, 3), dtype=bool))
    border = np.unique(np.concatenate([labels[0], labels[-1], labels[:, 0], labels[:, -1]]))
    keep = np.ones(n + 1, dtype=bool)
    keep[border] = False
    keep[0] = False
    remap = np.zeros(n + 1, dtype=np.int64)
    remap[keep] = np.arange(1, int(keep.sum()) + 1)
    return remap[labels], int(keep.sum())


@dataclass(frozen=True)
class _Ring:
    label: int
    slices: tuple[slice, slice]
    hole_cells: int
    touches_border: bool


def find_ring(grid: OccupancyGrid, options: MapTrackOptions) -> RingRegion:
    """Step 1-2 of the module docstring: the free ring of the track's loop, cropped.

    Raises:
        TrackError: no free cells, no ring, or two separate rings (and no ``start_xy_m``).
    """
    from scipy import ndimage

    free = grid.cells == FREE
    if not free.any():
        raise TrackError(grid.source, "the map has no free cells (is it empty or negated?)")
    labels, n = ndimage.label(free)  # 4-connected
    res2 = grid.resolution_m**2
    min_hole = max(4, int(np.ceil(options.min_hole_m2 / res2)))
    sizes = np.bincount(labels.ravel(), minlength=n + 1)
    rows, cols = free.shape
    rings: list[_Ring] = []
    for lab, slc in enumerate(ndimage.find_objects(labels), start=1):
        if slc is None or sizes[lab] < 8:
            continue
        h = slc[0].stop - slc[0].start
        w = slc[1].stop - slc[1].start
        if h < 3 or w < 3:
            continue
        comp = np.pad(labels[slc] == lab, 1)
        hole_labels, nh = _holes(comp)
        if nh == 0:
            continue
        biggest = int(np.bincount(hole_labels.ravel())[1:].max())
        if biggest < min_hole:
            continue
        touches = slc[0].start == 0 or slc[1].start == 0 or slc[0].stop == rows
        touches = touches or slc[1].stop == cols
        rings.append(_Ring(lab, slc, biggest, bool(touches)))
    if not rings:
        raise TrackError(
            grid.source,
            "no loop of free space around an infield found (is the track closed? are its walls "
            f"drawn? infield must be >= {options.min_hole_m2:g} m^2)",
        )
    if options.start_xy_m is not None:
        r, c = np.floor(world_to_cell_frac(grid, np.asarray(options.start_xy_m)) + 0.5)
        r, c = int(r), int(c)
        lab = int(labels[r, c]) if 0 <= r < rows and 0 <= c < cols else 0
        chosen = [g for g in rings if g.label == lab]
        if not chosen:
            raise TrackError(
                grid.source,
                f"start {options.start_xy_m} is not on a loop of free space of this map",
            )
        ring = chosen[0]
    else:
        inner = [g for g in rings if not g.touches_border] or rings
        inner.sort(key=lambda g: -g.hole_cells)
        ring = inner[0]
        for other in inner[1:]:
            if other.hole_cells < TWO_LOOPS_HOLE_FRACTION * ring.hole_cells:
                break
            if not _inside_hole_of(labels, ring, other):
                raise TrackError(
                    grid.source,
                    "two separate loops of free space; give the start point (--start X,Y) "
                    "on the one to use, or crop the map",
                )
    return _ring_region(labels, ring)


def _ring_region(labels: np.ndarray, ring: _Ring) -> RingRegion:
    """Crop (1 cell margin) with the ring, its largest hole and its other holes filled."""
    slc = ring.slices
    r0, c0 = slc[0].start - 1, slc[1].start - 1
    comp = np.pad(labels[slc] == ring.label, 1)
    hole_labels, _ = _holes(comp)
    counts = np.bincount(hole_labels.ravel())
    counts[0] = 0
    main = int(np.argmax(counts))
    hole = hole_labels == main
    region = comp | ((hole_labels > 0) & ~hole)
    return RingRegion(region=region, hole=hole, offset_rc=(r0, c0))


def _inside_hole_of(labels: np.ndarray, ring: _Ring, other: _Ring) -> bool:
    """Whether ring `other` lies in the largest hole of `ring` (nested, e.g. in the infield)."""
    region = _ring_region(labels, ring)
    rr, cc = np.nonzero(labels[other.slices] == other.label)
    rr = rr[:1] + other.slices[0].start - region.offset_rc[0]
    cc = cc[:1] + other.slices[1].start - region.offset_rc[1]
    h, w = region.hole.shape
    if not (0 <= rr[0] < h and 0 <= cc[0] < w):
        return False
    return bool(region.hole[rr[0], cc[0]])


# ---------------------------------------------------------------------- skeleton loop
def _neighbour_count(skel: np.ndarray) -> np.ndarray:
    from scipy import ndimage

    k = np.ones((3, 3), dtype=np.int32)
    k[1, 1] = 0
    return ndimage.convolve(skel.astype(np.int32), k, mode="constant") * skel


def prune_spurs(skel: np.ndarray) -> np.ndarray:
    """Remove end pixels (at most one 8-neighbour) until none is left: only cycles remain.

    `skel` is an (h, w) bool skeleton; returns a new array.
    """
    skel = skel.copy()
    count = _neighbour_count(skel)
    h, w = skel.shape
    stack = list(zip(*np.nonzero(skel & (count <= 1)), strict=True))
    while stack:
        r, c = stack.pop()
        if not skel[r, c]:
            continue
        skel[r, c] = False
        for dr in (-1, 0, 1):
            for dc in (-1, 0, 1):
                rr, cc = r + dr, c + dc
                if (dr or dc) and 0 <= rr < h and 0 <= cc < w and skel[rr, cc]:
                    count[rr, cc] -= 1
                    if count[rr, cc] <= 1:
                        stack.append((rr, cc))
    return skel


def order_loop(skel: np.ndarray) -> np.ndarray:
    """The closed loop of a pruned skeleton as (k, 2) (row, col) pixels in order.

    The loop is the shortest closed path through a pixel whose two neighbours are not
    neighbours of each other (so not a corner of a one-pixel triangle); with one hole in the
    region that is the skeleton's one loop, the little triangles of 8-connected corners cut.
    """
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import dijkstra

    rr, cc = np.nonzero(skel)
    n = rr.size
    if n < 8:
        raise ValueError("the skeleton has no loop")
    index = np.full(skel.shape, -1, dtype=np.int64)
    index[rr, cc] = np.arange(n)
    h, w = skel.shape
    src, dst, wts = [], [], []
    for dr, dc, length in _HALF_OFFSETS:
        r2, c2 = rr + dr, cc + dc
        ok = (r2 >= 0) & (r2 < h) & (c2 >= 0) & (c2 < w)
        j = np.full(n, -1, dtype=np.int64)
        j[ok] = index[r2[ok], c2[ok]]
        m = j >= 0
        src.append(np.flatnonzero(m))
        dst.append(j[m])
        wts.append(np.full(int(m.sum()), length))
    a = np.concatenate(src)
    b = np.concatenate(dst)
    wt = np.concatenate(wts)
    adjacency = [[] for _ in range(n)]
    for i, j in zip(a.tolist(), b.tolist(), strict=True):
        adjacency[i].append(j)
        adjacency[j].append(i)
    edges = {(min(i, j), max(i, j)) for i, j in zip(a.tolist(), b.tolist(), strict=True)}
    start = next_ = -1
    for i in range(n):
        nb = adjacency[i]
        if len(nb) == 2 and (min(nb), max(nb)) not in edges:
            start, next_ = i, nb[0]
            break
    if start < 0:
        raise ValueError("the skeleton has no simple loop pixel")
    keep = ~(((a == start) & (b == next_)) | ((a == next_) & (b == start)))
    graph = coo_matrix((wt[keep], (a[keep], b[keep])), shape=(n, n)).tocsr()
    dist, pred = dijkstra(graph, directed=False, indices=start, return_predecessors=True)
    if not np.isfinite(dist[next_]):
        raise ValueError("the skeleton has no loop")
    path = [next_]
    while path[-1] != start:
        path.append(int(pred[path[-1]]))
    order = np.asarray(path[::-1])
    return np.stack([rr[order], cc[order]], axis=1)


# ---------------------------------------------------------------------- smoothing
def resample_closed(xy: np.ndarray, n: int, s0: float = 0.0) -> np.ndarray:
    """(n, 2) points every L/n of arc along the closed polyline `xy` (m, 2), from arc s0."""
    closed = np.vstack([xy, xy[:1]])
    seg = np.hypot(*np.diff(closed, axis=0).T)
    s = np.concatenate([[0.0], np.cumsum(seg)])
    length = float(s[-1])
    t = np.mod(s0 + np.arange(n) * (length / n), length)
    return np.stack([np.interp(t, s, closed[:, 0]), np.interp(t, s, closed[:, 1])], axis=1)


def closed_length(xy: np.ndarray) -> float:
    """Length [m] of the closed polyline through the (m, 2) points."""
    return float(np.hypot(*(np.roll(xy, -1, axis=0) - xy).T).sum())


def smooth_closed(xy: np.ndarray, rms_m: float) -> np.ndarray:
    """A periodic cubic smoothing spline through the closed (m, 2) polyline `xy` [m]
    (uniformly spaced, first point not repeated), evaluated at m points evenly spaced in its
    chord-length parameter; the spline keeps within an RMS of `rms_m` [m] of the points
    (``splprep``'s ``s = m rms_m^2``: the fewest knots that do). Below 8 points the input is
    returned."""
    from scipy.interpolate import splev, splprep

    m = xy.shape[0]
    if m < 8:
        return xy.copy()
    closed = np.vstack([xy, xy[:1]])  # per=1: the last point closes the loop
    tck, _ = splprep([closed[:, 0], closed[:, 1]], s=m * rms_m**2, per=1, k=3, quiet=1)
    x, y = splev(np.arange(m) / m, tck)
    return np.stack([np.asarray(x), np.asarray(y)], axis=1)


def signed_area(xy: np.ndarray) -> float:
    """Signed area [m^2] of the closed polygon (m, 2): > 0 counter-clockwise (shoelace)."""
    x, y = xy[:, 0], xy[:, 1]
    return 0.5 * float(np.dot(x, np.roll(y, -1)) - np.dot(np.roll(x, -1), y))


# ---------------------------------------------------------------------- the track
def track_from_grid(grid: OccupancyGrid, options: MapTrackOptions | None = None,
                    name: str = "map") -> Track:
    """The track of an occupancy map (the steps of the module docstring).

    Args:
        grid: the occupancy map (``load_ros_map``).
        options: extraction settings (None: ``MapTrackOptions()``).
        name: the track's name.

    Returns:
        A ``Track`` with points every ~``spacing_m`` in ``direction`` and widths from the
        distance field; its ``source`` is the grid's.

    Raises:
        TrackError: naming the map and the problem (no free space, no loop, two loops, a
            track too narrow for its cells).
    """
    from scipy import ndimage
    from skimage.morphology import skeletonize

    opts = options or MapTrackOptions()
    res = grid.resolution_m
    ring = find_ring(grid, opts)
    skel = prune_spurs(skeletonize(ring.region))
    try:
        pixels = order_loop(skel)
    except ValueError as exc:
        raise TrackError(grid.source, f"cannot extract the centreline loop ({exc})") from None
    rc_grid = pixels + np.asarray(ring.offset_rc)
    raw = cell_to_world(grid, rc_grid.astype(float))
    length = closed_length(raw)
    fine_n = max(16, round(length / (0.5 * res)))
    fine = resample_closed(raw, fine_n)
    fine = smooth_closed(fine, opts.smoothing_cells * res)
    if (signed_area(fine) > 0) != (opts.direction == "ccw"):
        fine = fine[::-1]
    start = np.zeros(2) if opts.start_xy_m is None else np.asarray(opts.start_xy_m, float)
    i0 = int(np.argmin(np.sum((fine - start) ** 2, axis=1)))
    fine = np.roll(fine, -i0, axis=0)
    length = closed_length(fine)
    n = max(10, round(length / opts.spacing_m))
    xy = resample_closed(fine, n)
    # widths: distance to the infield (hole) and to everything else outside the region
    d_hole = ndimage.distance_transform_edt(~ring.hole)
    d_out = ndimage.distance_transform_edt(ring.region | ring.hole)
    rc = (world_to_cell_frac(grid, xy) - np.asarray(ring.offset_rc)).T
    w_hole = (ndimage.map_coordinates(d_hole, rc, order=1, mode="nearest") - 0.5) * res
    w_out = (ndimage.map_coordinates(d_out, rc, order=1, mode="nearest") - 0.5) * res
    w_left, w_right = (w_hole, w_out) if opts.direction == "ccw" else (w_out, w_hole)
    if min(w_left.min(), w_right.min()) <= 0.0:
        raise TrackError(grid.source, "the extracted centreline touches a wall (map too coarse?)")
    return Track(name=name, xy=xy, w_right_m=w_right, w_left_m=w_left, source=grid.source)


# ---------------------------------------------------------------------- comparison
def distances_to_polyline(points: np.ndarray, polyline: np.ndarray) -> np.ndarray:
    """(m,) distance [m] from each of the (m, 2) points to the CLOSED polyline (k, 2)."""
    a = np.asarray(polyline, dtype=float)
    ab = np.roll(a, -1, axis=0) - a
    ab2 = np.maximum(np.einsum("ij,ij->i", ab, ab), 1e-18)
    p = np.asarray(points, dtype=float)
    out = np.empty(p.shape[0])
    for k in range(0, p.shape[0], 256):
        q = p[k : k + 256]
        ap = q[:, None, :] - a[None]
        t = np.clip(np.einsum("mij,ij->mi", ap, ab) / ab2, 0.0, 1.0)
        d = ap - t[..., None] * ab[None]
        out[k : k + 256] = np.sqrt(np.min(np.einsum("mij,mij->mi", d, d), axis=1))
    return out


def symmetric_rms_max(a: np.ndarray, b: np.ndarray) -> tuple[float, float]:
    """(rms, max) [m] over both directions: the points of `a` to polyline `b` and back."""
    d = np.concatenate([distances_to_polyline(a, b), distances_to_polyline(b, a)])
    return float(np.sqrt(np.mean(d * d))), float(d.max())
