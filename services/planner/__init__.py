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
- the minimum-time lap (``MinTimeLap``, ``MinTimeSettings``, ``MinTimeError``): an
  artefact the tools make (``ensure_artefacts(method, track, settings, vehicle)`` before
  they build planners; ``make_min_time_lap``: read, or solved once and cached) and the
  planner only reads (``load_min_time_lap``; missing: ``MinTimeArtefactMissingError``,
  one line naming the ``racestack mintime`` command that makes it); which lap a use races
  on (``LapRequest``, ``limit_request``, ``line_request``, ``raceline_request``,
  ``request_for``, ``laps_of``, ``MIN_TIME_USES``), with the settings of the planner's pose
  source (``for_pose_source``: truth, ekf, lidar; ``for_stack``: the stack's
  ``[localization] pose_source``); and its tracker (``Tracker``, ...);
"""

from services.planner.interface import (
    BRAKING,
    FALLBACK,
    RECOVERING,
    SOLVED,
    DriveCommand,
    PlannerLike,
    SolveResult,
)
from services.planner.mintime.model import DELTA, servo_reach
from services.planner.mintime.ocp import CODE_VERSION as MIN_TIME_CODE_VERSION
from services.planner.mintime.ocp import MinTimeError, MinTimeLap, MinTimeSettings
from services.planner.mintime.requests import LIMIT as MIN_TIME_LIMIT
from services.planner.mintime.requests import USES as MIN_TIME_USES
from services.planner.mintime.requests import (
    LapRequest,
    for_pose_source,
    for_stack,
    laps_of,
    limit_request,
    line_request,
    raceline_request,
    request_for,
)
from services.planner.mintime.store import (
    MinTimeArtefactMissingError,
    ensure_artefacts,
    load_min_time_lap,
    make_min_time_lap,
    min_time_lap,
)
from services.planner.mpc.model import discretise, kinematic_bicycle, step_numpy
from services.planner.mpc.planner import Planner
from services.planner.opponents import OpponentEstimate
from services.planner.raceline.planner import RacelinePlanner
from services.planner.raceline.tracker import ReferenceLap, Tracker, TrackerGains, TrackerTiming
from services.planner.recovery import Recovery
from services.planner.registry import PlannerPool, make_planner

__all__ = [
    "BRAKING",
    "DELTA",
    "FALLBACK",
    "MIN_TIME_CODE_VERSION",
    "MIN_TIME_LIMIT",
    "MIN_TIME_USES",
    "RECOVERING",
    "SOLVED",
    "DriveCommand",
    "LapRequest",
    "MinTimeArtefactMissingError",
    "MinTimeError",
    "MinTimeLap",
    "MinTimeSettings",
    "OpponentEstimate",
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
    "ensure_artefacts",
    "for_pose_source",
    "for_stack",
    "kinematic_bicycle",
    "laps_of",
    "limit_request",
    "line_request",
    "load_min_time_lap",
    "make_min_time_lap",
    "make_planner",
    "min_time_lap",
    "raceline_request",
    "request_for",
    "servo_reach",
    "step_numpy",
]
