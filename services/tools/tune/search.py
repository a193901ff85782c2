"""What ``racestack tune`` searches and how it scores a trial: pure functions, no I/O.

A **search space** per method lists its parameters (bounds, log scale, the configuration's
value) and maps a point to a configuration *overlay*: the nested TOML tables of the keys it
sets, e.g. ``{"planner": {"cimpcc": {"v_up_mps": [4.18, 3.8], ...}}, "curvature": {...}}``.
The same overlay is what a trial races and what ``best.toml`` holds, so the written file is
exactly the configuration that was measured (values are rounded before either).

Velocity pairs ``(v_l, v_p)``: the paper sets ``v_l = 1.1 v_p`` in both its pairs (4.18 /
3.8 and 2.72 / 2.47), and so do we: one speed per pair is searched and ``v_l`` follows. The
lag error ties the car's speed to the progress speed, so the two references of a pair can
only differ by a small bias; the paper's ratio is kept and the search spends its 40-trial
budget on six dimensions instead of eight. ``v_low`` is searched as a share of ``v_up``, so
the corner speed never exceeds the straight speed.

**Score** of a trial (``score``): the mean lap time over every timed lap of every seed. A
trial is infeasible (Optuna constraints, each ``<= 0`` when met) when the car left the
track (footprint, whole run with the out lap), the recovery rule took over, the car's body
came closer than ``margin_m`` to a boundary, or fewer laps than asked were driven; an
infeasible trial's value is still its mean lap when it has one (``PENALTY_S`` when it has
none), and the sampler ranks it behind every feasible trial by how much it violated.
"""

from __future__ import annotations

import hashlib
import json
import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

from shared.config import RacestackConfig
from shared.config.methods import CIMPCC, CIMPCC_LINE, METHODS, MPCC, RACELINE
from shared.config.planner import CIMPCC_LINE_WEIGHTS

#: v_l = V_RATIO * v_p in every velocity pair (the paper's pairs).
V_RATIO = 1.1
#: Value [s] of a trial that drove no complete set of laps (it is infeasible anyway).
PENALTY_S = 1000.0
#: Names of a trial's constraints (Optuna ``Trial.set_constraint``; each <= 0 when met).
CONSTRAINTS = (
    "off_track_events", "recoveries", "missing_laps", "margin_shortfall_m", "spins",
    "below_limit_laps",
)
#: How a family's cells make one objective (``family_score``): the worst or the mean ratio.
AGGREGATES = ("worst", "mean")
#: Significant digits kept of a searched weight (speeds: SPEED_DECIMALS decimals).
SIGNIFICANT_DIGITS = 4
SPEED_DECIMALS = 2

Params = Mapping[str, float]
Overlay = dict[str, Any]


class UnknownMethodError(ValueError):
    """A method ``racestack tune`` cannot search."""


@dataclass(frozen=True)
class ParamSpec:
    """One searched parameter.

    Attributes:
        name: the Optuna parameter name.
        low, high: bounds (inclusive).
        log: sample on a log scale.
        doc: what it is, with its unit.
    """

    name: str
    low: float
    high: float
    log: bool
    doc: str

    def clip(self, value: float) -> float:
        """`value` moved into the bounds."""
        return min(max(float(value), self.low), self.high)


@dataclass(frozen=True)
class SearchSpace:
    """The parameters of one method and their mapping to a configuration overlay.

    Attributes:
        method: a method of the registry (``shared.config.methods``) with a search space.
        params: the searched parameters.
        overlay: a point (name -> value) -> the configuration overlay it races.
        from_config: the point a configuration already has (clipped into the bounds): the
            study's first, enqueued trial, so the history starts at the baseline.
    """

    method: str
    params: tuple[ParamSpec, ...]
    overlay: Callable[[Params], Overlay]
    from_config: Callable[[RacestackConfig], dict[str, float]] = field(repr=False)

    def names(self) -> list[str]:
        """The parameter names in order."""
        return [p.name for p in self.params]

    def baseline(self, cfg: RacestackConfig) -> dict[str, float]:
        """The configuration's own point, inside the bounds."""
        raw = self.from_config(cfg)
        return {p.name: p.clip(raw[p.name]) for p in self.params}


