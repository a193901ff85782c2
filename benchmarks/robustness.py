"""Robustness benchmark: methods racing a matrix of tracks, cars and pose sources.

    python -m benchmarks.robustness --quick                  # CI-sized subset, a few minutes
    python -m benchmarks.robustness --out runs/robust        # the whole matrix
    python -m benchmarks.robustness --tracks f1tenth --v-max 10   # the F1TENTH maps uncapped
    python -m benchmarks.robustness --methods cimpcc,raceline --cars default --poses truth
    python -m benchmarks.robustness --tracks Oschersleben --v-max 10 --config try.toml

The matrix (``--tracks``, ``--cars``, ``--poses`` narrow it):

- tracks: map416 and paperlike (``builtin``), the six F1TENTH maps of ``../shared/tracks``
  (``f1tenth``), the generated measuring tracks ``gen:N`` for N in
  ``shared.track.generator.GENERATED_SEEDS`` (``generated``; never the tuning seeds);
- cars (``CARS`` of ``shared.evaluation.car_family``, shared with ``racestack tune``): ``default``
  (the F1TENTH gym's car, ``linear_saturated`` tyres),
  ``linear`` (the gym's own unbounded linear tyres), ``identified`` (the identified car with
  Pacejka tyres, the planners told its car) and ``identified-on-default`` (the simulator races
  the identified car, the planners keep the default car: a model mismatch);
  ``linear-on-default`` (the world linear, the planners on the default car) on request;
  ``varied:SEED`` (a seeded variant of the identified car's tyres, servo and speed loop, the
  planners told it: ``car_family.varied_car``; seeds 1001-... to tune on, 1-... to measure);
- pose: ``truth``, ``ekf``, ``lidar`` (``services.tools.bench.estimation``);
- methods: the near-limit methods (cimpcc-line, raceline) unless ``--methods`` names others
  of the registry (a bench variant races its base method with the configuration's settings).

A cell is one (track, car, pose); the planners' settings are those of its pose source
(``services.planner.for_pose_source``: the raceline's margin widened by ``[planner.raceline]
truth_margin_m`` / ``ekf_margin_m`` / ``lidar_margin_m``); each method races it in the
bench's closed loop (``services.tools.bench.run_method``: an out lap from standstill,
then ``--laps`` flying laps). Per method the cell records the mean lap over the simulated
car's minimum-time lap at the cap (``ratio``), off-track events of the whole run (out lap
included), recoveries, spins
(``spin_events``: the rear axle's slip angle beyond ``SPIN_SLIP_FACTOR`` x its tyres' peak slip for
more than ``SPIN_MIN_DURATION_S``; beside it the largest rear slip over that peak; the gym's
unbounded ``linear`` tyres have no peak: their reference is the largest rear slip of the car's own
limit lap, ``rear_peak_slip_rad``), laps completed,
the laps below the limit and the excursions over the cap
(``shared.evaluation.results.rule_check``) and the solve time's median and p99. A method
is clean in a cell when it completed every lap with no off-track event, recovery, spin, lap
below the limit or excursion over the cap.

The cap: the configuration's (``[planner.cimpcc] v_up_mps[0]``, 4.18 m/s) unless ``--v-max``
sets every method's: ``[planner.cimpcc] v_up_mps`` (the tuner's pair, v_l = 1.1 v_p),
``[planner.cimpcc_line] v_max_mps`` and ``[planner.raceline] v_max_mps`` (``cap_overlay``);
the limit is then solved at that top speed too. MPCC's fixed speed reference is no cap and
stays. ``--config FILE`` lays a TOML file's tables over every car's (``config_for``: e.g.
``[planner.raceline]`` settings to try; the laps it changes are solved and cached like the
others). ``--min-time-ds`` puts the limit's and the raceline's minimum-time laps on a coarser
grid (``[planner.raceline] ds_m``) for every track; without it the tracks longer than
``LONG_TRACK_M`` (the 260-460 m F1TENTH maps) take ``LONG_TRACK_DS_M`` and the others the
configuration's 0.1 m. cimpcc-line's line keeps 0.1 m.

Two phases: first every minimum-time lap the cells read (each car's limit and the planners'
lines), solved once and cached (``services.planner.make_min_time_lap``), in ``--jobs``
processes with a progress line each; then the cells in ``--jobs`` processes (spawned; each
builds its own planners). Each finished cell is appended to ``OUT/cells.jsonl``
(``--resume`` skips the cells found there); at the end ``OUT/robustness.json`` (the cells, the
summary, the wall times by kind of cell) and ``OUT/robustness.txt`` (the table, the worst
cells, the wall time against ``MATRIX_WALL_TARGET_S``, per method the worst ratio per pose source
with its cell against ``RATIO_TARGETS`` / ``MISMATCH_RATIO_TARGET`` and the summary line, also
printed).
"""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import multiprocessing as mp
import os
import sys
import time
import tomllib
from collections.abc import Callable, Iterable
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np

from services.planner import (
    PlannerPool,
    for_pose_source,
    laps_of,
    limit_request,
    make_min_time_lap,
    request_for,
)
from services.planner.mintime.model import STATE_NAMES
from services.planner.mintime.ocp import MinTimeLap, MinTimeSettings
from services.tools.bench.closed_loop import LoopOptions, run_method
from services.tools.bench.estimation import ESTIMATORS
from services.tools.bench.run import BenchError, min_time_reference, parse_methods
from services.tools.tune.search import speed_pair, top_progress_speed
from shared.config import RacestackConfig, config_from_dict
from shared.config.methods import CIMPCC, CIMPCC_LINE, METHODS, RACELINE
from shared.config.vehicle import DynamicVehicleParams
from shared.evaluation import MethodRun, results_document, write_results
from shared.evaluation.car_family import (  # the family, one definition
    CARS,
    DEFAULT_CARS,
    UnknownCarError,
    car_names,
    car_spec,
)
from shared.evaluation.spins import (
    SPIN_MIN_DURATION_S,
    SPIN_SLIP_FACTOR,
    rear_peak_slip_rad,
    spin_events,
)
from shared.track import Track, load_track
from shared.track.generator import GENERATED_SEEDS

