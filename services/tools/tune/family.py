"""A trial of ``racestack tune`` over a family: every track with every car (``--tracks``,
``--cars``), each cell (track, car) raced by its own ``Evaluator``.

A cell's configuration is the base configuration with the car's tables laid over it
(``shared.evaluation.car_family.CARS``: ``[vehicle]`` and, for a mismatch, ``[simulator.vehicle]``),
then the trial's overlay. Each cell is judged against its simulated car's minimum-time lap on
its track at the study's top speed (``limit_lap_s``, solved once and cached): a lap below it
counts like an off-track event. The trial is feasible only when every cell is; the cells run
in order and stop at the first infeasible one (the rest are skipped, as seeds are).

The objective: with one cell, its mean lap [s] (the single-track tuning as it was); with
several, the worst (``--aggregate worst``, the default) or the mean ratio of a cell's mean lap
to its minimum-time lap (``search.family_score``).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

from services.planner import MIN_TIME_LIMIT, limit_request, make_min_time_lap
from services.tools.tune.evaluate import Evaluator, ObjectiveSettings, TrialOutcome
from services.tools.tune.search import (
    CellScore,
    Params,
    SearchSpace,
    deep_merge,
    family_score,
)
from shared.config import RacestackConfig, config_from_dict
from shared.evaluation.car_family import car_spec
from shared.track import Track


@dataclass(frozen=True)
class FamilyCell:
    """One cell of the family: a track (its spec and the loaded track) and a car of ``CARS``."""

    spec: str
    track: Track
    car: str

    @property
    def label(self) -> str:
        """``TRACK/CAR``."""
        return f"{self.track.name}/{self.car}"


def cell_data(base_data: dict[str, Any], car: str) -> dict[str, Any]:
    """The base configuration (TOML tables) with car `car`'s tables laid over it."""
    return deep_merge(base_data, car_spec(car).tables)


def cell_config(base_data: dict[str, Any], car: str) -> RacestackConfig:
    """The validated configuration of a cell (before any trial's overlay)."""
    return config_from_dict(cell_data(base_data, car), f"car {car}")


def limit_lap_s(
    track: Track, cfg: RacestackConfig, v_max_mps: float,
    progress: Callable[[str], None] | None = None,
) -> tuple[float, bool]:
    """(The simulated car's minimum-time lap on `track` at top speed `v_max_mps` [s], read
    from the cache), the bench's limit (``limit_request``) with that cap; solved and cached
    when missing. Raises ``MinTimeError`` when the track allows none."""
    car, settings = limit_request(cfg.planner, cfg.simulator.vehicle)
    settings = dataclasses.replace(settings, v_max_mps=float(v_max_mps))
    lap = make_min_time_lap(track, car, settings, use=MIN_TIME_LIMIT, progress=progress)
    return float(lap.lap_time_s), bool(lap.cache_hit)


class FamilyEvaluator:
    """Races points over every cell: ``evaluator(params) -> TrialOutcome``.

    Args:
        space: the method's search space.
        cells: the family's cells, in the order they race.
        base_data: the base configuration as TOML tables (``--config``, or {}).
        settings: how each cell is raced and judged (laps, seeds, margin, noise).
        limits_s: each cell's minimum-time lap [s] (``limit_lap_s``), as `cells`.
        aggregate: ``worst`` or ``mean`` (``search.AGGREGATES``; used with several cells).
    """

    def __init__(
        self,
        space: SearchSpace,
        cells: Sequence[FamilyCell],
        base_data: dict[str, Any],
        settings: ObjectiveSettings,
        limits_s: Sequence[float],
        aggregate: str = "worst",
    ) -> None:
        if len(cells) != len(limits_s) or not cells:
            raise ValueError("one limit per cell, at least one cell")
        self.space = space
        self.cells = tuple(cells)
        self.limits_s = tuple(float(x) for x in limits_s)
        self.aggregate = aggregate
        self.settings = settings
        self.evaluators = [
            Evaluator(space, c.track, cell_data(base_data, c.car), settings, lim)
            for c, lim in zip(self.cells, self.limits_s, strict=True)
        ]

    def __call__(self, params: Params) -> TrialOutcome:
        """Race `params` in every cell (stopping at the first infeasible one) and score."""
        outcomes: list[TrialOutcome] = []
        scored: list[CellScore] = []
        for cell, limit, ev in zip(self.cells, self.limits_s, self.evaluators, strict=True):
            out = ev(params)
            outcomes.append(out)
            scored.append(CellScore(cell.track.name, cell.car, out.score, limit))
            if not out.score.feasible:
                break
        if len(self.cells) == 1:
            sc = outcomes[0].score
        else:
            sc = family_score(scored, len(self.cells), self.aggregate)
        records = tuple(
            cell_record(c, s, o) for c, s, o in zip(self.cells, scored, outcomes, strict=False)
        )
        seeds = tuple(r for o in outcomes for r in o.seeds)
        details = {
            "cells_run": len(outcomes),
            "cells_skipped": len(self.cells) - len(outcomes),
            "seeds_run": sum(o.details.get("seeds_run", 0) for o in outcomes),
            "seeds_skipped": sum(o.details.get("seeds_skipped", 0) for o in outcomes),
        }
        return TrialOutcome(sc, seeds, outcomes[0].overlay, details, records)


def cell_record(cell: FamilyCell, scored: CellScore, out: TrialOutcome) -> dict[str, Any]:
    """One cell's figures of a trial (the trial's user attribute ``cells``, the outputs)."""
    sc = scored.score
    seeds = [r.to_json() for r in out.seeds]
    ratio = scored.ratio
    return {
        "track": cell.track.name,
        "track_spec": cell.spec,
        "car": cell.car,
        "limit_s": scored.limit_s,
        "mean_lap_s": sc.mean_lap_s,
        "ratio": None if ratio is None else round(ratio, 6),
        "feasible": sc.feasible,
        "reasons": list(sc.reasons),
        "laps": sum(len(r["lap_times_s"]) for r in seeds),
        "off_track_events": sum(r["off_track_events"] for r in seeds),
        "recoveries": sum(r["recoveries"] for r in seeds),
        "spins": sum(r["spins"] for r in seeds),
        "below_limit_laps": sum(r["below_limit_laps"] for r in seeds),
        "min_clearance_m": min(
            (r["min_clearance_m"] for r in seeds if r["min_clearance_m"] is not None),
            default=None,
        ),
        "seeds": seeds,
    }
