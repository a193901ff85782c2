"""Which planner a configuration asks for: the MPC methods or the raceline baseline."""

from __future__ import annotations

from services.planner.interface import PlannerLike
from services.planner.mpc.planner import Planner
from services.planner.raceline.planner import RacelinePlanner
from shared.config.planner import CurvatureSettings, PlannerSettings
from shared.config.vehicle import DynamicVehicleParams
from shared.track import Track


def make_planner(
    track: Track,
    settings: PlannerSettings,
    curvature: CurvatureSettings | None = None,
    vehicle: DynamicVehicleParams | None = None,
) -> PlannerLike:
    """``settings.method``: "cimpcc" or "mpcc" (one MPC problem on the centreline),
    "cimpcc-line" (the same problem builder on the minimum-time line of `vehicle`) or
    "raceline" (the baseline: a line tracked by a pursuit controller); all have
    ``step``/``prepare``/``reset``.

    Args:
        vehicle: the simulated (or real) car the minimum-time lap is solved for
            (``cimpcc-line``, ``raceline``); None: the F1TENTH gym's, the simulator's default.
    """
    if settings.method == "raceline":
        return RacelinePlanner(track, settings, curvature, vehicle=vehicle)
    return Planner(track, settings, curvature, vehicle=vehicle)
