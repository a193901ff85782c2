"""The one closed loop: a planner racing a plant for N laps, in one process (no Zenoh).

``race(planner, plant, laps)`` ticks ``planner.step`` on the pose ``plant.pose()`` and hands
each result to ``plant.advance(result, period_s)`` (``period_s`` = ``planner.settings.dt_s``)
until the plant has completed ``laps`` laps, the plant gives up (``stop_reason``) or
``max_ticks`` ran. The plant owns the car, its timing (delays, lap timer) and what it records;
the loop owns the planner's side (solve times, statuses, contour error). Plants:

- ``ModelPlant``: the planner's own kinematic model (or any ``(x, u) -> x`` CasADi step),
  one model step per tick, the command acting at once; laps counted from the planner's
  progress ``s_m`` (``racestack laps``, ``benchmarks/solve_time.py``, the planner's tests);
- ``services.tools.bench.closed_loop.SimulatorPlant``: the dynamic ``Simulator`` with the bench's
  compute delay, the simulator's actuation delays and the ``LapTimer`` (``racestack bench``,
  ``racestack tune``).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, Protocol

import numpy as np

from services.planner import (
    RECOVERING,
    SOLVED,
    PlannerLike,
    SolveResult,
    discretise,
    kinematic_bicycle,
    step_numpy,
)
from shared.config.planner import PlannerSettings
from shared.track import Track


class Plant(Protocol):
    """What the planner races against: gives a pose, takes each tick's result."""

    @property
    def laps_completed(self) -> int:
        """Laps completed (timed) so far."""
        ...

    @property
    def stop_reason(self) -> str:
        """Why the plant gave up ("" while it runs)."""
        ...

    def pose(self) -> tuple[float, float, float]:
        """The pose the planner sees now: rear axle x, y [m], yaw [rad]."""
        ...

    def advance(self, result: SolveResult, period_s: float) -> None:
        """Drive one planner period with `result`'s command (and record what it records)."""
        ...


@dataclass
class RaceResult:
    """The planner's side of a race.

    Attributes:
        ticks: planner steps run.
        laps: laps the plant completed.
        stop_reason: "" (the laps were driven), "max ticks", or the plant's reason.
        solve_times_s: each tick's solve time [s].
        solved: ticks with status SOLVED.
        failures: ticks neither SOLVED nor RECOVERING.
        max_abs_e_con_m: the largest |contour error| the planner saw [m].
        last: the last tick's result (None: no tick).
    """

    ticks: int = 0
    laps: int = 0
    stop_reason: str = ""
    solve_times_s: list[float] = field(default_factory=list)
    solved: int = 0
    failures: int = 0
    max_abs_e_con_m: float = 0.0
    last: SolveResult | None = None


def race(
    planner: PlannerLike,
    plant: Plant,
    laps: int | None,
    *,
    max_ticks: int | None = None,
    on_tick: Callable[[SolveResult], None] | None = None,
    reset: bool = True,
) -> RaceResult:
    """Race `planner` against `plant` for `laps` laps (None: until `max_ticks`).

    Args:
        max_ticks: stop after this many ticks (None: no limit; the plant must stop itself).
        on_tick: called with every result, before the plant advances (exceptions
            propagate, e.g. a test's assertion).
        reset: reset the planner first (a cold start).
    """
    if laps is None and max_ticks is None:
        raise ValueError("race: give laps or max_ticks")
    if reset:
        planner.reset()
    period_s = planner.settings.dt_s
    out = RaceResult()
    while laps is None or plant.laps_completed < laps:
        if max_ticks is not None and out.ticks >= max_ticks:
            out.stop_reason = "max ticks"
            break
        res = planner.step(*plant.pose())
        out.ticks += 1
        out.solve_times_s.append(res.solve_time_s)
        out.solved += res.status == SOLVED
        out.failures += res.status not in (SOLVED, RECOVERING)
        out.max_abs_e_con_m = max(out.max_abs_e_con_m, abs(res.e_con_m))
        out.last = res
        if on_tick is not None:
            on_tick(res)
        plant.advance(res, period_s)
        if plant.stop_reason:
            out.stop_reason = plant.stop_reason
            break
    out.laps = plant.laps_completed
    return out


class ModelPlant:
    """A model car: state ``[x, y, yaw, ...]`` (rear axle), one model step per tick.

    The command acts at once (no delays). Laps are counted from the planner's progress
    ``result.s_m`` (the projection of the pose it was given): a lap ends at the tick whose
    pose is past the start line again, its time is that pose's time since the last one.

    Attributes:
        x: the model's state.
        t_s: the time of the current pose [s].
        progress_m: the planner's progress since the start, unwrapped [m].
        lap_times_s: the completed laps' times [s].
    """

    def __init__(
        self,
        track: Track,
        step: Any,
        x0: np.ndarray | None = None,
        on_lap: Callable[[int, float], None] | None = None,
    ) -> None:
        """`step`: a CasADi ``(x, u) -> x`` over one planner period (``u`` = speed,
        steering, progress speed); `x0` None: standstill on the start line, along it;
        `on_lap(n, lap_time_s)` is called at each completed lap."""
        self.track = track
        self.F = step
        if x0 is None:
            x0 = np.array([*track.xy[0], track.heading_rad[0], 0.0])
        self.x = np.asarray(x0, dtype=float)
        self.t_s = 0.0
        self.progress_m = 0.0
        self.lap_times_s: list[float] = []
        self.on_lap = on_lap
        self._s_last = 0.0
        self._lap_start_s = 0.0

    @classmethod
    def kinematic(
        cls,
        track: Track,
        settings: PlannerSettings,
        x0: np.ndarray | None = None,
        on_lap: Callable[[int, float], None] | None = None,
    ) -> ModelPlant:
        """The planner's kinematic bicycle (``settings.wheelbase_m``, ``dt_s``,
        ``integrator``)."""
        f = kinematic_bicycle(settings.wheelbase_m)
        return cls(track, discretise(f, settings.dt_s, settings.integrator), x0, on_lap)

    @property
    def laps_completed(self) -> int:
        """Laps completed."""
        return len(self.lap_times_s)

    @property
    def stop_reason(self) -> str:
        """A model car never gives up."""
        return ""

    def pose(self) -> tuple[float, float, float]:
        """The model's x, y, yaw."""
        return float(self.x[0]), float(self.x[1]), float(self.x[2])

    def advance(self, result: SolveResult, period_s: float) -> None:
        """Count the progress of `result`, then step the model with its command."""
        L = self.track.length_m
        self.progress_m += (result.s_m - self._s_last + L / 2) % L - L / 2
        self._s_last = result.s_m
        if self.progress_m >= (self.laps_completed + 1) * L:
            self.lap_times_s.append(self.t_s - self._lap_start_s)
            self._lap_start_s = self.t_s
            if self.on_lap is not None:
                self.on_lap(self.laps_completed, self.lap_times_s[-1])
        u = np.array([result.command.speed_mps, result.command.steering_rad, 0.0])
        self.x = step_numpy(self.F, self.x, u)
        self.t_s += period_s
