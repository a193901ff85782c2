"""ROS map_server occupancy maps (yaml + PGM/PNG image) as a grid, for lidar and drawing."""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from shared.track.errors import TrackError

#: Cell values of OccupancyGrid.cells.
FREE, OCCUPIED, UNKNOWN = 0, 100, -1


@dataclass(frozen=True, eq=False)
class OccupancyGrid:
    """An occupancy grid in the map frame.

    Attributes:
        cells: (rows, cols) int8, row 0 at the BOTTOM (y = origin y), FREE / OCCUPIED / UNKNOWN.
        resolution_m: cell edge [m].
        origin_xy_m: (2,) map-frame position of the lower-left corner of cell (0, 0) [m].
        origin_yaw_rad: map rotation [rad] (ROS maps almost always use 0).
        source: the yaml path.
    """

    cells: np.ndarray
    resolution_m: float
    origin_xy_m: np.ndarray
    origin_yaw_rad: float = 0.0
    source: str = "<memory>"

    @property
    def shape(self) -> tuple[int, int]:
        """(rows, cols)."""
        return tuple(self.cells.shape)  # type: ignore[return-value]

    def world_to_cell(self, xy: np.ndarray) -> np.ndarray:
        """(..., 2) map-frame points [m] -> (..., 2) integer (row, col) indices (may be outside)."""
        p = np.asarray(xy, dtype=float) - self.origin_xy_m
        if self.origin_yaw_rad:
            c, s = np.cos(-self.origin_yaw_rad), np.sin(-self.origin_yaw_rad)
            p = np.stack([c * p[..., 0] - s * p[..., 1], s * p[..., 0] + c * p[..., 1]], -1)
        col = np.floor(p[..., 0] / self.resolution_m).astype(int)
        row = np.floor(p[..., 1] / self.resolution_m).astype(int)
        return np.stack([row, col], axis=-1)

    def occupied_at(self, xy: np.ndarray) -> np.ndarray:
        """Whether each point [m] is in an occupied cell; outside the map counts as occupied."""
        rc = self.world_to_cell(xy)
        rows, cols = self.shape
        inside = (rc[..., 0] >= 0) & (rc[..., 0] < rows) & (rc[..., 1] >= 0) & (rc[..., 1] < cols)
        out = np.ones(rc.shape[:-1], dtype=bool)
        r = np.clip(rc[..., 0], 0, rows - 1)
        c = np.clip(rc[..., 1], 0, cols - 1)
        out[inside] = self.cells[r[inside], c[inside]] == OCCUPIED
        return out


def load_ros_map(yaml_path: str | Path) -> OccupancyGrid:
    """Load a ROS map_server map: the yaml (image, resolution, origin, negate, thresholds).

    The image (PGM or PNG, top row first) is read with Pillow and flipped so that row 0 is the
    bottom row. Occupancy probability of a pixel value v (0..255) is ``(255 - v) / 255``
    (``v / 255`` when ``negate`` is 1); above ``occupied_thresh`` is occupied, below
    ``free_thresh`` is free, anything else unknown.
    """
    import yaml
    from PIL import Image, UnidentifiedImageError

    path = Path(yaml_path)
    try:
        meta = yaml.safe_load(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, yaml.YAMLError) as exc:
        raise TrackError(str(path), f"cannot read map yaml ({exc})") from exc
    if not isinstance(meta, dict):
        raise TrackError(str(path), "map yaml is not a mapping")
    for key in ("image", "resolution", "origin"):
        if key not in meta:
            raise TrackError(str(path), f"map yaml has no '{key}'")
    try:
        resolution = float(meta["resolution"])
        origin = [float(v) for v in meta["origin"]]
        occ_t = float(meta.get("occupied_thresh", 0.65))
        free_t = float(meta.get("free_thresh", 0.196))
        negate = int(meta.get("negate", 0))
    except (TypeError, ValueError) as exc:
        raise TrackError(str(path), f"bad map yaml value ({exc})") from exc
    if not (resolution > 0 and np.isfinite(resolution)) or len(origin) != 3:
        raise TrackError(str(path), "resolution must be > 0 and origin must be [x, y, yaw]")
    image_path = path.parent / str(meta["image"])
    try:
        with Image.open(image_path) as img:
            pixels = np.asarray(img.convert("L"), dtype=float)
    except (OSError, UnidentifiedImageError) as exc:
        raise TrackError(str(image_path), f"cannot read map image ({exc})") from exc
    p = pixels / 255.0 if negate else (255.0 - pixels) / 255.0
    cells = np.full(p.shape, UNKNOWN, dtype=np.int8)
    cells[p > occ_t] = OCCUPIED
    cells[p < free_t] = FREE
    cells = np.ascontiguousarray(cells[::-1])
    cells.setflags(write=False)
    return OccupancyGrid(
        cells=cells,
        resolution_m=resolution,
        origin_xy_m=np.array(origin[:2]),
        origin_yaw_rad=origin[2],
        source=str(path),
    )


#: Above this turn between two centreline segments [rad] ``inside_cells`` projects every
#: cell on every segment (its local search's reach grows as 1 / cos of the turn).
MAX_LOCAL_TURN_RAD = math.radians(80.0)


