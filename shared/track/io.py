"""Loading tracks from the usual F1TENTH formats (the only module here that reads files).

Formats (see ``docs`` in the README):
- F1TENTH centreline CSV: header ``# x_m, y_m, w_tr_right_m, w_tr_left_m``, comma separated,
  the loop closed implicitly (last point about one step before the first).
- CiMPCC waypoint triple: ``*_track_centerline_waypoints.csv``, ``*_track_left_waypoints.csv``,
  ``*_track_right_waypoints.csv``, each ``x,y`` rows without header, the last row repeating the
  first. Widths are the distances from each centre point to its left / right points.
- A folder holding either of the above (F1TENTH ``<T>/<T>_centerline.csv`` or a triple).
- ``builtin:NAME`` or a bare built-in name for the tracks shipped in the package.
"""

from __future__ import annotations

from importlib import resources
from pathlib import Path

import numpy as np

from shared.track.errors import TrackError
from shared.track.geometry import Track

#: Names of the built-in tracks shipped with the package; the first is the default.
BUILTIN_TRACKS = ("paperlike", "gentle")
DEFAULT_TRACK = "builtin:paperlike"
F1TENTH_COLUMNS = ("x_m", "y_m", "w_tr_right_m", "w_tr_left_m")


def _read_numeric_rows(path: Path, delimiter: str, ncols: int) -> np.ndarray:
    """Read a numeric CSV (comment lines start with '#') into an (n, ncols) float array."""
    try:
        text = path.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise TrackError(str(path), f"cannot read file ({exc})") from exc
    rows = []
    for lineno, line in enumerate(text.splitlines(), start=1):
        stripped = line.strip()
        if not stripped or stripped.startswith("#"):
            continue
        parts = [p.strip() for p in stripped.split(delimiter)]
        if len(parts) != ncols:
            raise TrackError(str(path), f"line {lineno} has {len(parts)} columns, expected {ncols}")
        try:
            rows.append([float(p) for p in parts])
        except ValueError as exc:
            raise TrackError(str(path), f"line {lineno}: not a number ({exc})") from exc
    if not rows:
        raise TrackError(str(path), "no data rows")
    return np.asarray(rows, dtype=float)


def _check_header(path: Path) -> None:
    """Require the F1TENTH header naming the four columns (in order)."""
    try:
        with path.open(encoding="utf-8") as fh:
            first = fh.readline()
    except (OSError, UnicodeDecodeError) as exc:
        raise TrackError(str(path), f"cannot read file ({exc})") from exc
    if not first.lstrip().startswith("#"):
        return  # header-less files are accepted if they have four numeric columns
    names = [c.strip() for c in first.lstrip("# \t").strip().split(",")]
    missing = [c for c in F1TENTH_COLUMNS if c not in names]
    if missing:
        raise TrackError(str(path), f"missing column(s) {', '.join(missing)} in header {names}")
    if tuple(names[:4]) != F1TENTH_COLUMNS:
        raise TrackError(
            str(path), f"columns must be {', '.join(F1TENTH_COLUMNS)} in this order, got {names}"
        )


def _drop_closing_duplicate(xy: np.ndarray) -> np.ndarray:
    """Remove a last point that repeats the first (closed files repeat it)."""
    if xy.shape[0] > 1 and np.allclose(xy[0], xy[-1], atol=1e-9):
        return xy[:-1]
    return xy


def load_f1tenth_centerline(path: str | Path, name: str | None = None) -> Track:
    """Load an F1TENTH ``*_centerline.csv`` (x_m, y_m, w_tr_right_m, w_tr_left_m)."""
    path = Path(path)
    _check_header(path)
    data = _read_numeric_rows(path, ",", 4)
    keep = np.ones(len(data), dtype=bool)
    if len(data) > 1 and np.allclose(data[0, :2], data[-1, :2], atol=1e-9):
        keep[-1] = False
    data = data[keep]
    return Track(
        name=name or path.stem.removesuffix("_centerline"),
        xy=data[:, :2],
        w_right_m=data[:, 2],
        w_left_m=data[:, 3],
        source=str(path),
    )