ROOT = Path(__file__).resolve().parents[1]
#: The shared track data (map416, the F1TENTH maps).
TRACKS_DIR = ROOT.parent / "shared" / "tracks"
#: The six F1TENTH maps under ``TRACKS_DIR / "f1tenth"``.
F1TENTH_MAPS = ("Austin", "Monza", "Oschersleben", "Silverstone", "Spielberg", "YasMarina")
#: The near-limit methods (the default ``--methods``).
NEAR_LIMIT_METHODS = (CIMPCC_LINE, RACELINE)
#: The ``--quick`` subset.
QUICK_TRACKS = ("map416", "paperlike", *(f"gen:{s}" for s in GENERATED_SEEDS[:2]))
QUICK_CARS = ("default", "identified")
QUICK_POSES = ("truth",)
#: Rows of the worst-cells list.
WORST_ROWS = 20
#: The minimum-time lap's states ``lap_rear_slip_rad`` reads.
V_MPS, BETA, R_RADPS = (STATE_NAMES.index(n) for n in ("v_mps", "beta_rad", "r_radps"))
#: The targets of issue #21 for the worst ratio of the best near-limit method (mean lap /
#: the simulated car's minimum-time lap) where the planner knows its car, per pose source.
RATIO_TARGETS = {"truth": 1.03, "ekf": 1.05, "lidar": 1.06}
#: ... and where it does not (the identified car raced on the default car's model).
MISMATCH_RATIO_TARGET = 1.15
#: The whole matrix's wall time target here [s] (the minimum-time laps cached, both cores).
MATRIX_WALL_TARGET_S = 30 * 60.0
#: Tracks longer than this [m] (the 260-460 m F1TENTH maps; the built-in and generated ones
#: are 25-120 m) take their minimum-time laps on ``LONG_TRACK_DS_M`` unless
#: ``--min-time-ds`` sets one grid for all.
LONG_TRACK_M = 200.0
#: Their grid [m] (on 0.1 m one such lap takes minutes: the whole matrix needs 60 of them).
LONG_TRACK_DS_M = 0.25
#: A cell's wall time per metre of track relative to the true pose's (the medians of the
#: matrix's cells by pose: the EKF about doubles it, the lidar's scans and particle filter
#: about six times it); ``cell_order`` schedules the costly cells first.
POSE_COST = {"truth": 1.0, "ekf": 2.0, "lidar": 6.0}




# ------------------------------------------------------------------------- the matrix
def track_groups(tracks_dir: Path = TRACKS_DIR) -> dict[str, tuple[str, ...]]:
    """The track specs of each ``--tracks`` group (``builtin``, ``f1tenth``, ``generated``)."""
    return {
        "builtin": (str(tracks_dir / "map416"), "paperlike"),
        "f1tenth": tuple(str(tracks_dir / "f1tenth" / n) for n in F1TENTH_MAPS),
        "generated": tuple(f"gen:{s}" for s in GENERATED_SEEDS),
    }


def resolve_tracks(text: str, tracks_dir: Path = TRACKS_DIR) -> list[str]:
    """The track specs of a ``--tracks`` list: groups (``all``, ``builtin``, ``f1tenth``,
    ``generated``), ``map416`` (the shared one), or any track spec."""
    groups = track_groups(tracks_dir)
    out: list[str] = []
    for item in (t.strip() for t in text.split(",")):
        if not item:
            continue
        if item == "all":
            specs: Iterable[str] = [s for g in groups.values() for s in g]
        elif item in groups:
            specs = groups[item]
        elif item == "map416":
            specs = [str(tracks_dir / "map416")]
        else:
            specs = [item]
        out += [s for s in specs if s not in out]
    if not out:
        raise BenchError("no track given")
    return out


def _names(text: str, known: Iterable[str], what: str) -> list[str]:
    names = [n.strip() for n in text.split(",") if n.strip()]
    known = list(known)
    bad = [n for n in names if n not in known]
    if bad or not names:
        raise BenchError(f"unknown {what} {', '.join(bad) or '(none)'}; choose from "
                         f"{', '.join(known)}")
    return list(dict.fromkeys(names))


def cap_overlay(v_max_mps: float | None) -> dict[str, Any]:
    """The planner tables that put every method's cap at `v_max_mps` [m/s] (module
    docstring); {} for None (the configuration's own cap)."""
    if v_max_mps is None:
        return {}
    v_up = speed_pair(top_progress_speed(v_max_mps))  # the tuner's pair: v_l = 1.1 v_p
    return {
        "planner": {
            METHODS[CIMPCC].section: {"v_up_mps": v_up},
            METHODS[CIMPCC_LINE].section: {"v_max_mps": v_up[0]},
            METHODS[RACELINE].section: {"v_max_mps": v_up[0]},
        }
    }


def _merge(a: dict[str, Any], b: dict[str, Any]) -> dict[str, Any]:
    out = dict(a)
    for k, v in b.items():
        out[k] = _merge(out[k], v) if isinstance(v, dict) and isinstance(out.get(k), dict) else v
    return out


def grid_overlay(ds_m: float | None) -> dict[str, Any]:
    """The planner table that puts the raceline's line on grid `ds_m` [m] (``--min-time-ds``;
    the limit's grid goes through ``limit_request``); {} for None."""
    if ds_m is None:
        return {}
    return {"planner": {METHODS[RACELINE].section: {"ds_m": ds_m}}}


def config_for(car: str, v_max_mps: float | None = None, ds_m: float | None = None,
               extra: dict[str, Any] | None = None) -> RacestackConfig:
    """The validated configuration of `car` (``CARS``) at cap `v_max_mps` (None: 4.18),
    the raceline's line on grid `ds_m` (None: its own), with the tables `extra` (``--config``,
    e.g. ``[planner.raceline]`` settings) over all of them."""
    tables = _merge(_merge(car_spec(car).tables, cap_overlay(v_max_mps)), grid_overlay(ds_m))
    return config_from_dict(_merge(tables, extra or {}))


