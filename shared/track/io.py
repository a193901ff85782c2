"""Loading tracks from the usual F1TENTH formats (the only module here that reads files;
it also writes the F1TENTH raceline CSV that it reads).

Formats (see ``docs`` in the README):
- F1TENTH centreline CSV: header ``# x_m, y_m, w_tr_right_m, w_tr_left_m``, comma separated,
  the loop closed implicitly (last point about one step before the first).
- CiMPCC waypoint triple: ``*_track_centerline_waypoints.csv``, ``*_track_left_waypoints.csv``,
  ``*_track_right_waypoints.csv``, each ``x,y`` rows without header, the last row repeating the
  first. Widths are the distances from each centre point to its left / right points.
- A folder holding either of the above (F1TENTH ``<T>/<T>_centerline.csv`` or a triple).
- A ROS map_server map ``MAP.yaml`` (``load_map_track``): the centreline and widths are
  extracted from its free space (``shared.track.from_map``); written back with
  ``write_f1tenth_centerline``.
- ``builtin:NAME`` or a bare built-in name for the tracks shipped in the package.
- ``gen:SEED`` for a track of racestack's seeded generator (``shared.track.generator``).
- F1TENTH raceline CSV (``load_f1tenth_raceline`` / ``write_f1tenth_raceline``): two
  comment lines, then ``# s_m; x_m; y_m; psi_rad; kappa_radpm; vx_mps; ax_mps2``, then
  ``;`` separated rows.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from importlib import resources
from pathlib import Path

import numpy as np

from shared.track.errors import TrackError
from shared.track.geometry import MIN_POINTS, Track

log = logging.getLogger(__name__)

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


#: What a track argument may be, for the command lines' help.
TRACK_SPEC_HELP = (
    "a built-in name (paperlike, gentle), gen:SEED (a generated track), a folder, an F1TENTH "
    "centreline CSV or a ROS map's MAP.yaml"
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


def load_generated(spec: str) -> Track:
    """The generated track of ``gen:SEED`` (SEED a non-negative integer)."""
    from shared.track.generator import generate_track

    seed = spec.removeprefix("gen:").strip()
    if not (seed.isascii() and seed.isdigit()):
        raise TrackError(spec, "expected gen:SEED with SEED an integer >= 0, e.g. gen:7")
    return generate_track(int(seed))


def load_track(spec: str | Path) -> Track:
    """Load a track from a built-in name, ``builtin:NAME``, ``gen:SEED``, a folder, a file or
    a ROS map.

    A file may be an F1TENTH centreline CSV or the centre file of a CiMPCC triple (its left and
    right files are found beside it); ``gen:SEED`` is ``shared.track.generator.generate_track``
    of the integer SEED. Raises TrackError naming the spec and the problem.
    """
    text = str(spec)
    if text.startswith("builtin:"):
        return load_builtin(text.removeprefix("builtin:"))
    if text.startswith("gen:"):
        return load_generated(text)
    path = Path(text).expanduser()
    if not path.exists():
        if text in BUILTIN_TRACKS:
            return load_builtin(text)
        raise TrackError(
            text,
            "no such file or folder, and not a built-in track "
            f"(built-in: {', '.join(BUILTIN_TRACKS)}; or builtin:NAME, gen:SEED for a "
            "generated track, a folder, a centreline CSV or a ROS map .yaml)",
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
    if path.suffix.lower() in (".yaml", ".yml"):
        return load_map_track(path)
    raise TrackError(
        text, "unsupported track file (expected a .csv centreline, a ROS map .yaml or a folder)"
    )


def published_centerline_beside(map_yaml: str | Path) -> tuple[Path, np.ndarray] | None:
    """The centreline published beside a ROS map, if any: ``<stem>_centerline.csv`` (the
    map's stem without ``_map``) or a CiMPCC ``*_track_centerline_waypoints.csv`` in its
    folder, as (its path, its (n, 2) points [m] in its driving order, not validated as a
    Track); None when there is none or it does not read."""
    path = Path(map_yaml)
    stem = path.stem.removesuffix("_map")
    f1tenth = path.with_name(f"{stem}_centerline.csv")
    candidates = [(f1tenth, 4)] if f1tenth.is_file() else []
    candidates += [(p, 2) for p in sorted(path.parent.glob("*_track_centerline_waypoints.csv"))]
    for candidate, ncols in candidates:
        try:
            xy = _drop_closing_duplicate(_read_numeric_rows(candidate, ",", ncols)[:, :2])
        except TrackError:
            return None
        return (candidate, xy) if xy.shape[0] >= 3 and np.isfinite(xy).all() else None
    return None


def load_map_track(map_yaml: str | Path, options=None) -> Track:
    """The track extracted from a ROS map_server map (``shared.track.from_map``).

    `options` is a ``MapTrackOptions``; None: the defaults, with the driving direction of
    the centreline published beside the map (``published_centerline_beside``) if there is
    one, else counter-clockwise, with a warning saying it was guessed (one line; ``racestack
    track --from-map MAP --direction cw`` makes a clockwise track). Raises TrackError
    naming the map and the problem.
    """
    from shared.track.from_map import MapTrackOptions, signed_area, track_from_grid
    from shared.track.occupancy import load_ros_map

    path = Path(map_yaml)
    if options is None:
        published = published_centerline_beside(path)
        if published is None:
            log.warning(
                "direction: ccw (guessed: no centreline beside %s; for clockwise make the "
                "track with racestack track --from-map %s --direction cw --out DIR)", path, path
            )
        direction = "ccw" if published is None or signed_area(published[1]) > 0 else "cw"
        options = MapTrackOptions(direction=direction)
    grid = load_ros_map(path)
    name = path.stem.removesuffix("_map")
    return track_from_grid(grid, options, name=name)


def write_f1tenth_centerline(path: str | Path, track: Track) -> None:
    """Write `track` as an F1TENTH centreline CSV (``# x_m, y_m, w_tr_right_m, w_tr_left_m``,
    6 decimals [m], the loop closed implicitly), atomically (a temporary file, then a rename)."""
    path = Path(path)
    lines = ["# " + ", ".join(F1TENTH_COLUMNS)]
    rows = np.column_stack([track.xy, track.w_right_m, track.w_left_m])
    lines += [", ".join(f"{v:.6f}" for v in row) for row in rows]
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_text("\n".join(lines) + "\n", encoding="utf-8")
    tmp.replace(path)


#: Columns of the F1TENTH raceline CSV (``<T>_raceline.csv``), in order.
RACELINE_COLUMNS = ("s_m", "x_m", "y_m", "psi_rad", "kappa_radpm", "vx_mps", "ax_mps2")


@dataclass(frozen=True, eq=False)
class RacelineTable:
    """A racing line with its speed profile, as in the F1TENTH ``<T>_raceline.csv``.

    Attributes (each an (n,) array, one row per point, the loop closed implicitly):
        s_m: arc length along the line [m], increasing from its first point.
        x_m, y_m: position [m]; psi_rad: heading of the line from the x axis [rad] in
            [0, 2 pi); kappa_radpm: curvature [1/m] (left +); vx_mps: speed [m/s];
        ax_mps2: longitudinal acceleration [m/s^2].
        source: the file it came from (or where it is going).
    """

    s_m: np.ndarray
    x_m: np.ndarray
    y_m: np.ndarray
    psi_rad: np.ndarray
    kappa_radpm: np.ndarray
    vx_mps: np.ndarray
    ax_mps2: np.ndarray
    source: str = "<memory>"

    def columns(self) -> np.ndarray:
        """(n, 7) array in ``RACELINE_COLUMNS`` order."""
        return np.column_stack([getattr(self, c) for c in RACELINE_COLUMNS])


def load_f1tenth_raceline(path: str | Path) -> RacelineTable:
    """Read an F1TENTH raceline CSV: comment lines (``#``), the last of which names the
    columns ``s_m; x_m; y_m; psi_rad; kappa_radpm; vx_mps; ax_mps2``, then ``;`` separated
    rows. Raises TrackError naming the file and the problem (missing header, a wrong column
    count, a non-number, NaN, fewer than ``MIN_POINTS`` rows, s not increasing)."""
    path = Path(path)
    try:
        lines = path.read_text(encoding="utf-8").splitlines()
    except (OSError, UnicodeDecodeError) as exc:
        raise TrackError(str(path), f"cannot read file ({exc})") from exc
    header = [ln for ln in lines if ln.lstrip().startswith("#")]
    names = [c.strip() for c in header[-1].lstrip("# \t").split(";")] if header else []
    if tuple(names) != RACELINE_COLUMNS:
        raise TrackError(str(path), f"expected a '# {'; '.join(RACELINE_COLUMNS)}' header line")
    data = _read_numeric_rows(path, ";", len(RACELINE_COLUMNS))
    if len(data) < MIN_POINTS:
        raise TrackError(str(path), f"only {len(data)} rows; at least {MIN_POINTS} are needed")
    if not np.all(np.isfinite(data)):
        bad = int(np.flatnonzero(~np.isfinite(data).all(axis=1))[0])
        raise TrackError(str(path), f"non-finite value (NaN or inf) in data row {bad + 1}")
    if np.any(np.diff(data[:, 0]) <= 0.0):
        raise TrackError(str(path), "s_m must increase from row to row")
    return RacelineTable(*(data[:, i].copy() for i in range(len(RACELINE_COLUMNS))),
                         source=str(path))


def write_f1tenth_raceline(
    path: str | Path, table: RacelineTable, comments: tuple[str, str] = ("", "")
) -> None:
    """Write `table` as an F1TENTH raceline CSV (two free comment lines, the column line,
    then ``;`` separated rows, 7 decimals), atomically (a temporary file, then a rename)."""
    path = Path(path)
    lines = [f"# {comments[0]}".rstrip(), f"# {comments[1]}".rstrip(),
             "# " + "; ".join(RACELINE_COLUMNS)]
    lines += [";".join(f"{v:.7f}" for v in row) for row in table.columns()]
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_text("\n".join(lines) + "\n", encoding="utf-8")
    tmp.replace(path)