def inside_cells(track, cx_m: np.ndarray, cy_m: np.ndarray) -> np.ndarray:
    """``track.is_inside`` at every grid point ``(cx_m[j], cy_m[i])``, computed locally.

    `track.is_inside` projects each point on every centreline segment (O(points x segments):
    27 s for a 780 x 760 grid of a generated track). Here each segment visits only the grid
    points within a reach ``R`` of it (its bounding box grown by ``R``), keeping per point the
    nearest segment (the first of equals, as the full search's argmin) and where on it, in
    the same arithmetic; the contour error, arc length and widths then follow as in
    `Track.project` and `Track.is_inside`. Exact, not approximate: a point farther than ``R``
    from every segment is outside, because its contour error is at least its distance times
    ``cos(turn)`` (the largest turn between two segments; a nearest point at a vertex lies in
    the cone of the two normals), and ``R = w_max / cos(turn)`` plus a cell.

    Args:
        track: a shared.track.Track.
        cx_m: (cols,) ascending x of the grid points [m].
        cy_m: (rows,) ascending y of the grid points [m].

    Returns:
        (rows, cols) bool, True inside the boundaries.
    """
    cx = np.asarray(cx_m, dtype=float)
    cy = np.asarray(cy_m, dtype=float)
    h = np.asarray(track.heading_rad, dtype=float)
    turn = float(np.max(np.abs(np.angle(np.exp(1j * (np.roll(h, -1) - h))))))
    if turn > MAX_LOCAL_TURN_RAD:
        gx, gy = np.meshgrid(cx, cy)
        points = np.stack([gx.ravel(), gy.ravel()], axis=1)
        return track.is_inside(points).reshape(cy.size, cx.size)
    step = max(float(np.max(np.diff(cx), initial=0.0)), float(np.max(np.diff(cy), initial=0.0)))
    w_max = float(max(np.max(track.w_right_m), np.max(track.w_left_m)))
    reach = w_max / math.cos(turn) + step
    a = np.asarray(track.xy, dtype=float)
    ab, ab2, ab_len = track._segments  # the very arrays Track.project divides by
    lo = np.minimum(a, a + ab) - reach
    hi = np.maximum(a, a + ab) + reach
    c0s, c1s = np.searchsorted(cx, lo[:, 0]), np.searchsorted(cx, hi[:, 0], side="right")
    r0s, r1s = np.searchsorted(cy, lo[:, 1]), np.searchsorted(cy, hi[:, 1], side="right")
    best = np.full((cy.size, cx.size), np.inf)
    seg = np.zeros((cy.size, cx.size), dtype=np.intp)
    tt = np.zeros((cy.size, cx.size))
    for i in range(a.shape[0]):
        c0, c1, r0, r1 = int(c0s[i]), int(c1s[i]), int(r0s[i]), int(r1s[i])
        if c0 >= c1 or r0 >= r1:
            continue
        apx = cx[None, c0:c1] - a[i, 0]
        apy = cy[r0:r1, None] - a[i, 1]
        t = np.clip((apx * ab[i, 0] + apy * ab[i, 1]) / ab2[i], 0.0, 1.0)
        dx = cx[None, c0:c1] - (a[i, 0] + t * ab[i, 0])
        dy = cy[r0:r1, None] - (a[i, 1] + t * ab[i, 1])
        d2 = dx * dx + dy * dy
        blk = best[r0:r1, c0:c1]
        nearer = d2 < blk
        blk[nearer] = d2[nearer]
        seg[r0:r1, c0:c1][nearer] = i
        tt[r0:r1, c0:c1][nearer] = t[nearer]
    near = best <= reach * reach
    k = seg[near]
    t = tt[near]
    gy, gx = np.nonzero(near)
    dx = cx[gx] - (a[k, 0] + t * ab[k, 0])
    dy = cy[gy] - (a[k, 1] + t * ab[k, 1])
    s = np.mod(track.s_m[k] + t * ab_len[k], track.length_m)
    e = np.sin(h[k]) * dx - np.cos(h[k]) * dy
    w_r, w_l = track.interp_width(s)
    inside = np.zeros((cy.size, cx.size), dtype=bool)
    inside[near] = (e <= w_r) & (e >= -w_l)
    return inside


def rasterize_track(track, resolution_m: float = 0.05, margin_m: float = 1.0) -> OccupancyGrid:
    """An occupancy grid made from a track's boundaries: free inside, occupied outside
    (``inside_cells``: `Track.is_inside` at every cell centre).

    For tracks that come without a map (the built-in ones). `track` is a shared.track.Track.
    """
    lo = np.minimum(track.left_boundary.min(0), track.right_boundary.min(0)) - margin_m
    hi = np.maximum(track.left_boundary.max(0), track.right_boundary.max(0)) + margin_m
    cols = int(np.ceil((hi[0] - lo[0]) / resolution_m))
    rows = int(np.ceil((hi[1] - lo[1]) / resolution_m))
    cx = lo[0] + (np.arange(cols) + 0.5) * resolution_m
    cy = lo[1] + (np.arange(rows) + 0.5) * resolution_m
    inside = inside_cells(track, cx, cy)
    cells = np.where(inside, FREE, OCCUPIED).astype(np.int8)
    cells.setflags(write=False)
    return OccupancyGrid(
        cells=cells,
        resolution_m=resolution_m,
        origin_xy_m=lo,
        source=f"{track.source} (rasterised)",
    )


def occupancy_for(track) -> OccupancyGrid:
    """The track's ROS map if its folder has one (the first ``*.yaml``), else a grid rasterised
    from its boundaries at 5 cm: the one grid the simulator's lidar and the bridge's
    particle filter share. `track` is a shared.track.Track."""
    src = Path(track.source)
    folder = src if src.is_dir() else src.parent
    if src.exists():
        maps = sorted(folder.glob("*.yaml"))
        if maps:
            return load_ros_map(maps[0])
    return rasterize_track(track, resolution_m=0.05)