def load_overlay(path: str | Path) -> str:
    """The tables of the TOML file at `path` (``--config``) as canonical JSON (``Matrix.
    overlay``), validated on the default car (BenchError on a wrong file)."""
    try:
        tables = tomllib.loads(Path(path).read_text(encoding="utf-8"))
        config_for("default", extra=tables)
    except (OSError, tomllib.TOMLDecodeError, ValueError) as exc:
        raise BenchError(f"--config {path}: {exc}") from None
    return json.dumps(tables, sort_keys=True)


@dataclass(frozen=True)
class Cell:
    """One cell: a track spec, a car of ``CARS``, a pose source of ``ESTIMATORS``."""

    track: str
    car: str
    pose: str

    @property
    def key(self) -> str:
        """The cell's identity in ``cells.jsonl``."""
        return f"{self.track}|{self.car}|{self.pose}"


@dataclass(frozen=True)
class Matrix:
    """What the benchmark races (module docstring)."""

    tracks: tuple[str, ...]
    cars: tuple[str, ...]
    poses: tuple[str, ...]
    methods: tuple[str, ...]
    laps: int = 2
    v_max_mps: float | None = None
    ds_m: float | None = None
    #: ``--config``'s tables as JSON ("": none), over every car's (``config_for``)
    overlay: str = ""
    #: the grid [m] of a track longer than ``LONG_TRACK_M`` when ``ds_m`` is None (the
    #: F1TENTH maps: their minimum-time laps take minutes each on the 0.1 m grid)
    long_track_ds_m: float | None = LONG_TRACK_DS_M

    def ds_for(self, track_spec: str) -> float | None:
        """The minimum-time grid [m] of `track_spec`'s laps: ``ds_m`` when given, else
        ``long_track_ds_m`` on a track longer than ``LONG_TRACK_M``, else None (the
        configuration's own)."""
        if self.ds_m is not None or self.long_track_ds_m is None:
            return self.ds_m
        return self.long_track_ds_m if _track(track_spec).length_m > LONG_TRACK_M else None

    @property
    def extra(self) -> dict[str, Any]:
        """The ``--config`` tables ({} for none)."""
        return json.loads(self.overlay) if self.overlay else {}

    def cells(self) -> list[Cell]:
        """Every cell, track-major (the same track and car next to each other)."""
        return [Cell(t, c, p) for t in self.tracks for c in self.cars for p in self.poses]


# ------------------------------------------------------------------ the cell's figures
def lap_rear_slip_rad(lap: MinTimeLap, car: DynamicVehicleParams) -> float:
    """The largest |rear slip angle| [rad] of a minimum-time lap of `car`: ``alpha_r =
    atan(tan(beta) - l_r r / (v cos(beta)))`` at its nodes (``mintime.model.STATE_NAMES``)."""
    x = np.asarray(lap.states, dtype=float)
    v, beta, r = x[:, V_MPS], x[:, BETA], x[:, R_RADPS]
    alpha = np.arctan(np.tan(beta) - car.lr_m * r / (np.maximum(v, 1e-3) * np.cos(beta)))
    return float(np.abs(alpha).max())


def method_record(run: MethodRun, entry: dict[str, Any], peak_rad: float) -> dict[str, Any]:
    """One method's figures in a cell from its run and its results.json entry (with the
    reference's ``ratio_to_min_time`` and ``rule_check`` keys when the limit is known)."""
    slip = np.abs(np.asarray(run.trace.rear_slip_rad, dtype=float))
    solve = entry["solve_time_ms"]
    rec = {
        "ratio": entry.get("ratio_to_min_time"),
        "mean_lap_s": entry["lap_time_s"]["mean"],
        "laps_completed": run.completed_laps,
        "laps_requested": run.requested_laps,
        "off_track": run.run_off_track_events,
        "out_lap_off_track": run.out_lap_off_track_events,
        "recoveries": int(run.extra.get("recoveries", 0)),
        "spins": spin_events(run.trace.t_s, run.trace.rear_slip_rad, peak_rad),
        "max_rear_slip_rad": float(slip.max()) if slip.size else None,
        "max_slip_over_peak": float(slip.max() / peak_rad) if slip.size else None,
        "below_limit_laps": entry.get("below_limit_laps"),
        "over_cap_events": entry.get("over_cap_events"),
        "max_speed_mps": entry.get("max_speed_mps"),
        "solve_ms_median": solve["median"],
        "solve_ms_p99": solve["p99"],
        "solve_ms_max": solve["max"],
        "solver_failures": run.solver_failures,
        "aborted": run.extra.get("aborted", ""),
        "errors": list(entry.get("errors", [])),
    }
    if "localisation" in run.extra:
        rec["localisation"] = run.extra["localisation"]
    rec["clean"] = is_clean(rec)
    return rec


def is_clean(rec: dict[str, Any]) -> bool:
    """Every lap completed, and no off-track event, recovery, spin, lap below the limit,
    excursion over the cap or error."""
    return (
        not rec.get("error")
        and rec.get("laps_completed", 0) >= rec.get("laps_requested", 1)
        and not rec.get("off_track")
        and not rec.get("recoveries")
        and not rec.get("spins")
        and not rec.get("below_limit_laps")
        and not rec.get("over_cap_events")
    )


# -------------------------------------------------------------------- phase 1: the laps
@dataclass(frozen=True)
class LapTask:
    """One minimum-time lap to make: the track, its use (``MIN_TIME_USES``), the car and the
    settings it is solved for."""

    track: str
    use: str
    car: dict[str, Any]
    settings: MinTimeSettings
    label: str = ""

    @property
    def key(self) -> str:
        """What makes two tasks the same lap."""
        return json.dumps([self.track, self.car, asdict(self.settings)], sort_keys=True)


