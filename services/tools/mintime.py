"""``racestack mintime``: the minimum-time lap of the car, written to a folder.

    racestack mintime [--for limit|cimpcc-line|raceline] --track T [--config F]
                      [--v-max V] [--ds D] [--margin M] [--simulated-car] [--cache DIR]
                      --out DIR

The car is the configuration's ``[vehicle]`` (the car the planners believe);
``--simulated-car`` (only with ``--for limit``) solves the limit of the car the simulator
races instead (``[simulator.vehicle]`` when it overrides ``[vehicle]``: the bench's
reference of a model-mismatch run).

Which lap (``--for``, ``services.planner.mintime.requests``): ``limit`` (default) the car's
limit, the bench's reference (top speed ``[planner.cimpcc] v_up_mps[0]``, or ``--v-max``,
``--ds``, ``--margin``); ``cimpcc-line`` the line that method contours and ``raceline``
the raceline baseline's line, each exactly as the stack's planner of that configuration reads
it (settings from ``[planner.cimpcc_line]`` / ``[planner.raceline]``, no overrides; the
raceline's margin widened for ``[localization] pose_source``:
``services.planner.for_stack``). The lap is the artefact the planner process reads: solved
once per track, car and settings and stored in the cache (``services.planner.mintime.store``;
``--cache`` its base folder, default ``$RACESTACK_CACHE`` or ``~/.cache/racestack``).

Writes ``DIR/mintime.json`` (lap time, settings, solver figures), ``DIR/raceline.csv`` (the
driven line in the F1TENTH raceline format, readable with
``shared.track.load_f1tenth_raceline``), ``DIR/mintime_line.{pdf,svg,png}`` (the line on
the track coloured by speed) and ``DIR/mintime_speed.{pdf,svg,png}`` (speed and acceleration
over s), each figure as vector PDF and SVG beside a 300 dpi PNG
(``shared.evaluation.plotting.save_figure``, as the bench's figures).
Bad input (unknown track, unwritable folder, bad numbers, no feasible lap) is one line on
stderr and exit code 2.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

from services.planner import MIN_TIME_CODE_VERSION as CODE_VERSION
from services.planner import MIN_TIME_LIMIT as LIMIT
from services.planner import MIN_TIME_USES as USES
from services.planner import (
    MinTimeLap,
    MinTimeSettings,
    for_stack,
    make_min_time_lap,
    request_for,
)
from shared.config import ConfigError, load_config
from shared.config.methods import RACELINE
from shared.config.vehicle import DynamicVehicleParams
from shared.evaluation.plotting import FORMATS, pyplot, save_figure
from shared.outdir import writable_dir_problem
from shared.track import (
    TRACK_SPEC_HELP,
    RacelineTable,
    Track,
    TrackError,
    load_track,
    write_f1tenth_raceline,
)

PROG = "racestack mintime"


class MinTimeArgumentError(ValueError):
    """A command-line value is wrong (reported as one line, exit code 2)."""


def raceline_table(lap: MinTimeLap) -> RacelineTable:
    """The lap's driven line as an F1TENTH raceline table (CoG path, course, speed, dv/dt)."""
    return RacelineTable(
        lap.s_m, lap.x_m, lap.y_m, lap.psi_rad, lap.kappa_radpm, lap.v_mps, lap.ax_mps2
    )


def mintime_document(
    lap: MinTimeLap, track: Track, vehicle: DynamicVehicleParams, use: str = LIMIT
) -> dict:
    """The ``mintime.json`` document (plain JSON values); `vehicle` the car the lap was
    solved for, `use` which lap it is (``requests.USES``)."""
    return {
        "for": use,
        "track": lap.track_name,
        "track_source": track.source,
        "track_length_m": lap.track_length_m,
        "reference_length_m": lap.reference_length_m,
        "lap_time_s": lap.lap_time_s,
        "v_max_mps": lap.v_max_mps,
        "peak_speed_mps": float(lap.v_mps.max()),
        "mean_speed_mps": lap.track_length_m / lap.lap_time_s,  # centreline / lap, as the bench
        "tyre_model": lap.tyre_model,
        "status": lap.status,
        "success": lap.success,
        "iterations": lap.iterations,
        "solve_time_s": lap.solve_time_s,
        "cache_hit": lap.cache_hit,
        "ds_m": lap.ds_m,
        "grid_points": len(lap.s_ref_m),
        "margin_m": lap.margin_m,
        "min_clearance_m": lap.min_clearance_m,
        "max_abs_offset_m": float(np.abs(lap.n_m).max()),
        "point_mass_lap_time_s": lap.point_mass_lap_time_s,
        "code_version": CODE_VERSION,
        "vehicle": vehicle.model_dump(),
    }


