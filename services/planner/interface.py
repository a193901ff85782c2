"""What every planner offers its callers: the planner service, the bench, the tuner, the CLI.

``Planner`` (the MPC methods, ``services.planner.mpc.planner``) and ``RacelinePlanner`` (the
raceline baseline, ``services.planner.raceline.planner``) both implement ``PlannerLike``; callers
type against it instead of spelling out the union (``make_planner`` returns one).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Protocol, runtime_checkable

import numpy as np

from services.planner.recovery import Recovery
from shared.config.planner import PlannerSettings
from shared.curvature import CurvatureProfile
from shared.messages.vocab import PlanStatusName
from shared.track import Track

#: Status of a result: a fresh solution, the shifted previous plan, or a braking command;
#: RECOVERING: the car is lost (spun or far off the track), the recovery rule drives.
SOLVED, FALLBACK, BRAKING, RECOVERING = (
    PlanStatusName.SOLVED,
    PlanStatusName.FALLBACK,
    PlanStatusName.BRAKING,
    PlanStatusName.RECOVERING,
)


@dataclass(frozen=True)
class DriveCommand:
    """What the planner commands: speed [m/s] and steering angle [rad]."""

    speed_mps: float
    steering_rad: float


@dataclass(frozen=True)
class SolveResult:
    """The record of one planner tick.

    Attributes:
        command: the drive command to apply now.
        states: (N+1, 4) predicted model states [X, Y, phi, s] (s: progress along the
            planner's reference path, the centreline or the line; may exceed its length).
        inputs: (N, 3) planned inputs [v_l, delta, v_p].
        status: SOLVED, FALLBACK or BRAKING.
        solver_status: the back-end's return status text.
        iterations: solver iterations.
        solve_time_s: wall time of the solver call [s].
        beta: (N,) beta used at each stage.
        s_m: the car's progress [m] along the track's centreline in [0, lap length).
        e_con_m: the car's contour error [m] (positive right of the centreline).
        consecutive_failures: failed solves in a row, this one included.
        method: "cimpcc", "mpcc" or "cimpcc-line".
        speed_limited: the car was outside the track, so the speed command was capped at
            ``off_track_speed_mps`` (a safety rule outside the optimisation).
    """

    command: DriveCommand
    states: np.ndarray
    inputs: np.ndarray
    status: str
    solver_status: str
    iterations: int
    solve_time_s: float
    beta: np.ndarray
    s_m: float
    e_con_m: float
    consecutive_failures: int
    method: str
    speed_limited: bool = False


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