def lap_tasks(matrix: Matrix) -> list[LapTask]:
    """Every distinct minimum-time lap the cells read: each simulated car's limit and each
    method's line for the planners' car, the longest tracks first."""
    tasks: dict[str, LapTask] = {}
    for car in matrix.cars:
        for track in matrix.tracks:
            ds_m = matrix.ds_for(track)
            cfg = config_for(car, matrix.v_max_mps, ds_m, matrix.extra)
            wanted = [("limit", *limit_request(cfg.planner, cfg.simulator.vehicle, ds_m))]
            for pose in matrix.poses:  # the pose source's margin (``for_pose_source``)
                planner = for_pose_source(cfg.planner, pose)
                for method in matrix.methods:
                    for use in laps_of(method, planner, cfg.vehicle):
                        wanted.append((use, *request_for(use, planner, cfg.vehicle)))
            for use, vehicle, settings in wanted:
                task = LapTask(track, use, vehicle.model_dump(mode="json"), settings,
                               f"{_short(track)} {use} ({car}, margin {settings.margin_m:g} m)")
                tasks.setdefault(task.key, task)
    return sorted(tasks.values(), key=lambda t: -_track(t.track).length_m)


_TRACKS: dict[str, Track] = {}


def _track(spec: str) -> Track:
    if spec not in _TRACKS:
        _TRACKS[spec] = load_track(spec)
    return _TRACKS[spec]


def solve_lap(task: LapTask) -> dict[str, Any]:
    """Make one lap (read from the cache or solved); its outcome and wall time [s]."""
    t0 = time.perf_counter()
    try:
        car = DynamicVehicleParams.model_validate(task.car)
        lap = make_min_time_lap(_track(task.track), car, task.settings, use=task.use,
                                progress=None)
        out = {"ok": True, "lap_time_s": lap.lap_time_s, "cache_hit": lap.cache_hit}
    except Exception as exc:  # a lap that cannot be made is an error of its cells
        out = {"ok": False, "error": f"{type(exc).__name__}: {exc}", "cache_hit": False}
    out.update(label=task.label, wall_s=time.perf_counter() - t0)
    return out


# -------------------------------------------------------------------- phase 2: the cells
#: Per worker: the track, configuration, planner pool and limit of the last (track, car)s.
_SETUPS: dict[tuple[str, str, float | None, float | None, str],
              tuple[Track, RacestackConfig, PlannerPool, dict | None, str, float]] = {}


def _setup(track_spec: str, car: str, v_max: float | None, ds_m: float | None = None,
           overlay: str = ""):
    key = (track_spec, car, v_max, ds_m, overlay)
    if key not in _SETUPS:
        if len(_SETUPS) >= 4:
            _SETUPS.pop(next(iter(_SETUPS)))
        track = _track(track_spec)
        cfg = config_for(car, v_max, ds_m, json.loads(overlay) if overlay else None)
        said = io.StringIO()
        with contextlib.redirect_stderr(said):
            ref = min_time_reference(track, cfg, ds_m=ds_m)
        note = "" if ref is not None else said.getvalue().strip().splitlines()[-1]
        limit = _limit_lap(track, cfg, ds_m)
        lap_slip = None if limit is None else lap_rear_slip_rad(limit, cfg.simulator.vehicle)
        peak = rear_peak_slip_rad(cfg.simulator.vehicle, lap_slip)
        _SETUPS[key] = (track, cfg, PlannerPool(track, cfg.vehicle), ref, note, peak)
    return _SETUPS[key]


def _limit_lap(track: Track, cfg: RacestackConfig, ds_m: float | None = None
               ) -> MinTimeLap | None:
    """The simulated car's limit (cached by phase 1), for the linear tyres' reference slip;
    None for the other tyres or when it cannot be made."""
    if cfg.simulator.vehicle.tyre_model != "linear":
        return None
    try:
        car, settings = limit_request(cfg.planner, cfg.simulator.vehicle, ds_m)
        return make_min_time_lap(track, car, settings, use="limit", progress=None)
    except Exception:  # no limit: the tyres' nominal peak (the cell says why)
        return None


def run_cell(
    cell: Cell,
    matrix: Matrix,
    instrument: Callable[[str, Any], None] | None = None,
) -> dict[str, Any]:
    """Race every method of `matrix` in `cell`; the cell's record (JSON-ready).
    `instrument(method, planner)` is called with each planner before it races (a
    benchmark's timing of its ticks: ``benchmarks/planner_ticks.py``)."""
    t0 = time.perf_counter()
    track, cfg, pool, ref, note, peak = _setup(cell.track, cell.car, matrix.v_max_mps,
                                               matrix.ds_for(cell.track), matrix.overlay)
    opts = LoopOptions(laps=matrix.laps, estimator=cell.pose, localization=cfg.localization)
    methods: dict[str, Any] = {}
    for name in matrix.methods:
        m0 = time.perf_counter()
        try:
            settings = for_pose_source(cfg.planner, cell.pose)
            planner = pool.planner(settings, name, cfg.curvature)
            if instrument is not None:
                instrument(name, planner)
            run = run_method(name, planner, track, cfg.simulator, opts)
            entry = results_document(track.name, track.length_m, [run], reference=ref)
            rec = method_record(run, entry["methods"][name], peak)
        except Exception as exc:  # a method that cannot race is recorded
            rec = {"error": f"{type(exc).__name__}: {exc}", "laps_completed": 0,
                   "laps_requested": matrix.laps, "clean": False}
        rec["wall_s"] = round(time.perf_counter() - m0, 2)
        methods[name] = rec
    return {
        "key": cell.key,
        "track": track.name,
        "track_spec": cell.track,
        "track_length_m": round(track.length_m, 2),
        "car": cell.car,
        "knows_car": car_spec(cell.car).knows_car,
        "pose": cell.pose,
        "limit_s": None if ref is None else ref["min_time_lap_s"],
        "v_max_mps": None if ref is None else ref["v_max_mps"],
        "reference_note": note,
        "rear_peak_slip_rad": peak,
        "methods": methods,
        "wall_s": round(time.perf_counter() - t0, 2),
    }


def cell_order(cells: list[Cell], length_m: Callable[[str], float]) -> list[Cell]:
    """`cells` in the order the workers take them: the (track, car) groups by their
    estimated cost (track length x ``POSE_COST`` of their poses), the costliest first, each
    group's cells together (its track, lines and planners are set up once per worker) and
    its costliest first; so the workers do not end on one long lidar cell."""
    def cost(c: Cell) -> float:
        return length_m(c.track) * POSE_COST.get(c.pose, 1.0)

    groups: dict[tuple[str, str], list[Cell]] = {}
    for c in cells:
        groups.setdefault((c.track, c.car), []).append(c)
    ordered = sorted(groups.values(), key=lambda g: -sum(cost(c) for c in g))
    return [c for g in ordered for c in sorted(g, key=lambda c: -cost(c))]


