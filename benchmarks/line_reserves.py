"""What each reserve of the raceline's line costs: its lap time against the car's limit with
every reserve, and with each one removed in turn.

    python -m benchmarks.line_reserves            # the identified car on map416 and paperlike
    python -m benchmarks.line_reserves --tracks map416,gen:11 --cars identified,default
    python -m benchmarks.line_reserves --poses truth,ekf,lidar

The raceline's minimum-time line (``services.planner.mintime.requests.raceline_request``, the
one the planner races, for the pose source's margin: ``for_pose_source``) keeps reserves the
car's limit (``limit_request``) does not: a footprint margin (``min_time_margin_m``, plus
``servo_margin_m`` for a slow servo and the pose source's ``ekf_margin_m`` /
``lidar_margin_m``), and on Pacejka tyres a slip reserve (``min_time_slip_fraction``) and a
friction-ellipse reserve (``min_time_ellipse_fraction``). A flying lap on the line can be no
faster than the line's own plan, so the line's ratio to the limit is the floor of the
robustness table's ratio for that cell (``benchmarks/robustness.py``; the rest is tracking).
Per track, car and pose source this prints the line's ratio and the ratio with each reserve
removed alone (the margin back to the limit's footprint margin, the slip and ellipse shares
to 1): how much of the floor each one is. Laps are read from the cache and solved into it
when missing (the variants are laps no planner races; each is solved once).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys

from benchmarks.robustness import BenchError, _track, config_for, load_overlay, resolve_tracks
from services.planner import for_pose_source
from services.planner.mintime.ocp import MinTimeError, MinTimeSettings
from services.planner.mintime.requests import LIMIT, limit_request, raceline_request
from services.planner.mintime.store import make_min_time_lap
from shared.evaluation.car_family import car_names

#: The variants: name -> the line's settings with that reserve removed (None: the line).
VARIANTS = ("line", "no margin", "no slip", "no ellipse")
#: ... and those of the high-speed reserve (``MinTimeSettings.reserve_*``), printed when a
#: line has it (a cap above ``min_time_reserve_speed_mps``, e.g. ``--v-max 10``): its
#: speed margin, its steering-rate cost, its yaw bound, the rear's own share, and the whole
#: ellipse reserve (both shares 1).
SPEED_VARIANTS = ("no speed margin", "no steer cost", "no yaw bound", "no rear share",
                  "no hs ellipse")


def variant(line: MinTimeSettings, limit: MinTimeSettings, name: str) -> MinTimeSettings:
    """`line`'s settings with the reserve `name` (``VARIANTS``, ``SPEED_VARIANTS``)
    removed: the margin back to `limit`'s, the slip or ellipse share to 1, the high-speed
    reserve's part off; "line": `line` itself."""
    changes = {
        "line": {},
        "no margin": {"margin_m": limit.margin_m},
        "no slip": {"slip_fraction": 1.0},
        "no ellipse": {"ellipse_fraction": 1.0},
        "no speed margin": {"reserve_margin_m": 0.0},
        "no steer cost": {"reserve_steering_weight_s": 0.0},
        "no yaw bound": {"reserve_yaw_pole_per_s": None},
        "no rear share": {"reserve_rear_fraction": None},
        "no hs ellipse": {"reserve_fraction": 1.0, "reserve_rear_fraction": None},
    }
    if name not in changes:
        raise ValueError(f"unknown variant {name!r}; choose from "
                         f"{', '.join(VARIANTS + SPEED_VARIANTS)}")
    return dataclasses.replace(line, **changes[name]) if changes[name] else line


def main(argv: list[str] | None = None) -> int:
    """Solve (or read) and print."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--tracks", default="map416,paperlike",
                    help="comma list of tracks as robustness takes them (groups, map416, "
                    "specs; default %(default)s)")
    ap.add_argument("--cars", default="identified",
                    help="comma list of robustness cars the planner knows (default %(default)s)")
    ap.add_argument("--poses", default="truth", help="comma list of truth, ekf, lidar")
    ap.add_argument("--v-max", type=float, default=None,
                    help="the cap [m/s] of the line and the limit (default the "
                    "configuration's 4.18; above min_time_reserve_speed_mps the high-speed "
                    "reserve's parts are priced too)")
    ap.add_argument("--config", default=None,
                    help="a TOML file of configuration tables laid over every car's (as "
                    "robustness takes it)")
    args = ap.parse_args(argv)
    try:
        extra = json.loads(load_overlay(args.config)) if args.config else {}
    except BenchError as exc:
        print(f"line_reserves: {exc}", file=sys.stderr)
        return 2
    try:
        cars = car_names(args.cars)
    except ValueError as exc:
        print(f"line_reserves: {exc}", file=sys.stderr)
        return 2
    poses = [p.strip() for p in args.poses.split(",") if p.strip()]
    try:
        specs = resolve_tracks(args.tracks)
    except BenchError as exc:
        print(f"line_reserves: {exc}", file=sys.stderr)
        return 2
    names = VARIANTS
    header_done = False
    for spec in specs:
        try:
            track = _track(spec)
        except ValueError as exc:  # TrackError: a file that is no track
            print(f"line_reserves: {exc}", file=sys.stderr)
            return 2
        for car in cars:
            cfg = config_for(car, args.v_max, None, extra or None)
            vehicle = cfg.vehicle
            lim_car, lim = limit_request(cfg.planner, vehicle)
            try:
                limit = make_min_time_lap(track, lim_car, lim, use=LIMIT, progress=None)
            except MinTimeError as exc:
                print(f"{track.name:<12} {car:<11} no limit: {exc}")
                continue
            for pose in poses:
                try:
                    settings = for_pose_source(cfg.planner, pose)
                except ValueError as exc:
                    print(f"line_reserves: {exc}", file=sys.stderr)
                    return 2
                line_car, line = raceline_request(settings, vehicle)
                if not header_done:
                    if line.reserve_active and vehicle.tyre_model != "linear":
                        names = VARIANTS + SPEED_VARIANTS
                    print(f"{'track':<12} {'car':<11} {'pose':<6} {'limit [s]':>9} "
                          + " ".join(f"{v:>15}" for v in names) + "   margin [m]")
                    header_done = True
                cells = []
                for name in names:
                    try:
                        lap = make_min_time_lap(track, line_car, variant(line, lim, name),
                                                progress=None)
                        cells.append(f"{lap.lap_time_s / limit.lap_time_s:>15.4f}")
                    except MinTimeError:
                        cells.append(f"{'infeasible':>15}")
                print(f"{track.name:<12} {car:<11} {pose:<6} {limit.lap_time_s:>9.3f} "
                      + " ".join(cells) + f"   {line.margin_m:.3f}", flush=True)
    print("ratio = the line's own lap time / the car's limit (the floor of the robustness "
          "table's ratio); each column after 'line' removes that reserve alone")
    return 0


if __name__ == "__main__":
    sys.exit(main())
