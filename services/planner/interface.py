"""What every planner offers its callers: the planner service, the bench, the tuner, the CLI.

``Planner`` (the MPC methods, ``services.planner.mpc.planner``) and ``RacelinePlanner`` (the
raceline baseline, ``services.planner.raceline.planner``) both implement ``PlannerLike``; callers
type against it instead of spelling out the union (``make_planner`` returns one).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Protocol, runtime_checkable

from services.planner.mpc.planner import DriveCommand, SolveResult
from services.planner.recovery import Recovery
from shared.config.planner import PlannerSettings
from shared.curvature import CurvatureProfile
from shared.track import Track


@runtime_checkable
class PlannerLike(Protocol):
    """A planner: one ``step`` per tick from the car's rear-axle pose to a command.

    Attributes (read-only for callers):
        settings: the planner section it was built with (``dt_s`` is its tick period).
        recovery: the recovery rule (``episodes`` counts its take-overs).
        track: the track it plans on.
        profile: the track's curvature profile (beta along s).
        horizon: the number of planned stages N.
    """

    @property
    def settings(self) -> PlannerSettings: ...

    @property
    def recovery(self) -> Recovery: ...

    @property
    def track(self) -> Track: ...

    @property
    def profile(self) -> CurvatureProfile: ...

    @property
    def horizon(self) -> int: ...

    def step(
        self,
        x_m: float,
        y_m: float,
        yaw_rad: float,
        on_command: Callable[[DriveCommand], None] | None = None,
    ) -> SolveResult:
        """Plan from the pose (rear axle [m], yaw [rad]); `on_command` gets the command
        as soon as it is known."""
        ...

    def prepare(self) -> None:
        """Do the next tick's work that needs no new pose (idempotent)."""
        ...

    def reset(self) -> None:
        """Forget the past: the next step is a cold start."""
        ...