def round_sig(x: float, digits: int = SIGNIFICANT_DIGITS) -> float:
    """`x` rounded to `digits` significant digits (0 stays 0)."""
    if x == 0 or not math.isfinite(x):
        return float(x)
    return round(float(x), digits - 1 - math.floor(math.log10(abs(x))))


def speed_pair(v_p: float) -> list[float]:
    """The velocity pair ``[v_l, v_p]`` with ``v_l = V_RATIO v_p``, rounded to 0.01 m/s."""
    v_p = round(float(v_p), SPEED_DECIMALS)
    return [round(V_RATIO * v_p, SPEED_DECIMALS), v_p]


def top_progress_speed(v_max_mps: float) -> float:
    """The largest searched progress speed: ``v_l = V_RATIO v_p`` stays at most v_max."""
    return math.floor(v_max_mps / V_RATIO * 10**SPEED_DECIMALS + 1e-6) / 10**SPEED_DECIMALS


# ---------------------------------------------------------------------------- the spaces
def cimpcc_space(v_max_mps: float) -> SearchSpace:
    """CiMPCC: v_up, v_low (share of v_up), alpha, window, R3 (both entries), gamma."""
    top = top_progress_speed(v_max_mps)
    params = (
        ParamSpec("v_up_p", min(2.5, top), top, False, "v_p of v_up [m/s] (v_l = 1.1 v_p)"),
        ParamSpec("v_low_share", 0.4, 1.0, False, "v_low = share x v_up (both entries)"),
        ParamSpec("alpha", 0.5, 50.0, True, "g(K) = exp(-alpha K^2) sensitivity"),
        ParamSpec("window_m", 0.3, 4.0, False, "curvature moving-average window [m]"),
        ParamSpec("r3", 4.0, 400.0, True, "R3 = diag(r3, r3): pull towards v_up / v_low"),
        ParamSpec("gamma", 4.0, 400.0, True, "progress reward gamma"),
    )

    def overlay(p: Params) -> Overlay:
        v_up = speed_pair(p["v_up_p"])
        v_low = speed_pair(p["v_low_share"] * v_up[1])
        r3 = round_sig(p["r3"])
        return {
            "planner": {
                METHODS[CIMPCC].section: {
                    "v_up_mps": v_up,
                    "v_low_mps": v_low,
                    "r3_velocity": [r3, r3],
                    "gamma": round_sig(p["gamma"]),
                }
            },
            "curvature": {"alpha": round_sig(p["alpha"]), "window_m": round_sig(p["window_m"])},
        }

    def from_config(cfg: RacestackConfig) -> dict[str, float]:
        w = cfg.planner.cimpcc
        up = w.v_up_mps[1]
        return {
            "v_up_p": up,
            "v_low_share": w.v_low_mps[1] / up if up > 0 else 1.0,
            "alpha": cfg.curvature.alpha,
            "window_m": cfg.curvature.window_m,
            "r3": w.r3_velocity[1],
            "gamma": w.gamma,
        }

    return SearchSpace(CIMPCC, params, overlay, from_config)


def mpcc_space(v_max_mps: float) -> SearchSpace:
    """MPCC: its speed reference u_ref (v_l = 1.1 v_p) and R2 (speed entries, steering)."""
    top = top_progress_speed(v_max_mps)
    params = (
        ParamSpec("v_p_ref", min(1.5, top), top, False, "u_ref v_p [m/s] (v_l = 1.1 v_p)"),
        ParamSpec("r2_speed", 4.0, 400.0, True, "R2 weight of v_l and v_p on u_ref"),
        ParamSpec("r2_delta", 1.0, 100.0, True, "R2 weight of the steering angle"),
    )

    def overlay(p: Params) -> Overlay:
        v_l, v_p = speed_pair(p["v_p_ref"])
        r_v = round_sig(p["r2_speed"])
        return {
            "planner": {
                METHODS[MPCC].section: {
                    "u_ref": [v_l, 0.0, v_p],
                    "r2_input": [r_v, round_sig(p["r2_delta"]), r_v],
                }
            }
        }

    def from_config(cfg: RacestackConfig) -> dict[str, float]:
        w = cfg.planner.mpcc
        return {"v_p_ref": w.u_ref[2], "r2_speed": w.r2_input[2], "r2_delta": w.r2_input[1]}

    return SearchSpace(MPCC, params, overlay, from_config)