def fig_line(lap: MinTimeLap, track: Track, path: Path) -> None:
    """The optimal line on the track, coloured by speed (``path``'s stem as PDF, SVG and
    a 300 dpi PNG: ``save_figure``)."""
    fig, ax = pyplot().subplots(figsize=(8, 7))
    for b in (track.left_boundary, track.right_boundary):
        loop = np.vstack([b, b[:1]])
        ax.plot(loop[:, 0], loop[:, 1], color="0.2", lw=1.0)
    centre = np.vstack([track.xy, track.xy[:1]])
    ax.plot(centre[:, 0], centre[:, 1], color="0.7", lw=0.6, ls="--")
    pts = ax.scatter(lap.x_m, lap.y_m, c=lap.v_mps, s=6, cmap="turbo")
    fig.colorbar(pts, ax=ax, label="speed [m/s]")
    ax.set_aspect("equal")
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.set_title(
        f"minimum-time lap on {lap.track_name}: {lap.lap_time_s:.3f} s "
        f"(v_max {lap.v_max_mps:g} m/s, {lap.tyre_model})"
    )
    fig.tight_layout()
    save_figure(fig, path)


def fig_speed(lap: MinTimeLap, path: Path) -> None:
    """Speed and its rate over the driven line's arc length (PDF, SVG and PNG)."""
    fig, (a, b) = pyplot().subplots(2, 1, figsize=(9, 5.5), sharex=True)
    a.plot(lap.s_m, lap.v_mps, color="C0", label="speed")
    a.axhline(lap.v_max_mps, color="0.5", ls=":", label=f"v_max {lap.v_max_mps:g} m/s")
    a.set_ylabel("speed [m/s]")
    a.legend(loc="lower right")
    b.plot(lap.s_m, lap.ax_mps2, color="C3", lw=1.0, label="dv/dt")
    b.plot(lap.s_m, lap.inputs[:, 1], color="C2", lw=0.8, ls="--", label="demand a")
    b.set_ylabel("[m/s^2]")
    b.set_xlabel("s along the driven line [m]")
    b.legend(loc="lower right")
    fig.suptitle(f"minimum-time lap on {lap.track_name}: {lap.lap_time_s:.3f} s")
    fig.tight_layout()
    save_figure(fig, path)


def write_outputs(
    lap: MinTimeLap,
    track: Track,
    vehicle: DynamicVehicleParams,
    out_dir: Path,
    figures: bool = True,
    use: str = LIMIT,
) -> dict[str, Any]:
    """Write mintime.json, raceline.csv and the figures; returns the JSON document."""
    doc = mintime_document(lap, track, vehicle, use)
    comments = (
        f"minimum-time lap of the car (preset {vehicle.preset}) on {lap.track_name}: "
        f"{lap.lap_time_s:.4f} s",
        f"v_max {lap.v_max_mps:g} m/s, tyres {lap.tyre_model}, ds {lap.ds_m:.4f} m, "
        f"margin {lap.margin_m:g} m, {CODE_VERSION}",
    )
    write_f1tenth_raceline(out_dir / "raceline.csv", raceline_table(lap), comments)
    files = ["mintime.json", "raceline.csv"]
    if figures:
        fig_line(lap, track, out_dir / "mintime_line.png")
        fig_speed(lap, out_dir / "mintime_speed.png")
        files += [f"{stem}.{fmt}" for stem in ("mintime_line", "mintime_speed")
                  for fmt in FORMATS]
    doc["files"] = files
    tmp = out_dir / "mintime.json.tmp"
    tmp.write_text(json.dumps(doc, indent=2) + "\n", encoding="utf-8")
    tmp.replace(out_dir / "mintime.json")
    return doc


def _number(text: str | None, name: str) -> float | None:
    if text is None:
        return None
    try:
        value = float(text)
    except ValueError:
        raise MinTimeArgumentError(f"{name} must be a number, got {text!r}") from None
    if not math.isfinite(value):
        raise MinTimeArgumentError(f"{name} must be finite, got {text!r}")
    return value


def _say(line: str) -> None:
    """A progress line on stdout (stderr holds only the one-line errors)."""
    print(line, flush=True)


def _check_out_dir(path: Path) -> None:
    problem = writable_dir_problem(path)
    if problem:
        raise MinTimeArgumentError(problem)


