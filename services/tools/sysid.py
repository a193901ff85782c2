"""``racestack sysid RUN --out car.toml [--model linear|linear_saturated|pacejka]``: the
car identified from a recorded run. ``racestack sysid --drive [--track T] [--car CONFIG]
--out RUN_DIR``: records an identification drive in the simulator first
(``services.tools.sysid_drive``: speed steps, steering steps, cornering at a rising lateral
acceleration that stops short of the grip seen; about 3 minutes) into
``RUN_DIR/telemetry.0000.rrd``, which ``racestack sysid RUN_DIR --out car.toml`` then reads.

Reads the telemetry recording of a run (``racestack report``'s reader: a run folder, its
``telemetry.0000.rrd`` ... segments or one ``.rrd``; a killed run's open segment is read up
to its last complete message) and takes what the stack recorded, never the simulator's
truth: ``cmd/drive`` (``speed/commanded``, ``steering/commanded``), ``vehicle/odom``
(``speed/odom``, ``steering/odom``; the ``state`` speed and steering when odometry is
absent) and ``vehicle/imu`` (``imu/yaw_rate_radps``, ``imu/ax_mps2``, ``imu/ay_mps2``).
The fit is ``shared.vehicle.identification.identify`` (steering delay / time constant /
rate limit, speed-loop gains / delay / acceleration limit, the tyres of ``--model`` and a
steering offset; geometry and mass from the base car, ``--config``'s ``[vehicle]``).

Writes:

- ``--out`` (``car.toml``): a ``--config`` file whose ``[vehicle]`` is the base car with
  every identifiable estimate put in (the base configuration's other sections kept when
  ``--config`` is given); a comment block on top lists each parameter's estimate, its
  1-sigma uncertainty and whether this run tells it ("not identifiable from this run":
  kept from the base car). The file is loaded back before the command succeeds.
- ``<out>.sysid.json``: the same estimates machine-readable (value, sigma, identifiable,
  unit, note), the delays (which are ``[simulator]`` / ``[planner]`` settings, not
  ``[vehicle]``) and the fit's residuals.
- ``<out>.png`` (unless ``--no-figure``): measured against predicted steering angle,
  acceleration, yaw rate and lateral acceleration.

Exit codes: 0 written; 2 bad input (one line naming what the recording lacks: too short,
no cornering, a signal missing, not readable).
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import tomllib
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from shared.config import ConfigError, config_from_dict, load_config
from shared.config.toml_write import dumps
from shared.config.vehicle import DynamicVehicleParams
from shared.extras import require
from shared.service_shell import OneLineArgumentParser, plain_help
from shared.track import TRACK_SPEC_HELP
from shared.vehicle.identification import (
    TYRE_PARAMETERS,
    Estimate,
    SysidError,
    SysidResult,
    identify,
)

PROG = "racestack sysid"
#: Each signal ``identify`` needs: (bus key, recorded entities in order of preference).
SOURCES: dict[str, tuple[str, tuple[str, ...]]] = {
    "cmd_speed_mps": ("cmd/drive", ("speed/commanded",)),
    "cmd_steering_rad": ("cmd/drive", ("steering/commanded",)),
    "speed_mps": ("vehicle/odom", ("speed/odom", "speed/measured")),
    "steering_rad": ("vehicle/odom", ("steering/odom", "steering/measured")),
    "yaw_rate_radps": ("vehicle/imu", ("imu/yaw_rate_radps", "state/yaw_rate_radps")),
    "ax_mps2": ("vehicle/imu", ("imu/ax_mps2",)),
    "ay_mps2": ("vehicle/imu", ("imu/ay_mps2",)),
}
#: Parameters that are ``[vehicle]`` fields (the rest: delays, offset, informational).
NOT_VEHICLE = ("steering_delay_s", "speed_delay_s", "steering_offset_rad")


def signals_of(series: Mapping[str, tuple[np.ndarray, np.ndarray]]
               ) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """The signals of ``identify`` from a recording's scalar series (``SOURCES``).

    Raises:
        SysidError: naming the keys (and entities) the recording lacks.
    """
    out: dict[str, tuple[np.ndarray, np.ndarray]] = {}
    missing: dict[str, list[str]] = {}
    for name, (key, entities) in SOURCES.items():
        found = next((series[e] for e in entities if e in series and len(series[e][0]) >= 2),
                     None)
        if found is None:
            missing.setdefault(key, []).append(entities[0])
        else:
            out[name] = found
    if missing:
        what = "; ".join(f"{k} ({', '.join(v)})" for k, v in missing.items())
        raise SysidError(f"missing {what}: the recording must hold cmd/drive, vehicle/odom "
                         "and vehicle/imu")
    return out


def _fmt(e: Estimate) -> str:
    sig = "inf" if not math.isfinite(e.sigma) else f"{e.sigma:.3g}"
    tail = "" if e.identifiable else f"  NOT IDENTIFIABLE from this run ({e.note})"
    if e.identifiable and e.note:
        tail = f"  ({e.note})"
    return f"{e.name} = {e.value:.4g} +- {sig} {e.unit}".rstrip() + tail


def header(result: SysidResult, source: str, base_name: str) -> str:
    """The comment block of ``car.toml``: what was fitted, each estimate +- 1 sigma."""
    lines = [
        f"racestack sysid: the car identified from {source}",
        f"({result.duration_s:.0f} s of driving; tyre model {result.model}; geometry and mass "
        f"from {base_name}).",
        "Each parameter: estimate +- 1-sigma uncertainty [unit] (a block jackknife over",
        "the recording plus the grid's and the timing's floors). NOT IDENTIFIABLE ones",
        "are kept from the base car in",
        "[vehicle] below (the value shown is a bound or a guess), except a Pacejka B and C",
        "of which only the product is told: those are written as fitted, and a steering",
        "rate limit never told, written as the fastest rate seen when below the base's.",
        "The delays are not [vehicle] fields: [simulator] actuation_delay_s +",
        "steering_delay_s, [planner] speed_delay_s / steering_delay_s (tracker).",
        "",
    ]
    lines += [_fmt(e) for e in result.estimates.values()]
    return "\n".join(lines)


def _estimate_doc(e: Estimate) -> dict[str, Any]:
    """One estimate in the JSON (a sigma of inf as null)."""
    finite = math.isfinite(e.sigma)
    return {"value": e.value, "sigma": e.sigma if finite else None,
            "sigma_systematic": e.sigma_systematic if finite else None,
            "identifiable": e.identifiable, "unit": e.unit, "note": e.note,
            "lower_bound": e.lower_bound if math.isfinite(e.lower_bound) else None}


def write_outputs(result: SysidResult, base_data: dict[str, Any],
                  base: DynamicVehicleParams, out: Path, source: str, base_name: str) -> Path:
    """Write ``car.toml`` (loaded back: a ``ConfigError`` if it does not) and the JSON;
    returns the JSON's path."""
    vehicle = {k: v for k, v in base_data.get("vehicle", {}).items()}
    if not vehicle:
        vehicle = {"preset": base.preset}
    vehicle.update(result.vehicle_overlay(base))
    vehicle = {k: list(v) if isinstance(v, tuple) else v for k, v in vehicle.items()}
    data = {**base_data, "vehicle": vehicle}
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(dumps(data, header(result, source, base_name)), encoding="utf-8")
    load_config(out)  # proves the file is a valid configuration
    doc = {
        "recording": source,
        "model": result.model,
        "duration_s": result.duration_s,
        "estimates": {k: _estimate_doc(e) for k, e in result.estimates.items()},
        "fit": result.fit_info,
    }
    js = out.with_suffix(".sysid.json")
    # numpy scalars (a numpy bool in an estimate's flags) as plain Python values
    js.write_text(json.dumps(doc, indent=2, default=lambda o: o.item()) + "\n",
                  encoding="utf-8")
    return js