#: The raceline's tracker gains (either line): steering gain, look-ahead, drift correction.
_TRACKER = (
    ParamSpec("k_lateral_radpm", 0.1, 2.0, True, "steering per m of look-ahead error [rad/m]"),
    ParamSpec("lookahead_time_s", 0.2, 1.2, False, "look-ahead per m/s of speed [s]"),
    ParamSpec("lookahead_min_m", 0.2, 1.5, False, "shortest look-ahead [m]"),
    ParamSpec("k_outward_per_s2", 0.0, 160.0, False, "acceleration cut per m of outward drift"),
)
#: ... and the line's own settings, per line kind.
_LINE = {
    "min_time": (
        ParamSpec("min_time_margin_m", 0.0, 0.15, False,
                  "footprint kept this far inside the boundaries [m] (0.01 m steps: each "
                  "value is one cached minimum-time solve)"),
    ),
    "min_curvature": (
        ParamSpec("margin_m", 0.2, 0.45, False, "line kept this far inside the boundaries [m]"),
        ParamSpec("a_lat_mps2", 3.0, 9.0, False, "lateral acceleration of the profile"),
        ParamSpec("a_accel_mps2", 2.0, 8.0, False, "acceleration of the profile"),
        ParamSpec("a_brake_mps2", 2.0, 9.0, False, "braking of the profile"),
    ),
}


def raceline_space(v_max_mps: float, line: str = "min_time") -> SearchSpace:
    """The raceline (``[planner.raceline]``): its line's margin (and, for the
    minimum-curvature line, its speed profile's limits) and the tracker's gains.

    The speed cap is not searched: it is set to `v_max_mps`, like the MPC methods' v_up."""
    params = (*_LINE[line], *_TRACKER)

    def overlay(p: Params) -> Overlay:
        table: dict[str, float] = {s.name: round_sig(p[s.name]) for s in params}
        if "min_time_margin_m" in table:
            table["min_time_margin_m"] = round(p["min_time_margin_m"], 2)
        table["v_max_mps"] = float(v_max_mps)
        return {"planner": {METHODS[RACELINE].section: table}}

    def from_config(cfg: RacestackConfig) -> dict[str, float]:
        r = cfg.planner.raceline
        return {s.name: float(getattr(r, s.name)) for s in params}

    return SearchSpace(RACELINE, params, overlay, from_config)


