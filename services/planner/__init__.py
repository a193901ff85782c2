"""The planner core: the MPC methods (CiMPCC, MPCC, CiMPCC on the minimum-time line), the
raceline baseline, the minimum-time lap; ``service.py`` is the shell (``python -m
services.planner``). What tools may use (``docs/architecture.md``, rule 3) is ``__all__``:

- ``make_planner(track, settings, curvature, vehicle, method=)`` -> a ``PlannerLike``
  (``Planner`` or ``RacelinePlanner``, by the method's spec in ``shared.config.methods``):
  ``step(x, y, yaw, on_command) -> SolveResult``, ``prepare``, ``reset``, ``settings``,
  ``recovery``, ``track``, ``profile``, ``horizon``; ``PlannerPool`` builds many on one
  track, sharing MPC problems and solvers;
- the kinematic model the MPC plans with: ``kinematic_bicycle``, ``discretise``,
  ``step_numpy``;
- the minimum-time lap (``MinTimeLap``, ``MinTimeSettings``, ``MinTimeError``,
  ``min_time_lap``: solved once, then cached) and its tracker (``Tracker``, ...);
"""

from services.planner.interface import PlannerLike
from services.planner.mintime.model import DELTA
from services.planner.mintime.ocp import MinTimeError, MinTimeLap, MinTimeSettings
from services.planner.mintime.store import min_time_lap
from services.planner.mpc.model import discretise, kinematic_bicycle, step_numpy
from services.planner.mpc.planner import (
    BRAKING,
    FALLBACK,
    RECOVERING,
    SOLVED,
    DriveCommand,
    Planner,
    SolveResult,
)
from services.planner.raceline.planner import RacelinePlanner
from services.planner.raceline.tracker import ReferenceLap, Tracker, TrackerGains, TrackerTiming
from services.planner.recovery import Recovery
from services.planner.registry import PlannerPool, make_planner

__all__ = [
    "BRAKING",
    "DELTA",
    "FALLBACK",
    "RECOVERING",
    "SOLVED",
    "DriveCommand",
    "MinTimeError",
    "MinTimeLap",
    "MinTimeSettings",
    "Planner",
    "PlannerLike",
    "PlannerPool",
    "RacelinePlanner",
    "Recovery",
    "ReferenceLap",
    "SolveResult",
    "Tracker",
    "TrackerGains",
    "TrackerTiming",
    "discretise",
    "kinematic_bicycle",
    "make_planner",
    "min_time_lap",
    "step_numpy",
]
