"""Minimum-time lap of the simulator's car: lap time, solve time, iterations, grid check.

    .venv/bin/python -m benchmarks.mintime                    # map416 and paperlike at 4.18
    .venv/bin/python -m benchmarks.mintime --v-max 4.18,10    # and uncapped (10 m/s)
    .venv/bin/python -m benchmarks.mintime --grid             # + ds 0.05 / 0.1 / 0.2 on map416
    .venv/bin/python -m benchmarks.mintime --spielberg        # + Spielberg (~343 m)

Every problem is solved afresh (no cache), so the solve times are real. Prints figures
only; nothing here asserts (tests never time anything). Reference figures from an
independent solve with the simulator's previous ``linear_saturated`` model
(``../shared/docs/limits-and-anchors.md``): map416 7.171 s, paperlike 9.561 s at 4.18 m/s
(uncapped 6.198 / 7.503 s).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from services.planner.mintime.ocp import MinTimeLap, MinTimeSettings, solve_min_time
from shared.config import load_config
from shared.track import load_track

TRACKS = Path(__file__).resolve().parents[1].parent / "shared" / "tracks"
#: The grid check's spacings [m] and tolerance (relative spread of the lap times).
GRID_DS_M = (0.05, 0.1, 0.2)
GRID_TOLERANCE = 0.002


def _row(name: str, lap: MinTimeLap) -> str:
    return (
        f"{name:<10} {lap.v_max_mps:>6g} {lap.ds_m:>7.4f} {lap.lap_time_s:>9.4f} "
        f"{lap.v_mps.max():>6.2f} {lap.iterations:>6d} {lap.solve_time_s:>8.1f} "
        f"{lap.point_mass_lap_time_s:>9.3f} {lap.min_clearance_m:>7.4f}  {lap.status}"
    )


HEADER = (
    f"{'track':<10} {'v_max':>6} {'ds [m]':>7} {'lap [s]':>9} {'peak':>6} {'iters':>6} "
    f"{'solve[s]':>8} {'pm lap[s]':>9} {'clear':>7}  status"
)


def main(argv: list[str] | None = None) -> int:
    """Solve and print."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--v-max", default="4.18", help="comma list of top speeds [m/s]")
    ap.add_argument("--tracks", default="map416,paperlike", help="comma list (map416 = shared)")
    ap.add_argument("--grid", action="store_true", help="grid check on map416 at the first v_max")
    ap.add_argument("--spielberg", action="store_true", help="also Spielberg (several minutes)")
    args = ap.parse_args(argv)
    vehicle = load_config(None).vehicle
    specs = {"map416": str(TRACKS / "map416"), "paperlike": "paperlike"}
    names = [t.strip() for t in args.tracks.split(",") if t.strip()]
    if args.spielberg:
        specs["spielberg"] = str(TRACKS / "f1tenth" / "Spielberg")
        names.append("spielberg")
    v_maxes = [float(v) for v in args.v_max.split(",")]
    needs_shared = args.grid or any(n in ("map416", "spielberg") for n in names)
    if needs_shared and not (TRACKS / "map416").is_dir():
        print(f"needs the shared track data at {TRACKS}", file=sys.stderr)
        return 2
    print(f"vehicle: {vehicle.preset}, tyres {vehicle.tyre_model}; margin "
          f"{MinTimeSettings().margin_m} m; 'pm lap' = quasi-steady point mass on the centreline")
    print(HEADER)
    for name in names:
        track = load_track(specs.get(name, name))
        for v_max in v_maxes:
            lap = solve_min_time(track, vehicle, MinTimeSettings(v_max_mps=v_max))
            print(_row(name, lap), flush=True)
    if args.grid:
        track = load_track(specs["map416"])
        times = []
        for ds in GRID_DS_M:
            lap = solve_min_time(track, vehicle, MinTimeSettings(v_max_mps=v_maxes[0], ds_m=ds))
            times.append(lap.lap_time_s)
            print(_row("map416", lap), flush=True)
        spread = (max(times) - min(times)) / min(times)
        verdict = "within" if spread <= GRID_TOLERANCE else "OUTSIDE"
        print(
            "grid check map416: "
            + " / ".join(f"{t:.4f}" for t in times)
            + f" s at ds {' / '.join(f'{d:g}' for d in GRID_DS_M)} m: spread "
            f"{100 * spread:.3f} % ({verdict} {100 * GRID_TOLERANCE:g} %)"
        )
    return 0


if __name__ == "__main__":
    sys.exit(main())
