"""System identification from ordinary racing: does ``racestack sysid`` find the car?

For three cars the simulator races (the identified preset, Pacejka tyres, and two with its
tyre, steering and speed-loop parameters changed by 20-40 %), a planner races the car in
the bench's closed loop (``services.tools.bench``: planner and simulator in one process, the
planner told the true car so that it drives it well) for ``--duration`` seconds; the
simulator's own odometry and IMU (with their noise, the simulator's actuation and steering
delays) and the planner's commands are recorded as the stack records them, and
``shared.vehicle.identification.identify`` fits the car from them, never from the truth. Its
base car gives only geometry and mass; the tyres start from a neutral guess
(``B = 10, C = 1.5, D = 1`` per axle; ``E`` stays the base's, 0.373 front and 0 rear, as
``identify`` does not fit it), the actuators from the F1TENTH gym's values.

Prints, per car and parameter, the true value (for the delays: as the bench's loop acts
them, the configured delay rounded up to the simulator's sub-step, ``acted_delay``), the
estimate +- 1 sigma, the error and whether it is within 10 % (friction, the Pacejka D: 5 %;
delays: 10 ms), and which ones the run cannot tell ("not identifiable from this run").

    python -m benchmarks.sysid [--duration 120] [--track builtin:paperlike]
        [--method cimpcc] [--cars identified,softer,grippier] [--drive]

``--loop`` (implies ``--drive``): the loop closed, per car and ``--loop-tracks`` track: the
drive, the fit, the identified car (``SysidResult.vehicle_overlay`` over ``base_for``: what
``racestack sysid --out car.toml`` writes), the minimum-time lines the method races solved
on the IDENTIFIED car (``services.planner.make_min_time_lap``, cached), then the method
races the TRUE car in the simulator (``[simulator.vehicle]``) with the planner told the
identified one, ``--laps`` flying laps after the out lap; printed: the mean lap over the
TRUE car's limit (its own minimum-time lap, cached) and the off-track events (out lap
included). ``--with-true`` also races the planner told the true car (the method's own gap).

``--drive``: instead of racing, the identification drive (``racestack sysid --drive``'s
programme, ``shared.vehicle.sysid_drive``: 50 s of speed steps, 35 s of steering steps,
95 s of cornering at a rising lateral acceleration that stops at the saturation it sees)
records the car; the line then gives its off-track events and where the envelope stopped.
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

from services.planner import (
    PlannerPool,
    for_pose_source,
    laps_of,
    make_min_time_lap,
    request_for,
)
from services.simulator.dynamics import friction_accel_limit
from services.tools.bench import LoopOptions, SimulatorPlant, race
from services.tools.bench.closed_loop import run_method
from services.tools.bench.run import min_time_reference
from services.tools.sysid_drive import SignalTap, report_line, run_drive
from shared.config import RacestackConfig, config_from_dict
from shared.config.methods import CIMPCC, RACELINE, planner_methods
from shared.config.vehicle import DynamicVehicleParams, vehicle_preset
from shared.evaluation import results_document
from shared.track import load_track
from shared.vehicle.identification import SysidResult, identify

_ID = vehicle_preset("real_car_identified")
#: The cars the simulator races: name -> [vehicle] overrides of the identified preset.
CARS: dict[str, dict[str, Any]] = {
    "identified": {},
    # tyres 25-30 % weaker, a 30 % slower servo, a 30 % softer speed loop
    "softer": {
        "pacejka_front": (4.80 * 0.7, 2.16 * 0.8, 0.650 * 0.75, 0.373),
        "pacejka_rear": (20.0 * 0.7, 1.5 * 1.2, 0.618 * 0.75, 0.0),
        "steering_time_constant_s": 0.158 * 1.3,
        "speed_gain_accel_per_s": 4.755 * 0.7,
        "speed_gain_brake_per_s": 19.02 * 0.7,
    },
    # grippier (D + 25 %), stiffer rear (B - 20 %, C + 20 %), a faster servo with a lower rate
    # limit, a 35 % stiffer speed loop
    "grippier": {
        "pacejka_front": (4.80 * 1.3, 2.16 * 0.8, 0.650 * 1.25, 0.373),
        "pacejka_rear": (20.0 * 0.8, 1.5 * 1.2, 0.618 * 1.25, 0.0),
        "steering_time_constant_s": 0.158 * 0.6,
        "steering_rate_max_radps": 3.2 * 0.7,
        "steering_rate_min_radps": -3.2 * 0.7,
        "speed_gain_accel_per_s": 4.755 * 1.35,
        "speed_gain_brake_per_s": 19.02 * 1.35,
    },
}
#: The tracks of ``--loop``: map416 (../shared/tracks) and the built-in paperlike.
LOOP_TRACKS = "../shared/tracks/map416,builtin:paperlike"
#: An estimate's uncertainty is honest when its error is within this many sigmas.
HONEST_Z = 3.0
#: The neutral start of the tyre fit (B, C, D) per axle.
NEUTRAL_BCD = (10.0, 1.5, 1.0)


def car(name: str) -> DynamicVehicleParams:
    """The simulated car `name` (``CARS``)."""
    return vehicle_preset("real_car_identified", **CARS[name])


def base_for(true: DynamicVehicleParams) -> DynamicVehicleParams:
    """What ``identify`` is given: the true geometry and mass, the gym's actuators, the
    neutral Pacejka guess (the true ``E``s, which it does not fit)."""
    gym = vehicle_preset("f1tenth_gym")
    keep = ("mass_kg", "yaw_inertia_kgm2", "lf_m", "lr_m", "cog_height_m", "steering_min_rad",
            "steering_max_rad", "width_m", "length_m")
    return gym.model_copy(update={
        **{k: getattr(true, k) for k in keep}, "tyre_model": "pacejka", "mu": 1.0,
        "pacejka_front": (*NEUTRAL_BCD, true.pacejka_front[3]),
        "pacejka_rear": (*NEUTRAL_BCD, true.pacejka_rear[3])})


def _table(car: DynamicVehicleParams) -> dict[str, Any]:
    return {k: list(v) if isinstance(v, tuple) else v for k, v in car.model_dump().items()}


def config_of(true: DynamicVehicleParams) -> RacestackConfig:
    """The configuration that races `true` (the planners told the car)."""
    return config_from_dict({"vehicle": _table(true)})


def identified_table(result: SysidResult, base: DynamicVehicleParams) -> dict[str, Any]:
    """The ``[vehicle]`` table of the identified car: `base` with the fit's overlay (what
    ``racestack sysid --out car.toml`` writes over its base configuration)."""
    veh = _table(base)
    veh.update(result.vehicle_overlay(base))
    return {k: list(v) if isinstance(v, tuple) else v for k, v in veh.items()}


def loop_config(identified: dict[str, Any], true: DynamicVehicleParams) -> RacestackConfig:
    """The planners told the `identified` car, the simulator racing the `true` one."""
    return config_from_dict({"vehicle": identified, "simulator": {"vehicle": _table(true)}})


def race_identified(cfg: RacestackConfig, track_spec: str, method: str, laps: int
                    ) -> dict[str, Any]:
    """Race `method` (told ``cfg.vehicle``) against the simulator's car
    (``cfg.simulator.vehicle``) on `track_spec`: the lines solved on the told car first
    (cached), then `laps` flying laps after the out lap. Returns the mean flying lap [s],
    the true car's limit [s] and their ratio, off-track events (all / in the out lap),
    laps completed, the wall times of the lines and the race [s]."""
    track = load_track(track_spec)
    t0 = time.perf_counter()
    # it races on the true pose: the bench's settings for it (the raceline's truth tube)
    settings = for_pose_source(cfg.planner, "truth")
    for use in laps_of(method, settings, cfg.vehicle):  # the lines of the identified car
        make_min_time_lap(track, *request_for(use, settings, cfg.vehicle), use=use,
                          progress=None)
    ref = min_time_reference(track, cfg)  # the true car's limit
    t1 = time.perf_counter()
    planner = PlannerPool(track, cfg.vehicle).planner(settings, method, cfg.curvature)
    run = run_method(method, planner, track, cfg.simulator, LoopOptions(laps=laps))
    entry = results_document(track.name, track.length_m, [run], reference=ref)
    rec = entry["methods"][method]
    mean = rec["lap_time_s"]["mean"]
    return {"mean_lap_s": mean, "limit_s": None if ref is None else ref["min_time_lap_s"],
            "ratio": rec.get("ratio_to_min_time"), "off_track": run.run_off_track_events,
            "off_track_out_lap": run.out_lap_off_track_events, "laps": run.completed_laps,
            "lines_wall_s": t1 - t0, "race_wall_s": time.perf_counter() - t1}


def loop_line(who: str, track_spec: str, got: dict[str, Any]) -> str:
    """One printed line of a loop race."""
    ratio = "-" if got["ratio"] is None else f"{got['ratio']:.3f}"
    mean = "-" if got["mean_lap_s"] is None else f"{got['mean_lap_s']:.3f}"
    limit = "-" if got["limit_s"] is None else f"{got['limit_s']:.3f}"
    return (f"  {who:22s} {track_spec:22s} mean lap {mean} s / true limit {limit} s = "
            f"{ratio} (target <= 1.03); off-track {got['off_track']} "
            f"({got['off_track_out_lap']} in the out lap); {got['laps']} laps; lines "
            f"{got['lines_wall_s']:.0f} s, race {got['race_wall_s']:.0f} s wall")


def record_drive(cfg: RacestackConfig, track_spec: str, method: str, duration_s: float
                 ) -> tuple[dict[str, tuple[np.ndarray, np.ndarray]], dict[str, Any]]:
    """Race `method` for `duration_s` in the bench's closed loop; the recorded signals
    (``identification.SIGNALS``) and a summary (laps, off-track events, wall time)."""
    track = load_track(track_spec)
    for use in laps_of(method, cfg.planner, cfg.vehicle):  # its lines, solved once
        make_min_time_lap(track, *request_for(use, cfg.planner, cfg.vehicle), use=use,
                          progress=None)
    pool = PlannerPool(track, cfg.vehicle)
    planner = pool.planner(cfg.planner, method, cfg.curvature)
    planner.reset()
    plant = SimulatorPlant(track, cfg.simulator, LoopOptions(laps=10_000))
    sim = plant.sim
    tap = SignalTap(cfg.simulator, cfg.simulator.seed)
    step = sim.step
    last: list[Any] = [None]

    def recording_step(command: Any = None, dt_s: float | None = None) -> Any:
        if command is not None and command is not last[0]:  # a new cmd/drive, stamped now
            last[0] = command
            tap.command(sim.t_s, float(command[0]), float(command[1]))
        out = step(command, dt_s)
        tap.feed(out)
        return out

    sim.step = recording_step  # type: ignore[method-assign]
    t0 = time.perf_counter()
    got = race(planner, plant, None, max_ticks=int(duration_s / cfg.planner.dt_s), reset=False)
    signals = tap.signals()
    ays = np.abs(signals["ay_mps2"][1])
    summary = {"laps": plant.laps_completed, "off_track": plant.off_all,
               "stop": got.stop_reason or plant.stop_reason, "sim_s": sim.t_s,
               "wall_s": time.perf_counter() - t0,
               "ay_p95": float(np.percentile(ays, 95)) if len(ays) else 0.0}
    return signals, summary


def acted_delay(delay_s: float, cfg: RacestackConfig) -> float:
    """The delay [s] a command meets in the bench's loop: it is pushed `compute_delay_s`
    into a tick and acts from the first simulator sub-step that starts at least `delay_s`
    later; the sub-steps after the push are ``(dt - compute) / n`` long (n of them, at most
    ``integration_step_s`` each). So the simulator adds up to one sub-step (~9.6 ms) to
    its configured delays."""
    compute = LoopOptions().compute_delay_s
    rest = cfg.planner.dt_s - compute
    h = rest / math.ceil(rest / cfg.simulator.integration_step_s - 1e-9)
    return math.ceil(delay_s / h - 1e-9) * h


def truths(true: DynamicVehicleParams, cfg: RacestackConfig) -> dict[str, float]:
    """The true value of every parameter ``identify`` reports (the Pacejka model)."""
    sim = cfg.simulator
    out = {
        "steering_delay_s": acted_delay(sim.actuation_delay_s + sim.steering_delay_s, cfg),
        "steering_time_constant_s": true.steering_time_constant_s,
        "steering_rate_max_radps": true.steering_rate_max_radps,
        "speed_gain_accel_per_s": true.speed_gain_accel_per_s,
        "speed_gain_brake_per_s": true.speed_gain_brake_per_s,
        "speed_delay_s": acted_delay(sim.actuation_delay_s, cfg),
        # the simulator's acceleration limit: a_max, or the tyres' friction when lower
        "accel_max_mps2": min(true.accel_max_mps2, friction_accel_limit(true)),
        "steering_offset_rad": 0.0,
    }
    for axle, coeffs in (("front", true.pacejka_front), ("rear", true.pacejka_rear)):
        for letter, value in zip("BCD", coeffs[:3], strict=True):
            out[f"pacejka_{axle}_{letter}"] = true.mu * value if letter == "D" else value
    return out


def tolerance(name: str) -> tuple[float, bool]:
    """(tolerance, absolute?) of a parameter: delays and the offset absolute, 10 ms and
    5 mrad; friction (the D) 5 %; the rest 10 %."""
    if name.endswith("_delay_s"):
        return 0.010, True
    if name == "steering_offset_rad":
        return 0.005, True
    return (0.05 if name.endswith("_D") else 0.10), False


def _z(err: float, sigma: float) -> float:
    return abs(err) / sigma if sigma > 0 and math.isfinite(sigma) else math.nan


def table(name: str, result: SysidResult, true: dict[str, float]) -> tuple[list[str], int, int]:
    """The printed rows of one car; (rows, within tolerance, identifiable). Per parameter
    ``err/sig`` (the reported sigma: jackknife and grid terms) and ``curv`` (the
    curvature-only sigma it replaced, ``Estimate.sigma_curvature``), ``jack`` (the
    jackknife's part alone, without the floors); the last rows count
    the identifiable ones within ``HONEST_Z`` sigmas and give the median ``|error| /
    sigma`` (about 0.67 for an honest Gaussian sigma), for both."""
    rows = [f"  {'parameter':28s} {'true':>9s} {'estimate':>10s} {'+- 1 sigma':>10s} "
            f"{'error':>8s} {'err/sig':>7s} {'curv':>6s} {'jack':>6s}  within  identifiable"]
    good = told = honest = honest_c = 0
    zs: list[float] = []
    zs_c: list[float] = []
    for key, e in result.estimates.items():
        t = true.get(key, math.nan)
        tol, absolute = tolerance(key)
        err = e.value - t
        within = abs(err) <= tol if absolute else abs(err) <= tol * abs(t)
        err_txt = f"{1e3 * err:+7.1f}ms" if key.endswith("_s") and absolute else \
            f"{1e3 * err:+6.1f}mrad" if absolute else f"{100 * err / t:+7.1f}%"
        sig = f"{e.sigma:.3g}" if math.isfinite(e.sigma) else "inf"
        z, z_c = _z(err, e.sigma), _z(err, e.sigma_curvature)
        z_j = _z(err, math.sqrt(max(e.sigma ** 2 - e.sigma_systematic ** 2, 0.0)))
        honest += e.identifiable and z <= HONEST_Z
        honest_c += e.identifiable and z_c <= HONEST_Z
        if e.identifiable:
            zs.append(z)
            zs_c.append(z_c)
        ident = "yes" if e.identifiable else f"NO: not identifiable from this run ({e.note})"
        rows.append(f"  {key:28s} {t:9.4g} {e.value:10.4g} {sig:>10s} {err_txt:>8s} {z:7.1f} "
                    f"{z_c:6.1f} {z_j:6.1f}  {'yes' if within else 'NO ':6s}  {ident}")
        good += within and e.identifiable
        told += e.identifiable
    med = float(np.nanmedian(zs)) if zs and not np.all(np.isnan(zs)) else math.nan
    med_c = float(np.nanmedian(zs_c)) if zs_c and not np.all(np.isnan(zs_c)) else math.nan
    rows.append(f"  curvature-only sigma: {honest_c} of {told} within {HONEST_Z:g} sigma, "
                f"median |error|/sigma {med_c:.2f}")
    rows.append(f"  sigma honest (|error| <= {HONEST_Z:g} sigma): {honest} of {told} "
                f"identifiable parameters; median |error|/sigma {med:.2f} (honest: ~0.67)")
    return rows, good, told


def save_signals(path: str, signals: dict[str, tuple[np.ndarray, np.ndarray]]) -> None:
    """Write recorded `signals` (``identification.SIGNALS``: time [s], value) to `path`."""
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    np.savez_compressed(path, **{f"{k}__t": t for k, (t, _v) in signals.items()},
                        **{f"{k}__v": v for k, (_t, v) in signals.items()})


def load_signals(path: str) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """The signals ``save_signals`` wrote to `path`."""
    with np.load(path) as z:
        names = sorted({k.rsplit("__", 1)[0] for k in z.files})
        return {k: (z[f"{k}__t"], z[f"{k}__v"]) for k in names}


def main(argv: list[str] | None = None) -> int:
    """Run the benchmark (module docstring); 0 always (it reports, it does not judge)."""
    ap = argparse.ArgumentParser(prog="python -m benchmarks.sysid", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--duration", type=float, default=120.0, help="seconds of racing per car")
    ap.add_argument("--track", default="builtin:paperlike")
    ap.add_argument("--method", default=CIMPCC, choices=planner_methods())
    ap.add_argument("--cars", default=",".join(CARS), help=f"of {', '.join(CARS)}")
    ap.add_argument("--drive", action="store_true", help="record the identification drive "
                    "(racestack sysid --drive's programme, ~3 minutes) instead of racing; "
                    "--duration and --method are then not used")
    ap.add_argument("--loop", action="store_true", help="close the loop (implies --drive): "
                    "the identified car's minimum-time lines, then --loop-method races the "
                    "true car told the identified one on --loop-tracks (default off)")
    ap.add_argument("--loop-method", default=RACELINE, choices=planner_methods(),
                    help=f"the near-limit method of --loop (default {RACELINE})")
    ap.add_argument("--loop-tracks", default=LOOP_TRACKS,
                    help=f"the tracks of --loop (default {LOOP_TRACKS})")
    ap.add_argument("--laps", type=int, default=3,
                    help="flying laps of each --loop race after the out lap (default 3)")
    ap.add_argument("--with-true", action="store_true", help="--loop also races the planner "
                    "told the true car (the method's own gap to the limit; default off)")
    ap.add_argument("--save-signals", default=None, metavar="DIR",
                    help="also write each car's recorded signals to DIR/<car>.npz")
    ap.add_argument("--signals", default=None, metavar="DIR",
                    help="fit DIR/<car>.npz (a --save-signals recording) instead of racing")
    args = ap.parse_args(argv)
    args.drive = args.drive or args.loop
    for name in args.cars.split(","):
        true = car(name)
        cfg = config_of(true)
        if args.signals:
            signals = load_signals(f"{args.signals}/{name}.npz")
            print(f"\n{name}: the signals of {args.signals}/{name}.npz")
        elif args.drive:
            signals, drv = run_drive(load_track(args.track), cfg.simulator, cfg.planner.dt_s)
            print(f"\n{name}: the identification drive on {args.track}: {report_line(drv)}")
        else:
            signals, summ = record_drive(cfg, args.track, args.method, args.duration)
            print(f"\n{name}: {args.method} on {args.track}, {summ['sim_s']:.0f} s simulated "
                  f"({summ['wall_s']:.0f} s wall), {summ['laps']} laps, {summ['off_track']} "
                  f"off-track events{', stopped: ' + summ['stop'] if summ['stop'] else ''}; "
                  f"|a_y| p95 {summ['ay_p95']:.2f} m/s^2")
        if args.save_signals:
            save_signals(f"{args.save_signals}/{name}.npz", signals)
        t0 = time.perf_counter()
        result = identify(signals, base_for(true), "pacejka")
        rows, good, told = table(name, result, truths(true, cfg))
        print("\n".join(rows))
        print(f"  fit {time.perf_counter() - t0:.1f} s; {good} of {told} identifiable "
              f"parameters within tolerance; residuals: yaw rate "
              f"{result.fit_info['rms_yaw_rate_radps']:.3f} rad/s, a_y "
              f"{result.fit_info['rms_ay_mps2']:.3f} m/s^2 rms; "
              f"{100 * result.fit_info['at_friction_limit_share']:.1f} % of the samples at "
              "the friction limit; "
              f"{result.fit_info['windows']} windows ({result.fit_info['windows_dropped']} "
              "dropped)")
        sys.stdout.flush()
        if args.loop:
            ident = identified_table(result, base_for(true))
            print(f"  the loop: {args.loop_method} told the identified car, racing the true "
                  f"car ({args.laps} flying laps)")
            for spec in args.loop_tracks.split(","):
                got = race_identified(loop_config(ident, true), spec, args.loop_method,
                                      args.laps)
                print(loop_line("told the identified car", spec, got), flush=True)
                if args.with_true:
                    got = race_identified(cfg, spec, args.loop_method, args.laps)
                    print(loop_line("told the true car", spec, got), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