def load_waypoint_triple(centre: str | Path, left: str | Path, right: str | Path) -> Track:
    """Load the CiMPCC centre / left / right ``x,y`` waypoint files into a Track.

    Widths are the distances from each centre point to the left and right points of the same
    row; the side of each file is checked against the driving direction.
    """
    centre, left, right = Path(centre), Path(left), Path(right)
    c = _drop_closing_duplicate(_read_numeric_rows(centre, ",", 2))
    lft = _drop_closing_duplicate(_read_numeric_rows(left, ",", 2))
    rgt = _drop_closing_duplicate(_read_numeric_rows(right, ",", 2))
    for path, arr in ((left, lft), (right, rgt)):
        if arr.shape != c.shape:
            raise TrackError(
                str(path), f"{arr.shape[0]} points but the centreline has {c.shape[0]}"
            )
    source = str(centre)
    if not (np.isfinite(lft).all() and np.isfinite(rgt).all()):
        raise TrackError(source, "non-finite boundary coordinate (NaN or inf)")
    # side check against the left normal of the centreline
    t = np.roll(c, -1, axis=0) - np.roll(c, 1, axis=0)
    n_left = np.stack([-t[:, 1], t[:, 0]], axis=1)
    n_left /= np.maximum(np.linalg.norm(n_left, axis=1, keepdims=True), 1e-12)
    off_l = np.einsum("ij,ij->i", lft - c, n_left)
    off_r = np.einsum("ij,ij->i", rgt - c, n_left)
    if np.median(off_l) < 0 < np.median(off_r):
        raise TrackError(
            str(left), "left waypoints lie to the right of the driving direction (files swapped?)"
        )
    name = centre.name.removesuffix(".csv").removesuffix("_track_centerline_waypoints")
    return Track(name=name, xy=c, w_right_m=-off_r, w_left_m=off_l, source=source)


def load_track_folder(folder: str | Path) -> Track:
    """Load the track held in a folder: a CiMPCC triple if present, else an F1TENTH centreline."""
    folder = Path(folder)
    triples = sorted(folder.glob("*_track_centerline_waypoints.csv"))
    if triples:
        stem = triples[0].name.removesuffix("_centerline_waypoints.csv")
        return load_waypoint_triple(
            triples[0],
            folder / f"{stem}_left_waypoints.csv",
            folder / f"{stem}_right_waypoints.csv",
        )
    centres = sorted(folder.glob("*_centerline.csv"))
    if centres:
        return load_f1tenth_centerline(centres[0])
    raise TrackError(
        str(folder), "no *_centerline.csv or *_track_centerline_waypoints.csv in this folder"
    )


def load_builtin(name: str) -> Track:
    """Load a built-in track shipped in the package (``paperlike`` or ``gentle``)."""
    if name not in BUILTIN_TRACKS:
        raise TrackError(
            f"builtin:{name}", f"unknown built-in track; choose one of {', '.join(BUILTIN_TRACKS)}"
        )
    ref = resources.files("shared.track") / "builtin" / f"{name}_centerline.csv"
    with resources.as_file(ref) as path:
        track = load_f1tenth_centerline(path, name=name)
    return Track(
        name=name,
        xy=track.xy,
        w_right_m=track.w_right_m,
        w_left_m=track.w_left_m,
        source=f"builtin:{name}",
    )


def load_track(spec: str | Path) -> Track:
    """Load a track from a built-in name, ``builtin:NAME``, a folder or a file.

    A file may be an F1TENTH centreline CSV or the centre file of a CiMPCC triple (its left and
    right files are found beside it). Raises TrackError naming the spec and the problem.
    """
    text = str(spec)
    if text.startswith("builtin:"):
        return load_builtin(text.removeprefix("builtin:"))
    path = Path(text).expanduser()
    if not path.exists():
        if text in BUILTIN_TRACKS:
            return load_builtin(text)
        raise TrackError(
            text,
            "no such file or folder, and not a built-in track "
            f"(built-in: {', '.join(BUILTIN_TRACKS)})",
        )
    if path.is_dir():
        return load_track_folder(path)
    if path.name.endswith("_track_centerline_waypoints.csv"):
        stem = path.name.removesuffix("_centerline_waypoints.csv")
        return load_waypoint_triple(
            path,
            path.with_name(f"{stem}_left_waypoints.csv"),
            path.with_name(f"{stem}_right_waypoints.csv"),
        )
    if path.suffix.lower() == ".csv":
        return load_f1tenth_centerline(path)
    raise TrackError(text, "unsupported track file (expected a .csv centreline or a folder)")
