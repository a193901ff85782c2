"""Which planner a configuration asks for: the MPC methods or the raceline baseline."""

from __future__ import annotations

from services.planner.planner import Planner
from services.planner.raceline import RacelinePlanner
from shared.config.planner import CurvatureSettings, PlannerSettings
from shared.track import Track


def make_planner(
    track: Track, settings: PlannerSettings, curvature: CurvatureSettings | None = None
) -> Planner | RacelinePlanner:
    """``settings.method``: "cimpcc" or "mpcc" (one MPC problem) or "raceline" (the
    minimum-curvature line tracked by pure pursuit); both have ``step``/``prepare``/``reset``."""
    if settings.method == "raceline":
        return RacelinePlanner(track, settings, curvature)
    return Planner(track, settings, curvature)
