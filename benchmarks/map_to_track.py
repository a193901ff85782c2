"""A track from a SLAM map: accuracy and cost of ``shared.track.from_map`` on the real maps.

For map416 (the CiMPCC authors' map, against their ``map416_track_centerline_waypoints.csv``)
and the six F1TENTH maps (against ``<T>_centerline.csv``), extracts the track with the
default settings (0.1 m spacing, the published line's driving direction, start nearest the
map origin) and prints per map:

- the map size [cells] and cell [m];
- extraction time: wall-clock median and p99 over ``--repeats`` runs and the median CPU
  time of this process [s] (``track_from_grid``, the ``Track``'s own validation included;
  the map file is read once, outside the clock; on a shared machine trust the CPU column);
- RMS and max distance from the extracted points to the published polyline and back
  [cells and m] (``distances_to_polyline``; "fwd" extracted -> published, "back" the reverse);
- width error: mean of the extracted (left + right) width minus the published, and the
  mean absolute difference [m];
- length: extracted and published [m] and their difference [%];
- median |kappa| of the extracted and the published line [1/m] (``Track.signed_curvature``
  at the default 0.1 m spacing): how smooth the extracted line is (before its smoothing
  spline the pixel staircase gave 0.14-0.22 1/m on the F1TENTH maps, their lines 0.003-0.014);
- "pub off middle": RMS distance of the PUBLISHED points from the middle of the map's free
  corridor, ``(d_infield - d_outside) / 2`` from the distance fields [cells]: how far the
  published line itself is from what the map shows (a floor for any extraction).

Reads ../shared/tracks (skips a map whose files are missing)::

    .venv/bin/python -m benchmarks.map_to_track
    .venv/bin/python -m benchmarks.map_to_track --repeats 5 --maps map416,Monza
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

from shared.track import load_ros_map, load_track
from shared.track.from_map import (
    MapTrackOptions,
    distances_to_polyline,
    find_ring,
    signed_area,
    track_from_grid,
    world_to_cell_frac,
)

TRACKS = Path(__file__).resolve().parents[1].parent / "shared" / "tracks"
F1TENTH = ("Austin", "Monza", "Oschersleben", "Silverstone", "Spielberg", "YasMarina")


def map_files(name: str) -> tuple[Path, Path]:
    """(map yaml, published centreline) of a map name."""
    if name == "map416":
        folder = TRACKS / "map416"
        return folder / "map416.yaml", folder / "map416_track_centerline_waypoints.csv"
    folder = TRACKS / "f1tenth" / name
    return folder / f"{name}_map.yaml", folder / f"{name}_centerline.csv"


def measure(name: str, repeats: int) -> dict[str, float] | None:
    """The figures of one map (None when its files are missing)."""
    yaml, ref_path = map_files(name)
    if not (yaml.is_file() and ref_path.is_file()):
        return None
    grid = load_ros_map(yaml)
    ref = load_track(ref_path)
    opts = MapTrackOptions(direction="ccw" if signed_area(ref.xy) > 0 else "cw")
    times, cpu = [], []
    track = None
    for _ in range(repeats):
        t0, c0 = time.perf_counter(), time.process_time()
        track = track_from_grid(grid, opts, name=name)
        times.append(time.perf_counter() - t0)
        cpu.append(time.process_time() - c0)
    assert track is not None
    fwd = distances_to_polyline(track.xy, ref.xy)
    back = distances_to_polyline(ref.xy, track.xy)
    # published width at the extracted points: nearest published point
    d2 = ((track.xy[:, None, :] - ref.xy[None, :, :]) ** 2).sum(axis=2)
    nearest = np.argmin(d2, axis=1)
    w_ext = track.w_left_m + track.w_right_m
    w_pub = (ref.w_left_m + ref.w_right_m)[nearest]
    res = grid.resolution_m
    off_middle = _off_middle_m(grid, ref.xy, opts)
    return {
        "rows": grid.shape[0], "cols": grid.shape[1], "cell_m": res,
        "t_med_s": float(np.median(times)), "t_p99_s": float(np.percentile(times, 99)),
        "cpu_med_s": float(np.median(cpu)),
        "rms_fwd_m": float(np.sqrt(np.mean(fwd**2))),
        "rms_back_m": float(np.sqrt(np.mean(back**2))),
        "max_m": float(max(fwd.max(), back.max())),
        "width_bias_m": float(np.mean(w_ext - w_pub)),
        "width_mae_m": float(np.mean(np.abs(w_ext - w_pub))),
        "length_m": track.length_m, "length_pub_m": ref.length_m,
        "pub_off_middle_m": off_middle,
        "kappa_med": float(np.median(np.abs(track.signed_curvature()))),
        "kappa_pub_med": float(np.median(np.abs(ref.signed_curvature()))),
    }


def _off_middle_m(grid, xy: np.ndarray, opts: MapTrackOptions) -> float:
    """RMS [m] of the distance of points from the middle of the map's free ring."""
    from scipy import ndimage

    ring = find_ring(grid, opts)
    d_in = ndimage.distance_transform_edt(~ring.hole)
    d_out = ndimage.distance_transform_edt(ring.region | ring.hole)
    rc = (world_to_cell_frac(grid, xy) - np.asarray(ring.offset_rc)).T
    a = ndimage.map_coordinates(d_in, rc, order=1, mode="nearest")
    b = ndimage.map_coordinates(d_out, rc, order=1, mode="nearest")
    off = 0.5 * (a - b) * grid.resolution_m
    return float(np.sqrt(np.mean(off**2)))


def main(argv: list[str] | None = None) -> int:
    """Print the table; returns 0 (1 when no map was found)."""
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--repeats", type=int, default=3, help="extractions per map (timing)")
    ap.add_argument("--maps", default=",".join(("map416", *F1TENTH)), help="comma list")
    args = ap.parse_args(argv)
    head = (f"{'map':13s} {'cells':>9s} {'cell m':>7s} {'wall med/p99 s':>15s} {'CPU s':>6s} "
            f"{'RMS fwd/back [cells]':>21s} {'RMS [m]':>8s} {'max [cells / m]':>16s} "
            f"{'width bias/MAE m':>17s} {'length / published m':>30s} {'pub off middle':>14s} "
            f"{'med |kappa| ext/pub 1/m':>24s}")
    print(head)
    found = 0
    for name in args.maps.split(","):
        r = measure(name.strip(), max(1, args.repeats))
        if r is None:
            print(f"{name:13s} (files missing under {TRACKS})")
            continue
        found += 1
        c = r["cell_m"]
        dl = 100.0 * (r["length_m"] / r["length_pub_m"] - 1.0)
        print(
            f"{name:13s} {r['rows']:>4.0f}x{r['cols']:<4.0f} {c:7.4f} "
            f"{r['t_med_s']:7.2f}/{r['t_p99_s']:<7.2f} {r['cpu_med_s']:6.2f} "
            f"{r['rms_fwd_m'] / c:10.2f}/{r['rms_back_m'] / c:<10.2f} "
            f"{max(r['rms_fwd_m'], r['rms_back_m']):8.3f} "
            f"{r['max_m'] / c:7.2f} / {r['max_m']:6.3f} "
            f"{r['width_bias_m']:+8.3f}/{r['width_mae_m']:<8.3f} "
            f"{r['length_m']:8.2f} / {r['length_pub_m']:7.2f} ({dl:+.2f} %) "
            f"{r['pub_off_middle_m'] / c:8.2f} cells "
            f"{r['kappa_med']:11.4f}/{r['kappa_pub_med']:<.4f}"
        )
    return 0 if found else 1


if __name__ == "__main__":
    sys.exit(main())