def cimpcc_line_space(v_max_mps: float) -> SearchSpace:
    """cimpcc-line (``[planner.cimpcc_line]``): the cost's contouring, lag, steering-rate,
    speed-pull and progress weights, the pose lead, and the minimum-time line it follows
    (grip share and footprint margin, each rounded to 0.01: every value is one cached
    minimum-time solve). The top speed is `v_max_mps`, like the other methods' cap."""
    params = (
        ParamSpec("q_contour", 100.0, 5000.0, True, "Q contouring weight"),
        ParamSpec("q_lag", 100.0, 5000.0, True, "Q lag weight"),
        ParamSpec("r1_delta", 50.0, 3500.0, True, "R1 weight of the steering rate"),
        ParamSpec("r3", 4.0, 400.0, True, "R3 = diag(r3, r3): pull towards the profile speed"),
        ParamSpec("gamma", 4.0, 1000.0, True, "progress reward gamma"),
        ParamSpec("lead_pose_s", 0.0, 0.08, False, "plan from the pose this far ahead [s]"),
        ParamSpec("grip_fraction", 0.93, 1.0, False, "the line's share of the tyres' mu"),
        ParamSpec("line_margin_m", 0.03, 0.08, False, "the line's footprint margin [m]"),
    )

    def overlay(p: Params) -> Overlay:
        base = CIMPCC_LINE_WEIGHTS
        r1 = base.r1_delta_u
        r3 = round_sig(p["r3"])
        return {
            "planner": {
                METHODS[CIMPCC_LINE].section: {
                    "weights": {
                        "q_contour": round_sig(p["q_contour"]),
                        "q_lag": round_sig(p["q_lag"]),
                        "r1_delta_u": [r1[0], round_sig(p["r1_delta"]), r1[2]],
                        "r3_velocity": [r3, r3],
                        "gamma": round_sig(p["gamma"]),
                    },
                    "lead_pose_s": round(p["lead_pose_s"], 3),
                    "grip_fraction": round(p["grip_fraction"], 2),
                    "line_margin_m": round(p["line_margin_m"], 2),
                    "v_max_mps": float(v_max_mps),
                }
            }
        }

    def from_config(cfg: RacestackConfig) -> dict[str, float]:
        line = cfg.planner.cimpcc_line
        w = line.weights
        return {
            "q_contour": w.q_contour,
            "q_lag": w.q_lag,
            "r1_delta": w.r1_delta_u[1],
            "r3": w.r3_velocity[1],
            "gamma": w.gamma,
            "lead_pose_s": line.lead_pose_s,
            "grip_fraction": line.grip_fraction,
            "line_margin_m": line.line_margin_m,
        }

    return SearchSpace(CIMPCC_LINE, params, overlay, from_config)


#: The search space of each method ``racestack tune`` can search (by the registry's names):
#: ``builder(v_max_mps, cfg) -> SearchSpace``.
SPACES: dict[str, Callable[[float, RacestackConfig], SearchSpace]] = {
    CIMPCC: lambda v, cfg: cimpcc_space(v),
    MPCC: lambda v, cfg: mpcc_space(v),
    RACELINE: lambda v, cfg: raceline_space(v, cfg.planner.raceline.line),
    CIMPCC_LINE: lambda v, cfg: cimpcc_line_space(v),
}


def tunable_methods() -> tuple[str, ...]:
    """The registry's methods that have a search space, in registry order."""
    return tuple(name for name in METHODS if name in SPACES)


def space_for(method: str, v_max_mps: float, cfg: RacestackConfig | None = None) -> SearchSpace:
    """The search space of `method` with top speed `v_max_mps` (the raceline's depends on
    `cfg`'s line kind); UnknownMethodError for a method tune does not know."""
    if method not in SPACES:
        raise UnknownMethodError(
            f"unknown method {method!r}; choose from {', '.join(tunable_methods())}"
        )
    if not 0.5 <= v_max_mps <= 20.0:
        raise ValueError(f"--v-max must be in [0.5, 20] m/s, got {v_max_mps:g}")
    return SPACES[method](v_max_mps, cfg or RacestackConfig())


# ---------------------------------------------------------------------------- overlays
def deep_merge(base: Mapping[str, Any], overlay: Mapping[str, Any]) -> dict[str, Any]:
    """`base` with `overlay` laid over it: tables merge key by key, other values replace."""
    out: dict[str, Any] = dict(base)
    for key, value in overlay.items():
        if isinstance(value, Mapping) and isinstance(out.get(key), Mapping):
            out[key] = deep_merge(out[key], value)
        else:
            out[key] = value
    return out