def _run_cell_task(args: tuple[Cell, Matrix]) -> dict[str, Any]:
    return run_cell(*args)


def _init_worker() -> None:
    os.environ.setdefault("MPLBACKEND", "Agg")


def _map(fn: Callable, items: list, jobs: int) -> Iterable:
    """`fn` over `items` in this process (`jobs` 1) or `jobs` spawned workers, in the
    order they finish."""
    if jobs <= 1 or len(items) <= 1:
        yield from map(fn, items)
        return
    ctx = mp.get_context("spawn")
    with ctx.Pool(min(jobs, len(items)), initializer=_init_worker) as pool:
        yield from pool.imap_unordered(fn, items, chunksize=1)


# ----------------------------------------------------------------------- table, summary
def _short(track: str) -> str:
    """A track spec's short name: ``gen:7`` -> ``gen-7``, a path -> its last part."""
    if track.startswith("gen:"):
        return "gen-" + track.removeprefix("gen:")
    return Path(track).name


def _fmt(v: Any, spec: str, none: str = "-") -> str:
    return none if v is None else format(v, spec)


def method_cell_text(rec: dict[str, Any] | None) -> str:
    """One method's figures in a table row (``METHOD_HEADER``'s columns)."""
    if rec is None:
        return " " * METHOD_WIDTH
    if rec.get("error"):
        return f"{'error':>6} {rec['error'][:METHOD_WIDTH - 7]:<{METHOD_WIDTH - 7}}"
    laps = f"{rec['laps_completed']}/{rec['laps_requested']}"
    solve = (f"{_fmt(rec['solve_ms_median'], '.1f')}/{_fmt(rec['solve_ms_p99'], '.1f')}/"
             f"{_fmt(rec.get('solve_ms_max'), '.1f')}")
    return (f"{_fmt(rec['ratio'], '6.3f', '     -')} {laps:>4} {rec['off_track']:>3} "
            f"{rec['recoveries']:>3} {rec['spins']:>3} "
            f"{_fmt(rec.get('max_slip_over_peak'), '5.2f', '    -')} "
            f"{_fmt(rec['below_limit_laps'], '>3')} "
            f"{_fmt(rec['over_cap_events'], '>3')} {solve:>14} {'ok' if rec['clean'] else 'x':>2}")


METHOD_HEADER = (f"{'ratio':>6} {'laps':>4} {'off':>3} {'rec':>3} {'spn':>3} {'slip':>5} "
                 f"{'<lm':>3} {'>cp':>3} {'solve ms':>14} {'cl':>2}")
METHOD_WIDTH = len(METHOD_HEADER)


def format_table(cells: list[dict[str, Any]], methods: Iterable[str]) -> str:
    """Rows = cells (track x car x pose), one block of columns per method."""
    methods = list(methods)
    label_w = 44
    head1 = f"{'':<{label_w}}" + "".join(f" | {m:^{METHOD_WIDTH}}" for m in methods)
    head2 = f"{'track':<14} {'car':<22} {'pose':<6}" + "".join(
        f" | {METHOD_HEADER}" for _ in methods)
    lines = [head1, head2, "-" * len(head2)]
    for c in cells:
        label = f"{c['track']:<14} {c['car']:<22} {c['pose']:<6}"
        lines.append(label + "".join(f" | {method_cell_text(c['methods'].get(m))}"
                                     for m in methods))
    legend = (
        "ratio = mean lap / the simulated car's minimum-time lap at the cap; laps = completed/"
        "asked; off = off-track events (out lap included); rec = recoveries; spn = spins "
        f"(|rear slip| beyond {SPIN_SLIP_FACTOR:g} x the tyres' peak > "
        f"{SPIN_MIN_DURATION_S:g} s); slip = the largest "
        "|rear slip| over that peak; <lm = laps below "
        "the limit; >cp = excursions over the cap; solve = median/p99/max [ms] (wall time of "
        "each solve beside the other workers: it depends on the machine's load, the laps do "
        "not: the bench's compute delay is fixed); cl = clean"
    )
    return "\n".join([*lines, legend])


def summarise(cells: list[dict[str, Any]], method: str) -> dict[str, Any]:
    """One method's figures over the cells it raced."""
    recs = [(c, c["methods"][method]) for c in cells if method in c["methods"]]

    def total(key: str) -> int:
        return int(sum(r.get(key) or 0 for _, r in recs))

    def worst_of(pred: Callable[[dict], bool]) -> tuple[float, str] | None:
        ratios = [(r["ratio"], f"{c['track']} {c['car']}") for c, r in recs
                  if pred(c) and r.get("ratio") is not None]
        return max(ratios, key=lambda x: x[0]) if ratios else None

    def worst(pred: Callable[[dict], bool]) -> float | None:
        w = worst_of(pred)
        return None if w is None else w[0]

    def where(pred: Callable[[dict], bool]) -> str | None:
        w = worst_of(pred)
        return None if w is None else w[1]

    p99 = [r["solve_ms_p99"] for _, r in recs if r.get("solve_ms_p99") is not None]
    slowest = [r["solve_ms_max"] for _, r in recs if r.get("solve_ms_max") is not None]
    return {
        "cells": len(recs),
        "clean": sum(bool(r.get("clean")) for _, r in recs),
        "worst_ratio": {p: worst(lambda c, p=p: c["knows_car"] and c["pose"] == p)
                        for p in ESTIMATORS},
        "worst_ratio_mismatch": worst(lambda c: not c["knows_car"]),
        "worst_cell": {p: where(lambda c, p=p: c["knows_car"] and c["pose"] == p)
                       for p in ESTIMATORS},
        "worst_cell_mismatch": where(lambda c: not c["knows_car"]),
        "off_track": total("off_track"),
        "recoveries": total("recoveries"),
        "spins": total("spins"),
        "below_limit_laps": total("below_limit_laps"),
        "over_cap_events": total("over_cap_events"),
        "unfinished": sum(r.get("laps_completed", 0) < r.get("laps_requested", 1)
                          for _, r in recs),
        "errors": sum(bool(r.get("error")) for _, r in recs),
        "worst_solve_ms_p99": max(p99) if p99 else None,
        "worst_solve_ms_max": max(slowest) if slowest else None,
    }


