"""The bench's ``cimpcc-tuned`` column: CiMPCC with the weights and curvature mapping of a
tuned configuration (``racestack tune``'s ``best.toml``), raced beside the paper's.

``racestack bench --methods cimpcc,cimpcc-tuned --tuned DIR/best.toml`` takes
``[planner.cimpcc]`` and ``[curvature]`` from the tuned file; everything else (the car, the
planner's horizon and bounds, the track) stays the bench's own configuration, so the two
columns differ only in what was tuned. Without ``--tuned`` the column races the bench
configuration's own ``[planner.cimpcc]`` and ``[curvature]`` (the paper's values unless
``--config`` sets them), and says so on stderr and in results.json.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

from services.planner import PlannerLike, PlannerPool
from shared.config import RacestackConfig, load_config
from shared.config.methods import CIMPCC_TUNED
from shared.config.planner import CurvatureSettings, MethodWeights

NAME = CIMPCC_TUNED


@dataclass(frozen=True)
class TunedCimpcc:
    """What the column races.

    Attributes:
        weights: CiMPCC's weights.
        curvature: the curvature mapping (alpha, window).
        source: the tuned file, or None (the bench configuration's own values).
        track_source: the tuned file's ``[track] source`` (where it was tuned), or None.
    """

    weights: MethodWeights
    curvature: CurvatureSettings
    source: str | None
    track_source: str | None = None

    def describe(self) -> str:
        """One line on what the column races."""
        if self.source is None:
            return (
                f"{NAME}: no --tuned file given: racing the bench configuration's own "
                "[planner.cimpcc] and [curvature] (the paper's values unless --config sets them)"
            )
        return f"{NAME}: [planner.cimpcc] and [curvature] from {self.source}"

    def extra(self) -> dict[str, Any]:
        """The column's record in results.json."""
        return {
            "tuned_file": self.source,
            "tuned_track_source": self.track_source,
            "v_up_mps": list(self.weights.v_up_mps),
            "v_low_mps": list(self.weights.v_low_mps),
            "r3_velocity": list(self.weights.r3_velocity),
            "gamma": self.weights.gamma,
            "alpha": self.curvature.alpha,
            "window_m": self.curvature.window_m,
        }


def load_tuned(path: str | Path | None, cfg: RacestackConfig) -> TunedCimpcc:
    """The tuned values from `path` (validated like any configuration; ConfigError), or the
    bench configuration's own when `path` is None."""
    if path is None:
        return TunedCimpcc(cfg.planner.cimpcc, cfg.curvature, None)
    tuned = load_config(path)
    return TunedCimpcc(tuned.planner.cimpcc, tuned.curvature, str(path), tuned.track.source)


def tuned_planner(
    pool: PlannerPool, cfg: RacestackConfig, tuned: TunedCimpcc, name: str = CIMPCC_TUNED
) -> PlannerLike:
    """The column's planner: its base method (CiMPCC) with the tuned weights and curvature,
    on the pool's shared problem and solver."""
    return pool.planner(cfg.planner, name, tuned.curvature, weights=tuned.weights)