def complete_overlay(overlay: Overlay, cfg: RacestackConfig) -> Overlay:
    """`overlay` with each method weight table it touches written in full from `cfg`.

    A partial ``[planner.mpcc]`` table would take the keys it leaves out from
    ``MethodWeights``' class defaults (CiMPCC's, e.g. R3 = diag(40, 40)) instead of MPCC's
    own, so the tuned keys are laid over the base configuration's whole weight set."""
    out = deep_merge({}, overlay)
    for path in {spec.weights for spec in METHODS.values() if spec.weights}:
        parts = path.split(".")
        table: Any = out.get("planner", {})
        for part in parts:
            table = table.get(part) if isinstance(table, Mapping) else None
        if table is None:
            continue
        full: Any = cfg.planner
        for part in parts:
            full = getattr(full, part)
        parent = out["planner"]
        for part in parts[:-1]:
            parent = parent[part]
        parent[parts[-1]] = deep_merge(full.model_dump(mode="json"), table)
    return out


def dotted(d: Mapping[str, Any], prefix: str = "") -> list[str]:
    """The dotted keys of the leaves of nested tables (``planner.cimpcc.gamma``)."""
    out = []
    for k, v in d.items():
        key = f"{prefix}{k}"
        out += dotted(v, key + ".") if isinstance(v, Mapping) else [key]
    return out


def fingerprint(data: Any, n: int = 8) -> str:
    """A short, stable hash of JSON-able `data` (track geometry, a configuration)."""
    text = json.dumps(data, sort_keys=True, separators=(",", ":"), default=str)
    return hashlib.sha1(text.encode()).hexdigest()[:n]


# ---------------------------------------------------------------------------- scoring
@dataclass(frozen=True)
class SeedResult:
    """What one seed's run produced.

    Attributes:
        seed: the noise seed.
        lap_times_s: the timed laps completed [s].
        off_track_events: footprint departures in the whole run (out lap included).
        recoveries: episodes of the recovery rule.
        min_clearance_m: the smallest distance of the car's body to a boundary [m] (the
            CoG's distance to the nearer boundary minus half the car's width), or None.
        aborted: why the run stopped early ("" when it ran to the end).
        spins: times the rear slip stayed beyond its tyres' peak (``shared.evaluation.spins``).
        below_limit_laps: laps faster than the car's minimum-time lap (a broken rule).
    """

    seed: int
    lap_times_s: tuple[float, ...]
    off_track_events: int
    recoveries: int
    min_clearance_m: float | None
    aborted: str = ""
    spins: int = 0
    below_limit_laps: int = 0

    def to_json(self) -> dict[str, Any]:
        """The result as plain JSON values."""
        return {
            "seed": self.seed,
            "lap_times_s": list(self.lap_times_s),
            "off_track_events": self.off_track_events,
            "recoveries": self.recoveries,
            "min_clearance_m": self.min_clearance_m,
            "aborted": self.aborted,
            "spins": self.spins,
            "below_limit_laps": self.below_limit_laps,
        }


@dataclass(frozen=True)
class Score:
    """A trial's value and constraints.

    Attributes:
        value: the objective [s] (mean lap, or PENALTY_S without a complete set of laps).
        constraints: (off-track events, recoveries, missing laps, margin shortfall [m],
            spins, laps below the limit), as ``CONSTRAINTS``; each <= 0 when met.
        reasons: why the trial is infeasible, one phrase each (empty: feasible).
        mean_lap_s: the mean of the laps driven, or None.
    """

    value: float
    constraints: tuple[float, ...]
    reasons: tuple[str, ...]
    mean_lap_s: float | None

    @property
    def feasible(self) -> bool:
        """All constraints met."""
        return all(c <= 0.0 for c in self.constraints)


def is_infeasible(result: SeedResult, laps: int, margin_m: float) -> bool:
    """Whether one seed already makes the trial infeasible (the rest need not run)."""
    clearance_short = result.min_clearance_m is None or result.min_clearance_m < margin_m
    return bool(
        result.aborted
        or result.off_track_events
        or result.recoveries
        or len(result.lap_times_s) < laps
        or clearance_short
        or result.spins
        or result.below_limit_laps
    )