def summary_line(method: str, s: dict[str, Any]) -> str:
    """``robustness METHOD: N cells, clean k/N, worst ratio (truth/ekf/lidar) ..., ...``."""
    ratios = "/".join(_fmt(s["worst_ratio"][p], ".2f") for p in ESTIMATORS)
    mismatch = s["worst_ratio_mismatch"]
    return (
        f"robustness {method}: {s['cells']} cells, clean {s['clean']}/{s['cells']}, worst ratio "
        f"({'/'.join(ESTIMATORS)}) {ratios}"
        + ("" if mismatch is None else f", mismatch {mismatch:.2f}")
        + f", off-track {s['off_track']}, recoveries {s['recoveries']}, spins {s['spins']}, "
        f"below-limit {s['below_limit_laps']}, over-cap {s['over_cap_events']}, unfinished "
        f"{s['unfinished']}, solve p99 max {_fmt(s['worst_solve_ms_p99'], '.2f')} ms, slowest "
        f"tick {_fmt(s.get('worst_solve_ms_max'), '.1f')} ms"
    )


def _against(ratio: float | None, target: float, cell: str | None) -> str:
    if ratio is None:
        return "-"
    verdict = "met" if ratio <= target else "NOT met"
    return f"{ratio:.3f} ({cell}) vs {target:g} {verdict}"


def target_line(method: str, s: dict[str, Any]) -> str:
    """``targets METHOD: truth 1.004 (gen-3 default) vs 1.03 met; ekf ...; mismatch ...``:
    the worst ratio per pose source where the planner knows its car, and where it does not,
    each with its cell and against ``RATIO_TARGETS`` / ``MISMATCH_RATIO_TARGET``; then
    whether the cells were clean."""
    parts = [f"{p} {_against(s['worst_ratio'][p], RATIO_TARGETS[p], s['worst_cell'][p])}"
             for p in ESTIMATORS]
    parts.append("mismatch " + _against(s["worst_ratio_mismatch"], MISMATCH_RATIO_TARGET,
                                        s["worst_cell_mismatch"]))
    return (f"targets {method}: " + "; ".join(parts)
            + f"; clean {s['clean']}/{s['cells']} cells")


def wall_line(timings: dict[str, float]) -> str:
    """``wall time: 812 s (13.5 min; laps 40 s, cells 772 s) vs 30 min met``."""
    total = sum(timings.values())
    verdict = "met" if total <= MATRIX_WALL_TARGET_S else "NOT met"
    phases = ", ".join(f"{k} {v:.0f} s" for k, v in timings.items())
    return (f"wall time: {total:.0f} s ({total / 60:.1f} min; {phases}) vs "
            f"{MATRIX_WALL_TARGET_S / 60:.0f} min {verdict}")


def worst_cells(cells: list[dict[str, Any]], methods: Iterable[str], n: int = WORST_ROWS
                ) -> list[str]:
    """The `n` worst (cell, method)s: most rule breaks, then fewest laps, then the ratio."""
    rows = []
    for c in cells:
        for m in methods:
            r = c["methods"].get(m)
            if r is None:
                continue
            breaks = sum(r.get(k) or 0 for k in ("off_track", "recoveries", "spins",
                                                  "below_limit_laps", "over_cap_events"))
            missing = r.get("laps_requested", 0) - r.get("laps_completed", 0)
            rows.append(((missing, breaks, r.get("ratio") or 0.0), c, m, r))
    rows.sort(key=lambda x: x[0], reverse=True)
    out = []
    for _, c, m, r in rows[:n]:
        why = r.get("error") or "; ".join(filter(None, [r.get("aborted", ""),
                                                        *r.get("errors", [])]))
        out.append(f"{c['track']:<13} {c['car']:<22} {c['pose']:<6} {m:<12} "
                   f"{method_cell_text(r)}  {why}".rstrip())
    return out


GROUP_HEADER = (f"{'clean':>7} {'median':>6} {'worst':>6} {'off':>4} {'rec':>4} {'spn':>4} "
                f"{'unf':>3}")


def grouped_table(cells: list[dict[str, Any]], methods: Iterable[str],
                  tracks_dir: Path = TRACKS_DIR) -> str:
    """Rows = track group x car x pose; per method: clean cells of the group, the median
    and worst ratio, off-track events, recoveries, spins and unfinished cells."""
    methods = list(methods)
    group_of = {s: g for g, specs in track_groups(tracks_dir).items() for s in specs}
    groups: dict[tuple[str, str, str], list[dict]] = {}
    for c in cells:
        key = (group_of.get(c["track_spec"], "other"), c["car"], c["pose"])
        groups.setdefault(key, []).append(c)
    w = len(GROUP_HEADER)
    lines = [f"{'':<44}" + "".join(f" | {m:^{w}}" for m in methods),
             f"{'tracks':<14} {'car':<22} {'pose':<6}" + f" | {GROUP_HEADER}" * len(methods)]
    for (group, car, pose), members in groups.items():
        row = f"{group:<14} {car:<22} {pose:<6}"
        for m in methods:
            recs = [c["methods"][m] for c in members if m in c["methods"]]
            ratios = [r["ratio"] for r in recs if r.get("ratio") is not None]
            clean = f"{sum(bool(r.get('clean')) for r in recs)}/{len(recs)}"
            unf = sum(r.get("laps_completed", 0) < r.get("laps_requested", 1) for r in recs)
            row += (f" | {clean:>7} {_fmt(np.median(ratios) if ratios else None, '6.3f', '     -')}"
                    f" {_fmt(max(ratios) if ratios else None, '6.3f', '     -')} "
                    + " ".join(f"{sum(r.get(k) or 0 for r in recs):>4}"
                               for k in ("off_track", "recoveries", "spins"))
                    + f" {unf:>3}")
        lines.append(row)
    return "\n".join(lines)


