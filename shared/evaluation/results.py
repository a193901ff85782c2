"""What a bench run produces: per-lap records, traces, and the results.json document.

``results.json`` has this shape (extra keys allowed)::

    {"track": str, "track_length_m": float,
     "methods": {NAME: {"laps": [{"lap_time_s", "mean_speed_mps", "off_track_events",
                                  "max_abs_e_con_m"}, ...],
                        "lap_time_s": {"max", "min", "mean"},
                        "mean_speed_mps": {"max", "min", "mean"},
                        "solve_time_ms": {"median", "p95", "p99", "max"},
                        "solver_failures": int, "completed_laps": int,
                        "ratio_to_min_time": float | None}},
     "reference": {"min_time_lap_s", "v_max_mps", ...}}

``reference`` (when the bench computed it) is the minimum-time lap of the simulator's car
(``services.planner.mintime.ocp``); each method's ``ratio_to_min_time`` is its mean lap time
over that lap (1.0 would be the physical limit). The limit is also a rule of the comparison:
a lap faster than it was driven by breaking a rule the limit keeps (cutting inside the
boundaries, or above the speed cap), so each method records ``below_limit_laps`` (laps faster
than the limit), ``over_cap_events`` (times the car's measured speed rose above the cap by
more than ``CAP_TOLERANCE``) with ``max_speed_mps``, and ``violations`` = off-track events of
the whole run + laps below the limit + excursions over the cap; ``errors`` names each kind
found (an empty list: a clean run).
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

#: Where a race starts: the car at rest this far past the start line [m], so it drives an
#: out lap (nearly a whole lap, not timed) and the timed laps are flying laps. The bench's
#: start (``LoopOptions.start_offset_m``) and the simulator service's (``racestack up``).
OUT_LAP_START_M = 0.3
#: A lap counts as below the limit when it is faster than the minimum-time lap by more than
#: this [s] (the lap timer's interpolation and the limit's rounding).
LIMIT_TOLERANCE_S = 1e-3
#: The car's speed counts as over the cap above (1 + this) x the limit's top speed.
CAP_TOLERANCE = 0.01


@dataclass(frozen=True)
class LapRecord:
    """One timed lap.

    Attributes:
        lap_time_s: lap time [s].
        mean_speed_mps: lap length / lap time [m/s] (the paper's "velocity" of a lap).
        off_track_events: times the footprint left the track during the lap.
        max_abs_e_con_m: largest |contour error| of the car during the lap [m].
    """

    lap_time_s: float
    mean_speed_mps: float
    off_track_events: int
    max_abs_e_con_m: float

    def to_json(self) -> dict[str, Any]:
        """The lap as a JSON object."""
        return {
            "lap_time_s": self.lap_time_s,
            "mean_speed_mps": self.mean_speed_mps,
            "off_track_events": self.off_track_events,
            "max_abs_e_con_m": self.max_abs_e_con_m,
        }


@dataclass
class Trace:
    """Time series of a run, one row per planner tick (arrays of equal length).

    Attributes:
        t_s: simulation time [s]; s_m: progress along the centreline in [0, L) [m];
        x_m, y_m: car position [m]; speed_mps: measured speed [m/s];
        cmd_speed_mps: commanded speed [m/s]; e_con_m: contour error [m];
        beta: beta at the car; lap: index of the lap the row belongs to (0 = out lap);
        rear_slip_rad: the simulated car's rear-axle slip angle [rad] (the simulator's
            ``tyre_state``; 0 in its kinematic regime; empty when the source has none).
    """

    t_s: list[float] = field(default_factory=list)
    s_m: list[float] = field(default_factory=list)
    x_m: list[float] = field(default_factory=list)
    y_m: list[float] = field(default_factory=list)
    speed_mps: list[float] = field(default_factory=list)
    cmd_speed_mps: list[float] = field(default_factory=list)
    e_con_m: list[float] = field(default_factory=list)
    beta: list[float] = field(default_factory=list)
    lap: list[int] = field(default_factory=list)
    rear_slip_rad: list[float] = field(default_factory=list)

    def arrays(self) -> dict[str, np.ndarray]:
        """Every column as a numpy array."""
        return {k: np.asarray(v) for k, v in self.__dict__.items()}


@dataclass
class MethodRun:
    """Everything one method produced in a bench run."""

    name: str
    laps: list[LapRecord]
    trace: Trace
    solve_times_ms: list[float]
    solver_failures: int
    requested_laps: int
    extra: dict[str, Any] = field(default_factory=dict)
    #: every time the footprint left the track in the whole run: the out lap, the timed
    #: laps and a lap cut short (a method lost in its out lap has no timed lap to count it)
    run_off_track_events: int = 0
    #: of those, before the first timed lap started
    out_lap_off_track_events: int = 0
    #: where the car (its CoG) was at each off-track event of the run: (x [m], y [m])
    off_track_xy: list[tuple[float, float]] = field(default_factory=list)

    @property
    def completed_laps(self) -> int:
        """Timed laps completed."""
        return len(self.laps)


def _stats(values: list[float]) -> dict[str, float | None]:
    if not values:
        return {"max": None, "min": None, "mean": None}
    return {"max": max(values), "min": min(values), "mean": float(np.mean(values))}


def solve_time_stats(times_ms: list[float]) -> dict[str, float | None]:
    """median / p95 / p99 / max of solve times [ms]."""
    if not times_ms:
        return {"median": None, "p95": None, "p99": None, "max": None}
    t = np.asarray(times_ms)
    return {
        "median": float(np.median(t)),
        "p95": float(np.percentile(t, 95)),
        "p99": float(np.percentile(t, 99)),
        "max": float(t.max()),
    }


def method_json(run: MethodRun) -> dict[str, Any]:
    """The results.json entry of one method."""
    return {
        "laps": [lap.to_json() for lap in run.laps],
        "lap_time_s": _stats([lap.lap_time_s for lap in run.laps]),
        "mean_speed_mps": _stats([lap.mean_speed_mps for lap in run.laps]),
        "solve_time_ms": solve_time_stats(run.solve_times_ms),
        "solver_failures": run.solver_failures,
        "completed_laps": run.completed_laps,
        "requested_laps": run.requested_laps,
        "off_track_events": sum(lap.off_track_events for lap in run.laps),
        "off_track_events_all": run.run_off_track_events,
        "out_lap_off_track_events": run.out_lap_off_track_events,
        **run.extra,
    }


def reference_document(lap: Any) -> dict[str, Any]:
    """The ``reference`` of results.json from a minimum-time lap (a
    ``services.planner.MinTimeLap``, read by attribute: this package imports no service)."""
    return {
        "min_time_lap_s": lap.lap_time_s,
        "v_max_mps": lap.v_max_mps,
        "tyre_model": lap.tyre_model,
        "ds_m": lap.ds_m,
        "margin_m": lap.margin_m,
        "solver_status": lap.status,
        "solve_time_s": lap.solve_time_s,
        "cache_hit": lap.cache_hit,
    }


def results_document(
    track_name: str,
    track_length_m: float,
    runs: list[MethodRun],
    meta: dict[str, Any] | None = None,
    reference: dict[str, Any] | None = None,
) -> dict[str, Any]:
    """The whole results.json document.

    Args:
        reference: the minimum-time lap (``min_time_lap_s`` [s], ``v_max_mps`` [m/s], ...);
            adds ``reference`` and each method's ``ratio_to_min_time`` = mean lap /
            ``min_time_lap_s`` (None without laps).
    """
    doc: dict[str, Any] = {
        "track": track_name,
        "track_length_m": track_length_m,
        "methods": {run.name: method_json(run) for run in runs},
    }
    if reference is not None:
        doc["reference"] = dict(reference)
        limit = float(reference["min_time_lap_s"])
        cap = reference.get("v_max_mps")
        for run in runs:
            entry = doc["methods"][run.name]
            mean = entry["lap_time_s"]["mean"]
            entry["ratio_to_min_time"] = None if mean is None else mean / limit
            entry.update(rule_check(run, limit, None if cap is None else float(cap)))
    if meta:
        doc["meta"] = meta
    return doc


def over_cap_events(speed_mps: np.ndarray, cap_mps: float) -> int:
    """Times the speed rose above ``(1 + CAP_TOLERANCE) cap_mps`` (each excursion once)."""
    over = np.asarray(speed_mps, dtype=float) > (1.0 + CAP_TOLERANCE) * cap_mps
    return int(np.count_nonzero(over[1:] & ~over[:-1]) + (1 if over.size and over[0] else 0))


def rule_check(run: MethodRun, limit_s: float, cap_mps: float | None) -> dict[str, Any]:
    """A run against the rules the limit keeps (module docstring): ``below_limit_laps``,
    ``over_cap_events``, ``max_speed_mps``, ``violations`` and ``errors`` (one line each)."""
    fast = [lap.lap_time_s for lap in run.laps if lap.lap_time_s < limit_s - LIMIT_TOLERANCE_S]
    speed = np.abs(np.asarray(run.trace.speed_mps, dtype=float))
    v_top = float(speed.max()) if speed.size else None
    over = 0 if cap_mps is None or not speed.size else over_cap_events(speed, cap_mps)
    errors = []
    if run.run_off_track_events:
        errors.append(f"{run.run_off_track_events} off-track events")
    if fast:
        errors.append(
            f"{len(fast)} laps below the limit (fastest {min(fast):.3f} s < {limit_s:.3f} s): "
            "a lap faster than the minimum-time lap broke a rule the limit keeps"
        )
    if over:
        errors.append(
            f"car speed over the {cap_mps:g} m/s cap {over} times (max {v_top:.2f} m/s)"
        )
    return {
        "below_limit_laps": len(fast),
        "over_cap_events": over,
        "max_speed_mps": v_top,
        "violations": run.run_off_track_events + len(fast) + over,
        "errors": errors,
    }


def _clean(obj: Any) -> Any:
    """JSON-safe copy: numpy scalars to Python, non-finite floats to None."""
    if isinstance(obj, dict):
        return {str(k): _clean(v) for k, v in obj.items()}
    if isinstance(obj, list | tuple):
        return [_clean(v) for v in obj]
    if isinstance(obj, np.generic):
        obj = obj.item()
    if isinstance(obj, float) and not math.isfinite(obj):
        return None
    return obj


def write_results(path: Path, doc: dict[str, Any]) -> None:
    """Write results.json atomically (a crash never leaves half a file)."""
    tmp = path.with_suffix(".json.tmp")
    tmp.write_text(json.dumps(_clean(doc), indent=2) + "\n", encoding="utf-8")
    tmp.replace(path)