def build_parser(ap: argparse.ArgumentParser | None = None) -> argparse.ArgumentParser:
    """Arguments of ``racestack mintime`` (numbers are checked by ``main``, one line each)."""
    ap = ap or argparse.ArgumentParser(prog=PROG, description=__doc__.splitlines()[0])
    ap.add_argument("--for", dest="use", choices=USES, default=LIMIT,
                    help="which lap: the car's limit (default; the bench's reference), the "
                    "line cimpcc-line contours or the raceline baseline's line (the artefact "
                    "the planner of this configuration reads), or that baseline's out-lap "
                    "line (a car with a slow servo and [planner.raceline] "
                    "flying_servo_margin_m)")
    ap.add_argument("--config", help="TOML configuration file (its [vehicle] car; default: "
                    "the built-in configuration)")
    ap.add_argument("--track", help=f"{TRACK_SPEC_HELP} (default: the config's)")
    ap.add_argument("--v-max", dest="v_max", metavar="V",
                    help="top speed cap [m/s] (default: [planner.cimpcc] v_up_mps, 4.18)")
    ap.add_argument("--ds", metavar="D", help="grid spacing along the track [m] (default 0.1)")
    ap.add_argument("--margin", metavar="M",
                    help="footprint kept this far inside the boundaries [m] (default 0.02)")
    ap.add_argument("--simulated-car", action="store_true",
                    help="with --for limit: the limit of the car the simulator races "
                    "([simulator.vehicle] when given) instead of [vehicle] (default: "
                    "[vehicle], the planners' car)")
    ap.add_argument("--cache", metavar="DIR", help="cache base folder the lap is stored in "
                    "(default $RACESTACK_CACHE, else ~/.cache/racestack)")
    ap.add_argument("--out", help="output folder (default runs/mintime-<time>)")
    ap.add_argument("--no-cache", action="store_true",
                    help="solve even if a cached lap exists (default: read the cached one)")
    ap.add_argument("--no-figures", action="store_true",
                    help="write mintime.json and raceline.csv only, no PNG figures (default: "
                    "the figures too; they need matplotlib)")
    return ap


def main(argv: list[str] | None = None, args: argparse.Namespace | None = None) -> int:
    """Solve (or load) the lap and write the outputs; exit code 0, or 2 on bad input."""
    args = args or build_parser().parse_args(argv)
    try:
        cfg = load_config(args.config)
        v_max = _number(args.v_max, "--v-max")
        ds = _number(args.ds, "--ds")
        margin = _number(args.margin, "--margin")
        use = getattr(args, "use", LIMIT)
        simulated = getattr(args, "simulated_car", False)
        if simulated and use != LIMIT:
            raise MinTimeArgumentError(
                f"--simulated-car: only with --for limit (the planner's {use} lap is always "
                "solved for [vehicle])"
            )
        car = cfg.simulator.vehicle if simulated else cfg.vehicle
        # the planner's lap as the stack's planner reads it (its pose source's margin)
        planner = for_stack(cfg.planner, cfg.localization.pose_source)
        vehicle, settings = request_for(use, planner, car)
        given = [name for name, value in (("--v-max", v_max), ("--ds", ds),
                                          ("--margin", margin)) if value is not None]
        if given and use != LIMIT:
            raise MinTimeArgumentError(
                f"{', '.join(given)}: only with --for limit (the {use} lap's settings are "
                "the configuration's)"
            )
        try:
            if given:
                settings = MinTimeSettings(
                    v_max_mps=settings.v_max_mps if v_max is None else v_max,
                    ds_m=settings.ds_m if ds is None else ds,
                    margin_m=settings.margin_m if margin is None else margin,
                )
        except ValueError as exc:
            raise MinTimeArgumentError(str(exc).replace("v_max_mps", "--v-max")
                                       .replace("ds_m", "--ds")
                                       .replace("margin_m", "--margin")) from None
        if use == RACELINE and cfg.planner.raceline.line != "min_time":
            print(f"{PROG}: note: [planner.raceline] line = {cfg.planner.raceline.line!r}: "
                  "the raceline planner of this configuration does not race on this lap",
                  file=sys.stderr)
        track = load_track(args.track or cfg.track.source)
        out = Path(args.out or Path("runs") / time.strftime("mintime-%Y%m%d-%H%M%S"))
        _check_out_dir(out)
        lap = make_min_time_lap(track, vehicle, settings, getattr(args, "cache", None),
                                use_cache=not args.no_cache, use=use, progress=_say)
    except (MinTimeArgumentError, ConfigError, TrackError) as exc:
        print(f"{PROG}: error: {exc}", file=sys.stderr)
        return 2
    doc = write_outputs(lap, track, vehicle, out, figures=not args.no_figures, use=use)
    how = "from the cache" if lap.cache_hit else f"solved in {lap.solve_time_s:.1f} s"
    print(
        f"minimum-time lap ({use}) on {lap.track_name} ({lap.track_length_m:.2f} m): "
        f"{lap.lap_time_s:.3f} s, peak {doc['peak_speed_mps']:.2f} m/s "
        f"(v_max {lap.v_max_mps:g} m/s, tyres {lap.tyre_model})"
    )
    print(
        f"IPOPT {lap.status}, {lap.iterations} iterations, {how}; ds {lap.ds_m:.4f} m, "
        f"{doc['grid_points']} points; point mass on the centreline "
        f"{lap.point_mass_lap_time_s:.3f} s"
    )
    print(f"written: {', '.join(str(out / f) for f in doc['files'])}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