def wall_by_kind(cells: list[dict[str, Any]], tracks_dir: Path = TRACKS_DIR
                 ) -> dict[str, dict[str, float]]:
    """Wall time [s] of the cells by track group x pose and by car: total and per cell."""
    group_of = {s: g for g, specs in track_groups(tracks_dir).items() for s in specs}
    kinds: dict[str, list[float]] = {}
    for c in cells:
        for kind in (f"{group_of.get(c['track_spec'], 'other')}/{c['pose']}", f"car {c['car']}"):
            kinds.setdefault(kind, []).append(c["wall_s"])
    return {k: {"cells": len(v), "total_s": round(sum(v), 1),
                "per_cell_s": round(sum(v) / len(v), 1)} for k, v in sorted(kinds.items())}


def report(cells: list[dict[str, Any]], matrix: Matrix, timings: dict[str, float]
           ) -> tuple[dict[str, Any], str]:
    """The results document and the text (table, worst cells, wall times, summary)."""
    order = {c.key: i for i, c in enumerate(matrix.cells())}
    cells = sorted(cells, key=lambda c: order.get(c["key"], len(order)))
    summary = {m: summarise(cells, m) for m in matrix.methods}
    kinds = wall_by_kind(cells)
    cap = _fmt(matrix.v_max_mps, "g", "the configuration's (4.18 m/s)")
    if matrix.ds_m is not None:
        grid = f", minimum-time grid {matrix.ds_m:g} m"
    elif matrix.long_track_ds_m is not None:
        grid = (f", minimum-time grid {matrix.long_track_ds_m:g} m on tracks over "
                f"{LONG_TRACK_M:g} m")
    else:
        grid = ""
    over = "" if not matrix.overlay else f", --config {matrix.overlay}"
    lines = [
        f"robustness matrix: {len(matrix.tracks)} tracks x {len(matrix.cars)} cars x "
        f"{len(matrix.poses)} poses, methods {', '.join(matrix.methods)}, {matrix.laps} flying "
        f"laps, cap {cap}{grid}{over}",
        "cars: " + "; ".join(f"{c} = {car_spec(c).summary}" for c in matrix.cars),
        "",
        format_table(cells, matrix.methods),
        "",
        "worst cells:",
        *worst_cells(cells, matrix.methods),
        "",
        "by track group x car x pose (median / worst ratio over the group's cells; unf = "
        "unfinished cells):",
        grouped_table(cells, matrix.methods),
        "",
        "wall time by kind of cell: " + ", ".join(
            f"{k} {v['cells']} x {v['per_cell_s']:.1f} s" for k, v in kinds.items()),
        wall_line(timings),
        "",
        *(target_line(m, summary[m]) for m in matrix.methods),
        *(summary_line(m, summary[m]) for m in matrix.methods),
    ]
    doc = {
        "matrix": {**asdict(matrix), "cells": len(matrix.cells())},
        "summary": summary,
        "cells": cells,
        "meta": {"wall_time_s": {k: round(v, 1) for k, v in timings.items()},
                 "wall_by_kind": kinds, "cars": {c: asdict(car_spec(c)) for c in matrix.cars}},
    }
    return doc, "\n".join(lines)


# ------------------------------------------------------------------------------- running
def _say(text: str) -> None:
    print(text, file=sys.stderr, flush=True)


def make_laps(matrix: Matrix, jobs: int) -> dict[str, Any]:
    """Phase 1: every lap of ``lap_tasks``, with a progress line each; the counts."""
    tasks = lap_tasks(matrix)
    _say(f"phase 1: {len(tasks)} minimum-time laps (cached ones are read) ...")
    counts = {"laps": len(tasks), "solved": 0, "cached": 0, "failed": 0}
    for k, out in enumerate(_map(solve_lap, tasks, jobs), start=1):
        if not out["ok"]:
            counts["failed"] += 1
            what = f"FAILED {out['error'][:120]}"
        elif out["cache_hit"]:
            counts["cached"] += 1
            what = "cached"
        else:
            counts["solved"] += 1
            what = f"solved in {out['wall_s']:.1f} s (lap {out['lap_time_s']:.3f} s)"
        _say(f"  [{k}/{len(tasks)}] {out['label']}: {what}")
    return counts


def _json_default(obj: Any) -> Any:
    """numpy scalars as Python numbers in ``cells.jsonl``."""
    if isinstance(obj, np.generic):
        return obj.item()
    raise TypeError(f"not JSON: {type(obj).__name__}")


def _cell_line(k: int, n: int, c: dict[str, Any]) -> str:
    parts = []
    for m, r in c["methods"].items():
        if r.get("error"):
            parts.append(f"{m} error")
            continue
        bad = [f"{r[x]} {x.replace('_', '-')}" for x in (
            "off_track", "recoveries", "spins", "below_limit_laps", "over_cap_events")
            if r.get(x)]
        if r["laps_completed"] < r["laps_requested"]:
            bad.append(f"{r['laps_completed']}/{r['laps_requested']} laps")
        parts.append(f"{m} {_fmt(r.get('ratio'), '.3f')} "
                     + ("clean" if r["clean"] else ", ".join(bad) or "rules"))
    return (f"  [{k}/{n}] {c['track']} {c['car']} {c['pose']}: " + "; ".join(parts)
            + f" ({c['wall_s']:.0f} s)")