def write_figure(result: SysidResult, path: Path) -> None:
    """Measured against predicted signals, over the 30 s with the most tyre-fit samples."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    t = result.t_s
    covered = np.isfinite(result.curves["yaw_rate_radps"][1]).astype(float)
    span = min(len(t), int(30.0 / max(t[1] - t[0], 1e-3)))
    score = np.convolve(covered, np.ones(span), mode="valid")
    i0 = int(np.argmax(score)) if len(score) else 0
    sl = slice(i0, i0 + span)
    labels = {"steering_rad": "steering [rad]", "accel_mps2": "accel. demand [m/s^2]",
              "yaw_rate_radps": "yaw rate [rad/s]", "ay_mps2": "a_y [m/s^2]"}
    fig, axes = plt.subplots(len(labels), 1, figsize=(10, 9), sharex=True)
    for ax, (name, label) in zip(axes, labels.items(), strict=True):
        meas, pred = result.curves[name]
        ax.plot(t[sl], meas[sl], color="0.45", lw=0.8, label="measured")
        ax.plot(t[sl], pred[sl], color="tab:red", lw=0.9, label="predicted")
        ax.set_ylabel(label)
        ax.grid(alpha=0.3)
    axes[0].legend(loc="upper right")
    axes[0].set_title(f"racestack sysid ({result.model} tyres): measured vs predicted")
    axes[-1].set_xlabel("time [s]")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def build_parser(ap: argparse.ArgumentParser | None = None) -> argparse.ArgumentParser:
    """The ``racestack sysid`` arguments."""
    ap = ap or OneLineArgumentParser(prog=PROG, description=plain_help(__doc__))
    ap.add_argument("recording", nargs="?",
                    help="a telemetry run folder or .rrd (segments read in order)")
    ap.add_argument("--out", required=True, help="the identified car: a TOML --config file "
                    "(with --drive: the run folder the drive is recorded into)")
    ap.add_argument("--drive", action="store_true",
                    help="record an identification drive in the simulator into --out "
                    "instead of fitting (default: fit RECORDING)")
    ap.add_argument("--track", help=f"--drive's track: {TRACK_SPEC_HELP} (default: the "
                    "config's [track] source)")
    ap.add_argument("--car", help="--drive's simulated car and simulator: a --config file "
                    "(default: --config, else the built-in defaults)")
    ap.add_argument("--model", choices=tuple(TYRE_PARAMETERS),
                    help="tyre model to fit (default: the base car's tyre_model)")
    ap.add_argument("--config", help="base configuration: geometry and mass of the car, "
                    "the starting point of the fit, the other sections of --out (default: the "
                    "built-in defaults, the F1TENTH gym's car)")
    ap.add_argument("--no-figure", action="store_true",
                    help="write no PNG of measured against predicted signals (default: "
                    "write it beside --out, car.toml -> car.png)")
    return ap


def main(argv: Sequence[str] | None = None, args: argparse.Namespace | None = None) -> int:
    """``racestack sysid`` (module docstring); returns the exit code."""
    args = args or build_parser().parse_args(argv)
    if args.drive:
        from services.tools.sysid_drive import drive_main

        return drive_main(args.out, args.track, args.car or args.config, PROG)
    if not args.recording:
        print(f"{PROG}: error: give a RECORDING to fit, or --drive to record one",
              file=sys.stderr)
        return 2
    if not args.no_figure:
        require("matplotlib")
    base_data: dict[str, Any] = {}
    if args.config:
        cfg = load_config(args.config)
        base_data = tomllib.loads(Path(args.config).read_text(encoding="utf-8"))
    else:
        cfg = config_from_dict({})
    base = cfg.vehicle
    model = args.model or base.tyre_model
    out = Path(args.out)
    from services.tools.report import read_recording  # here: the parser needs no Rerun

    try:
        data = read_recording(args.recording)
    except FileNotFoundError as exc:
        print(f"{PROG}: error: {exc}", file=sys.stderr)
        return 2
    except (OSError, RuntimeError, ValueError) as exc:
        print(f"{PROG}: error: {args.recording}: not a readable telemetry recording "
              f"({str(exc).splitlines()[0] if str(exc) else type(exc).__name__})",
              file=sys.stderr)
        return 2
    if not data.complete:
        print(f"{PROG}: note: {data.segments[-1].name} has no footer (the run was killed): "
              "read up to its last complete message", file=sys.stderr)
    try:
        result = identify(signals_of(data.series), base, model)
    except SysidError as exc:
        print(f"{PROG}: error: {args.recording}: {exc}", file=sys.stderr)
        return 2
    base_name = args.config or "the default [vehicle]"
    try:
        js = write_outputs(result, base_data, base, out, str(data.path), base_name)
    except ConfigError as exc:
        print(f"{PROG}: error: the identified car is not a valid configuration: {exc}",
              file=sys.stderr)
        return 2
    print(header(result, str(data.path), base_name))
    print(f"\nwrote {out} and {js}")
    if not args.no_figure:
        png = out.with_suffix(".png")
        write_figure(result, png)
        print(f"wrote {png}")
    return 0


if __name__ == "__main__":  # python -m services.tools.sysid RUN --out car.toml
    sys.exit(main())