def score(results: Sequence[SeedResult], laps: int, n_seeds: int, margin_m: float) -> Score:
    """Score the seeds run so far (`n_seeds` asked; the rest were skipped, the trial being
    infeasible already): laps missing count only in the seeds that ran."""
    times = [t for r in results for t in r.lap_times_s]
    off = sum(r.off_track_events for r in results)
    rec = sum(r.recoveries for r in results)
    missing = sum(max(laps - len(r.lap_times_s), 0) for r in results)
    spins = sum(r.spins for r in results)
    below = sum(r.below_limit_laps for r in results)
    clear = [r.min_clearance_m for r in results if r.min_clearance_m is not None]
    min_clear = min(clear) if clear else None
    shortfall = margin_m - min_clear if min_clear is not None else margin_m
    reasons = []
    if off:
        reasons.append(f"{off} off-track event(s)")
    if rec:
        reasons.append(f"{rec} recovery episode(s)")
    if spins:
        reasons.append(f"{spins} spin(s)")
    if below:
        reasons.append(f"{below} lap(s) below the minimum-time lap")
    if missing > 0:
        reasons.append(f"{missing} of {laps * len(results)} laps missing")
    if shortfall > 0 and min_clear is not None:
        reasons.append(f"closest approach {min_clear:.4f} m < margin {margin_m:g} m")
    reasons += [f"seed {r.seed}: {r.aborted}" for r in results if r.aborted]
    if not results:
        reasons.append("no seed ran")
        missing = laps * n_seeds
    elif reasons and len(results) < n_seeds:
        reasons.append(f"{n_seeds - len(results)} seed(s) skipped")
    mean = sum(times) / len(times) if times else None
    value = mean if (mean is not None and missing == 0) else PENALTY_S
    constraints = (float(off), float(rec), float(missing), float(shortfall), float(spins),
                   float(below))
    return Score(float(value), constraints, tuple(reasons), mean)


@dataclass(frozen=True)
class CellScore:
    """One cell of a family (a track and a car): its score and its limit.

    Attributes:
        track: the track's name.
        car: the car's name (``shared.config.cars.CARS``).
        score: the cell's own score (``score``; its value the mean lap [s]).
        limit_s: the simulated car's minimum-time lap on the track [s].
    """

    track: str
    car: str
    score: Score
    limit_s: float

    @property
    def ratio(self) -> float | None:
        """Mean lap / the minimum-time lap, or None without a complete set of laps."""
        sc = self.score
        if sc.mean_lap_s is None or sc.constraints[2] > 0:
            return None
        return sc.mean_lap_s / self.limit_s


def family_score(cells: Sequence[CellScore], n_cells: int, aggregate: str) -> Score:
    """One score over a family's cells (`n_cells` asked; the rest were skipped, the trial
    being infeasible already).

    The value is the `aggregate` (``AGGREGATES``: ``worst`` = max, or ``mean``) of the
    cells' ratios to their minimum-time laps [1], ``PENALTY_S`` when a cell has no complete
    set of laps or cells were skipped; the constraints add up over the cells (the margin
    shortfall is the largest); a reason names its cell. ``mean_lap_s`` carries the
    aggregated ratio too (None without every cell's)."""
    if aggregate not in AGGREGATES:
        raise ValueError(f"aggregate must be one of {', '.join(AGGREGATES)}, got {aggregate!r}")
    if not cells:
        return Score(PENALTY_S, (0.0, 0.0, 1.0, 0.0, 0.0, 0.0), ("no cell ran",), None)
    cons = [sum(c.score.constraints[k] for c in cells) for k in range(len(CONSTRAINTS))]
    cons[3] = max(c.score.constraints[3] for c in cells)
    reasons = [f"{c.track}/{c.car}: {r}" for c in cells for r in c.score.reasons]
    if reasons and len(cells) < n_cells:
        reasons.append(f"{n_cells - len(cells)} cell(s) skipped")
    ratios = [c.ratio for c in cells]
    agg = None
    if len(cells) == n_cells and all(r is not None for r in ratios):
        vals = [float(r) for r in ratios if r is not None]
        agg = max(vals) if aggregate == "worst" else sum(vals) / len(vals)
    value = agg if agg is not None else PENALTY_S
    return Score(float(value), tuple(float(c) for c in cons), tuple(reasons), agg)