def run_matrix(matrix: Matrix, out_dir: Path, jobs: int = 2, resume: bool = False
               ) -> tuple[dict[str, Any], str]:
    """Both phases; writes ``cells.jsonl``, ``robustness.json`` and ``robustness.txt``
    into `out_dir` and returns the document and the text."""
    out_dir.mkdir(parents=True, exist_ok=True)
    jsonl = out_dir / "cells.jsonl"
    timings: dict[str, float] = {}
    t0 = time.perf_counter()
    counts = make_laps(matrix, jobs)
    timings["minimum-time laps"] = time.perf_counter() - t0
    done: dict[str, dict] = {}
    if resume and jsonl.exists():
        for line in jsonl.read_text(encoding="utf-8").splitlines():
            if line.strip():
                c = json.loads(line)
                done[c["key"]] = c
    elif jsonl.exists():
        jsonl.unlink()
    wanted = {c.key for c in matrix.cells()}
    cells = [c for k, c in done.items() if k in wanted]
    # the costliest first, so the two workers finish together
    todo = cell_order([c for c in matrix.cells() if c.key not in done],
                      lambda t: _track(t).length_m)
    _say(f"phase 2: {len(todo)} cells ({len(cells)} from {jsonl.name}) in {jobs} workers ...")
    t1 = time.perf_counter()
    with jsonl.open("a", encoding="utf-8") as fh:
        for k, rec in enumerate(_map(_run_cell_task, [(c, matrix) for c in todo], jobs), 1):
            fh.write(json.dumps(rec, default=_json_default) + "\n")
            fh.flush()
            cells.append(rec)
            _say(_cell_line(k, len(todo), rec))
    timings["cells"] = time.perf_counter() - t1
    doc, text = report(cells, matrix, timings)
    doc["meta"]["minimum_time_laps"] = counts
    write_results(out_dir / "robustness.json", doc)
    (out_dir / "robustness.txt").write_text(text + "\n", encoding="utf-8")
    return doc, text


def build_parser() -> argparse.ArgumentParser:
    """The command line (module docstring)."""
    ap = argparse.ArgumentParser(
        prog="python -m benchmarks.robustness", description=__doc__.splitlines()[0],
        formatter_class=argparse.RawDescriptionHelpFormatter,
        epilog="cars: " + "; ".join(f"{c.name} = {c.summary}" for c in CARS.values()))
    ap.add_argument("--quick", action="store_true",
                    help=f"CI-sized subset: tracks {', '.join(QUICK_TRACKS)}, cars "
                    f"{', '.join(QUICK_CARS)}, pose {', '.join(QUICK_POSES)} (--tracks, "
                    "--cars, --poses given beside it replace its choice)")
    ap.add_argument("--tracks", default=None,
                    help="comma list of groups (all, builtin, f1tenth, generated), map416 or "
                    "track specs (default all)")
    ap.add_argument("--cars", default=None,
                    help=f"comma list of {', '.join(CARS)} or varied:SEED (a seeded variant "
                    f"of the identified car; default {','.join(DEFAULT_CARS)})")
    ap.add_argument("--poses", default=None,
                    help=f"comma list of {', '.join(ESTIMATORS)} (default all)")
    ap.add_argument("--methods", default=",".join(NEAR_LIMIT_METHODS),
                    help="comma list of registry methods (default the near-limit ones, "
                    f"{','.join(NEAR_LIMIT_METHODS)})")
    ap.add_argument("--laps", type=int, default=2, help="flying laps per cell (default 2)")
    ap.add_argument("--v-max", type=float, default=None,
                    help="every method's cap and the limit's top speed [m/s] (default the "
                    "configuration's 4.18; e.g. 10 on the F1TENTH maps)")
    ap.add_argument("--min-time-ds", type=float, default=None,
                    help="grid [m] of the limit's and the raceline's minimum-time laps on "
                    "every track (default: the configuration's 0.1 m, and 0.25 m on tracks "
                    "longer than 200 m, the 260-460 m F1TENTH maps, where a 0.1 m grid takes "
                    "minutes per lap; cimpcc-line's line keeps 0.1)")
    ap.add_argument("--config", default=None,
                    help="a TOML file of configuration tables laid over every car's (e.g. "
                    "[planner.raceline] settings; default none)")
    ap.add_argument("--jobs", type=int, default=2, help="worker processes (default 2)")
    ap.add_argument("--out", default=None, help="output folder (default runs/robust-<time>)")
    ap.add_argument("--resume", action="store_true",
                    help="keep the cells already in OUT/cells.jsonl, race only the others")
    ap.add_argument("--tracks-dir", default=str(TRACKS_DIR),
                    help=f"the shared track data (default {TRACKS_DIR})")
    return ap


def matrix_from_args(args: argparse.Namespace) -> Matrix:
    """The matrix of the command line (BenchError on a wrong choice)."""
    tracks_dir = Path(args.tracks_dir)
    tracks = resolve_tracks(args.tracks or (",".join(QUICK_TRACKS) if args.quick else "all"),
                            tracks_dir)
    try:
        cars = car_names(args.cars or ",".join(QUICK_CARS if args.quick else DEFAULT_CARS))
    except UnknownCarError as exc:
        raise BenchError(str(exc)) from None
    poses = _names(args.poses or ",".join(QUICK_POSES if args.quick else ESTIMATORS),
                   ESTIMATORS, "pose")
    methods = parse_methods(args.methods)
    if args.laps < 1:
        raise BenchError("--laps must be at least 1")
    if args.jobs < 1:
        raise BenchError("--jobs must be at least 1")
    if args.v_max is not None and not 1.0 < args.v_max <= 20.0:
        raise BenchError("--v-max must be in (1, 20] m/s")
    ds = getattr(args, "min_time_ds", None)
    if ds is not None and not 0.02 <= ds <= 1.0:
        raise BenchError("--min-time-ds must be in [0.02, 1] m")
    for spec in tracks:
        load_track(spec)  # a wrong track fails here, before anything runs
    config = getattr(args, "config", None)
    overlay = "" if config is None else load_overlay(config)
    return Matrix(tuple(tracks), tuple(cars), tuple(poses), tuple(methods), args.laps,
                  args.v_max, ds, overlay)


def main(argv: list[str] | None = None) -> int:
    """Run the benchmark; exit code 0, or 2 on bad arguments."""
    args = build_parser().parse_args(argv)
    try:
        matrix = matrix_from_args(args)
    except (BenchError, ValueError) as exc:
        print(f"robustness: error: {exc}", file=sys.stderr)
        return 2
    variants = [m for m in matrix.methods if not METHODS[m].in_planner]
    if variants:
        _say(f"{', '.join(variants)}: raced as the base method with the configuration's "
             "settings (no sweep, no tuned file)")
    out = Path(args.out or Path("runs") / time.strftime("robust-%Y%m%d-%H%M%S"))
    _doc, text = run_matrix(matrix, out, args.jobs, args.resume)
    print(text)
    print(f"results: {out / 'robustness.json'}, {out / 'robustness.txt'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
