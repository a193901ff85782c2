"""Which planner a method gets: the builders of each kind of planner and a pool that shares
built MPC problems and solvers between the methods of one track and car.

The methods themselves, their names and specs, are the registry ``shared.config.methods``;
this module turns a spec into a planner. ``make_planner`` builds one; ``PlannerPool`` builds
many on one track (the bench, the tuner), reusing a problem (and its compiled solver) for
every method whose problem has the same structure: ``cimpcc`` and ``mpcc`` differ only in
their weights, which are parameters, so they share one.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from services.planner.interface import PlannerLike
from services.planner.mpc.planner import Planner, method_problem, method_reference
from services.planner.mpc.problem import OcpProblem
from services.planner.mpc.solver import SolverHandle, make_solver
from services.planner.raceline.planner import RacelinePlanner
from shared.config.methods import MethodSetup, PlannerKind, method_setup
from shared.config.planner import CurvatureSettings, MethodWeights, PlannerSettings
from shared.config.vehicle import DynamicVehicleParams
from shared.track import Track

#: The planner class of each kind (``MethodSpec.kind``); each is built as
#: ``cls(track, settings, curvature, method=..., vehicle=...)``.
BUILDERS: dict[PlannerKind, Callable[..., PlannerLike]] = {
    "mpc": Planner,
    "tracker": RacelinePlanner,
}


def make_planner(
    track: Track,
    settings: PlannerSettings,
    curvature: CurvatureSettings | None = None,
    vehicle: DynamicVehicleParams | None = None,
    *,
    method: str | None = None,
) -> PlannerLike:
    """The planner of `method` (default ``settings.method``) on `track`: ``step`` /
    ``prepare`` / ``reset`` (``PlannerLike``).

    Args:
        vehicle: the car the minimum-time line is solved for and the near-limit models
            know (default: the F1TENTH gym's, the simulator's default).
    """
    return PlannerPool(track, vehicle).planner(settings, method, curvature)


#: Fields of a line method's section that its problem does not read (parameters and the
#: planner's own Python: the weights, the solver's tolerances, the pose lead and the speed
#: estimate's gains), so planners of the same line for other pose sources share it.
LINE_FIELDS_OUTSIDE_PROBLEM = frozenset({
    "weights", "solver", "lead_pose_s",
    "speed_estimate_gain", "ekf_speed_estimate_gain", "lidar_speed_estimate_gain",
})


def _problem_key(setup: MethodSetup, vehicle: DynamicVehicleParams | None) -> tuple:
    """What fixes an MPC method's problem: its line, model, structure and layout (not its
    weights, which are parameters)."""
    s = setup.structure
    line: Any = None
    if setup.spec.reference == "min_time_line":
        line = (
            setup.spec.section,
            getattr(s, setup.spec.section or "").model_dump_json(
                exclude=LINE_FIELDS_OUTSIDE_PROBLEM
            ),
        )
    car = None
    if setup.model != "kinematic" or line is not None:
        car = None if vehicle is None else vehicle.model_dump_json()
    return (
        setup.spec.reference,
        line,
        car,
        setup.model,
        setup.lifted,
        setup.speed_cap_mps,
        s.horizon_steps,
        s.dt_s,
        s.integrator,
        s.wheelbase_m,
        s.track_margin_m,
        s.bounds.model_dump_json(),
    )


class PlannerPool:
    """Planners of many methods (or settings) on one track and car, sharing what is built.

    MPC problems are shared by structural key (``_problem_key``: line, model, N, Ts,
    integrator, L, margin, bounds) and their solvers by that key and the solver settings;
    each planner has its own weights, curvature profile and warm start.

    Args:
        track: the track every planner races.
        vehicle: the car (see ``make_planner``).
    """

    def __init__(self, track: Track, vehicle: DynamicVehicleParams | None = None) -> None:
        self.track = track
        self.vehicle = vehicle
        self._problems: dict[tuple, OcpProblem] = {}
        self._solvers: dict[tuple, SolverHandle] = {}

    def planner(
        self,
        settings: PlannerSettings,
        method: str | None = None,
        curvature: CurvatureSettings | None = None,
        *,
        weights: MethodWeights | None = None,
    ) -> PlannerLike:
        """A fresh planner of `method` (default ``settings.method``; a bench variant races
        its base method) with `settings`, `curvature` and optionally explicit `weights`."""
        setup = method_setup(settings, method)
        spec = setup.spec
        name = spec.base or spec.name
        if spec.kind != "mpc":
            return BUILDERS[spec.kind](
                self.track, settings, curvature, method=name, vehicle=self.vehicle
            )
        setup = method_setup(settings, name)
        problem, solver = self.problem_and_solver(setup)
        return BUILDERS["mpc"](
            self.track, settings, curvature, method=name, weights=weights,
            problem=problem, solver=solver, vehicle=self.vehicle,
        )

    def problem_and_solver(self, setup: MethodSetup) -> tuple[OcpProblem, SolverHandle]:
        """The shared problem and solver of an MPC method (built on first use)."""
        key = _problem_key(setup, self.vehicle)
        problem = self._problems.get(key)
        if problem is None:
            reference = method_reference(self.track, setup, self.vehicle)
            problem = self._problems[key] = method_problem(reference, setup, self.vehicle)
        solver_key = (key, setup.solver.model_dump_json())
        solver = self._solvers.get(solver_key)
        if solver is None:
            solver = self._solvers[solver_key] = make_solver(problem, setup.solver)
        return problem, solver

    @property
    def built(self) -> tuple[int, int]:
        """(problems, solvers) built so far."""
        return len(self._problems), len(self._solvers)
