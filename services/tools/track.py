"""``racestack track --from-map MAP.yaml --out DIR``: a track from a SLAM map (the shell).

Extracts the centreline and the widths of a ROS map_server occupancy map (Cartographer,
slam_toolbox, the F1TENTH maps) with ``shared.track.from_map``, then writes
``DIR/<name>_centerline.csv`` (F1TENTH format, what ``--track`` reads) and
``DIR/<name>_from_map.png`` (the result over the map). The same extraction runs when a
``MAP.yaml`` is given as ``--track`` or as ``[track] source``.

Driving direction: that of the centreline published beside the map if there is one
(``<stem>_centerline.csv`` or ``*_track_centerline_waypoints.csv``), else ``--direction`` is
required (exit code 2 and one line saying so): a map alone does not tell which way the car
drives (guessing from the map frame's x axis, where SLAM started facing, picked the published
direction on only 4 of the 7 maps with a published line), and a wrong guess races the track
backwards without a word. ``--direction`` given beside a published line overrides it. The
first point is the centreline point nearest ``--start`` or, without
it, nearest the map frame's origin (0, 0) - where the SLAM run usually started.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from shared.track.errors import TrackError
from shared.track.from_map import (
    MapTrackOptions,
    closed_length,
    signed_area,
    symmetric_rms_max,
    track_from_grid,
)
from shared.track.geometry import Track
from shared.track.io import published_centerline_beside, write_f1tenth_centerline
from shared.track.occupancy import FREE, OCCUPIED, OccupancyGrid, load_ros_map

__all__ = ["build_parser", "draw_track_over_map", "main"]


def _xy_pair(text: str) -> tuple[float, float]:
    """argparse type of ``--start X,Y`` [m]."""
    parts = text.split(",")
    try:
        x, y = (float(p) for p in parts)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected X,Y in metres, got {text!r}") from None
    if not (np.isfinite(x) and np.isfinite(y)):
        raise argparse.ArgumentTypeError(f"expected finite X,Y, got {text!r}")
    return x, y


def _positive_m(text: str) -> float:
    try:
        v = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a length in metres, got {text!r}") from None
    if not (np.isfinite(v) and 0.0 < v <= 5.0):
        raise argparse.ArgumentTypeError(f"expected a length in (0, 5] m, got {text!r}")
    return v


def _smoothing_cells(text: str) -> float:
    try:
        v = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number of cells, got {text!r}") from None
    if not (np.isfinite(v) and 0.0 <= v <= 5.0):
        raise argparse.ArgumentTypeError(f"expected a number of cells in [0, 5], got {text!r}")
    return v


def build_parser(ap: argparse.ArgumentParser | None = None) -> argparse.ArgumentParser:
    """The ``racestack track`` arguments (added to `ap`, or a new parser)."""
    ap = ap or argparse.ArgumentParser(prog="racestack track", description=__doc__)
    ap.add_argument(
        "--from-map", required=True, metavar="MAP.yaml",
        help="ROS map_server map (yaml + PGM/PNG image), e.g. from Cartographer or slam_toolbox",
    )
    ap.add_argument(
        "--out", required=True, metavar="DIR",
        help="output folder for <name>_centerline.csv and <name>_from_map.png",
    )
    ap.add_argument(
        "--direction", choices=("cw", "ccw"),
        help="driving direction, clockwise or counter-clockwise around the infield (default: "
        "that of the centreline published beside the map; required without one)",
    )
    ap.add_argument(
        "--start", type=_xy_pair, metavar="X,Y",
        help="start point [m, map frame]: the first point is the centreline point nearest it "
        "(also picks the loop when the map has several); default: nearest (0, 0)",
    )
    ap.add_argument(
        "--spacing-m", type=_positive_m, default=MapTrackOptions.spacing_m,
        help="spacing of the centreline points [m] (default %(default)s)",
    )
    ap.add_argument(
        "--smoothing-cells", type=_smoothing_cells, default=MapTrackOptions.smoothing_cells,
        help="RMS distance [map cells] the periodic smoothing spline may keep from the "
        "pixel centreline; 0: no smoothing (default %(default)s)",
    )
    ap.add_argument("--name", help="track name for the file names (default: the map's stem "
                    "without _map)")
    return ap


def draw_track_over_map(grid: OccupancyGrid, track: Track, path: Path, title: str) -> None:
    """Save a PNG of the map (free white, occupied black, unknown grey) with the track's
    centreline, borders, start point and driving direction, cropped to the track + 1 m."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    rows, cols = grid.shape
    res = grid.resolution_m
    x0, y0 = grid.origin_xy_m
    shade = np.where(grid.cells == FREE, 1.0, np.where(grid.cells == OCCUPIED, 0.0, 0.75))
    borders = np.vstack([track.left_boundary, track.right_boundary])
    lo = borders.min(axis=0) - 1.0
    hi = borders.max(axis=0) + 1.0
    span = hi - lo
    width_in = 10.0
    fig, ax = plt.subplots(figsize=(width_in, max(4.0, width_in * span[1] / span[0])))
    ax.imshow(
        shade, origin="lower", cmap="gray", vmin=0.0, vmax=1.0, interpolation="nearest",
        extent=(x0, x0 + cols * res, y0, y0 + rows * res),
    )
    closed = np.vstack([track.xy, track.xy[:1]])
    ax.plot(closed[:, 0], closed[:, 1], color="tab:blue", lw=1.6, label="centreline")
    for edge, label in ((track.left_boundary, "left border"),
                        (track.right_boundary, "right border")):
        e = np.vstack([edge, edge[:1]])
        ax.plot(e[:, 0], e[:, 1], lw=1.0, label=label,
                color="tab:orange" if label.startswith("left") else "tab:red")
    ax.plot(*track.xy[0], marker="o", ms=9, color="tab:green", ls="none", label="start")
    k = max(1, round(0.04 * float(np.hypot(*span)) / track.spacing_m))  # 4 % of the view
    ax.annotate(
        "", xy=track.xy[k], xytext=track.xy[0],
        arrowprops={"arrowstyle": "-|>", "color": "tab:green", "lw": 2.5, "mutation_scale": 20},
    )
    ax.set_xlim(lo[0], hi[0])
    ax.set_ylim(lo[1], hi[1])
    ax.set_aspect("equal")
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.set_title(title)
    ax.legend(loc="best", fontsize=8, framealpha=0.9)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def _run(args: argparse.Namespace) -> int:
    from shared.outdir import writable_dir_problem

    map_path = Path(args.from_map).expanduser()
    grid = load_ros_map(map_path)
    published = published_centerline_beside(map_path)
    direction = args.direction
    if direction is None and published is None:
        print(f"racestack: error: no centreline beside {map_path} tells the driving "
              "direction; pass --direction cw or --direction ccw (clockwise or "
              "counter-clockwise around the infield)", file=sys.stderr)
        return 2
    if direction is None:
        assert published is not None
        direction = "ccw" if signed_area(published[1]) > 0 else "cw"
        print(f"direction: {direction} (that of {published[0]}; --direction overrides it)")
    options = MapTrackOptions(
        direction=direction, spacing_m=args.spacing_m, smoothing_cells=args.smoothing_cells,
        start_xy_m=args.start,
    )
    name = args.name or map_path.stem.removesuffix("_map")
    track = track_from_grid(grid, options, name=name)
    out = Path(args.out).expanduser()
    problem = writable_dir_problem(out)
    if problem:
        print(f"racestack: error: {problem}", file=sys.stderr)
        return 2
    csv_path = out / f"{name}_centerline.csv"
    png_path = out / f"{name}_from_map.png"
    write_f1tenth_centerline(csv_path, track)
    width = track.w_left_m + track.w_right_m
    title = (f"{name}: {track.length_m:.1f} m, width {width.min():.2f}-{width.max():.2f} m, "
             f"{direction}")
    draw_track_over_map(grid, track, png_path, title)
    print(f"{name}: {track.n_points} points every {track.spacing_m:.3f} m, length "
          f"{track.length_m:.2f} m, {direction}, start ({track.xy[0, 0]:.2f}, "
          f"{track.xy[0, 1]:.2f}) m")
    print(f"  widths left {track.w_left_m.min():.2f}-{track.w_left_m.max():.2f} m, right "
          f"{track.w_right_m.min():.2f}-{track.w_right_m.max():.2f} m "
          f"(map cell {grid.resolution_m:g} m)")
    if published is not None:
        ref_path, ref_xy = published
        rms, worst = symmetric_rms_max(track.xy, ref_xy)
        cell = grid.resolution_m
        print(f"  vs the published centreline {ref_path}: RMS {rms / cell:.2f} cells "
              f"({rms:.3f} m), max {worst / cell:.2f} cells, length "
              f"{closed_length(ref_xy):.2f} m")
    print(f"wrote {csv_path}")
    print(f"wrote {png_path}")
    return 0


def main(argv: list[str] | None = None, args: argparse.Namespace | None = None) -> int:
    """``racestack track``; returns the exit code (2: a bad map or output folder)."""
    if args is None:
        args = build_parser().parse_args(argv)
    try:
        return _run(args)
    except TrackError as exc:
        print(f"racestack: error: {exc}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
