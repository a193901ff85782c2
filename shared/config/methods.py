"""The method registry: every planning method racestack knows, in one place.

``METHODS`` maps a method's name to its ``MethodSpec``: which planner runs it, which line it
contours or tracks, where its settings live in ``[planner]``, which solver settings and pose
lead it uses. Everything that lists or branches on methods derives from here: the
configuration's ``[planner] method`` validation, the plan record's method field, the planner's
construction (``services.planner.registry``), the bench's and the tuner's method lists and the
command line's choices.

Adding a method is one entry here plus its pieces: a weight set or settings section in
``shared/config/planner.py`` (when it has its own), and, for a new ``kind`` of planner, its
builder in ``services.planner.registry.BUILDERS``. A spec is plain data (no service imports),
so ``shared`` code may read it.

The names are the module's constants (``CIMPCC``, ``MPCC``, ...): code names a method by its
constant, never by its string (``tests/shared/test_method_registry.py`` checks the tree).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Literal

if TYPE_CHECKING:  # only for annotations: planner.py imports this module
    from shared.config.planner import MethodWeights, PlannerSettings, SolverSettings

#: The paper's curvature-integrated MPCC (Table I's CiMPCC column).
CIMPCC = "cimpcc"
#: The paper's MPCC baseline.
MPCC = "mpcc"
#: CiMPCC's cost contouring the car's minimum-time line, speeds from its profile.
CIMPCC_LINE = "cimpcc-line"
#: The raceline baseline: a line with a speed profile, tracked by a model-based tracker.
RACELINE = "raceline"
#: The bench's MPCC with its speed reference swept for the fastest clean laps.
MPCC_TUNED = "mpcc-tuned"
#: The bench's CiMPCC with the weights and curvature mapping of a tuned file.
CIMPCC_TUNED = "cimpcc-tuned"

#: How a planner is built: an MPC problem (``services.planner.mpc``) or a tracker along a
#: precomputed line (``services.planner.raceline``).
PlannerKind = Literal["mpc", "tracker"]
#: What a method follows: the track's centreline, the car's minimum-time line (with its
#: speed profile), or the raceline's own line (``[planner.raceline] line``).
ReferenceKind = Literal["centreline", "min_time_line", "planned_line"]
#: The MPC model: the paper's kinematic bicycle, with the car's steady-state tyre slip, or
#: with the slip and the car's speed as a state behind its speed loop.
ModelKind = Literal["kinematic", "kinematic_slip", "kinematic_slip_speed"]
#: How the bench races a variant of another method: its speed reference swept over a few
#: laps first, or the weights of a tuned configuration file.
BenchVariant = Literal["sweep", "tuned_file"]


@dataclass(frozen=True)
class MethodSpec:
    """One planning method.

    Attributes:
        name: the method's name (``[planner] method``, ``--methods``, the plan record).
        kind: the planner that runs it (``PlannerKind``).
        reference: the line it follows (``ReferenceKind``).
        section: the table of ``[planner]`` that holds its settings (``[planner.<section>]``),
            or None.
        weights: where its ``MethodWeights`` sit in ``[planner]``: a dotted attribute path
            (``"cimpcc"``, ``"cimpcc_line.weights"``), or None (no MPC cost).
        own_structure: its section sets its problem's structure (``horizon_steps``,
            ``integrator``, ``model``, ``lifted``, ``lead_pose_s``, ``v_max_mps``) and its
            solver tolerances (``<section>.solver``); False: ``[planner]``'s own (the paper's
            kinematic bicycle, no lead).
        base: a bench variant's underlying method (it races that method's planner), or None.
        bench_variant: how the bench races a variant (``BenchVariant``), or None.
        summary: one line for the command line's help and the docs.
        opponents: its planner plans around the other cars (``set_opponents``; the planner
            service then subscribes to ``opponents``, issue #24).
    """

    name: str
    kind: PlannerKind
    reference: ReferenceKind
    section: str | None
    weights: str | None
    own_structure: bool = False
    base: str | None = None
    bench_variant: BenchVariant | None = None
    summary: str = ""
    opponents: bool = False

    @property
    def in_planner(self) -> bool:
        """The planner service can run it (bench variants run only in the bench)."""
        return self.base is None


METHODS: dict[str, MethodSpec] = {
    CIMPCC: MethodSpec(
        CIMPCC, "mpc", "centreline", "cimpcc", "cimpcc",
        summary="the paper's CiMPCC: contours the centreline, speed pulls from its curvature",
    ),
    MPCC: MethodSpec(
        MPCC, "mpc", "centreline", "mpcc", "mpcc",
        summary="the paper's MPCC baseline: contours the centreline, a fixed speed reference",
    ),
    RACELINE: MethodSpec(
        RACELINE, "tracker", "planned_line", "raceline", None,
        summary="the raceline baseline: a line with a speed profile and a model tracker",
        opponents=True,
    ),
    CIMPCC_LINE: MethodSpec(
        CIMPCC_LINE, "mpc", "min_time_line", "cimpcc_line", "cimpcc_line.weights",
        own_structure=True,
        summary="CiMPCC's cost on the car's minimum-time line, speeds from its profile",
    ),
    MPCC_TUNED: MethodSpec(
        MPCC_TUNED, "mpc", "centreline", "mpcc", "mpcc", base=MPCC, bench_variant="sweep",
        summary="bench only: MPCC with its speed reference swept for the fastest clean laps",
    ),
    CIMPCC_TUNED: MethodSpec(
        CIMPCC_TUNED, "mpc", "centreline", "cimpcc", "cimpcc", base=CIMPCC,
        bench_variant="tuned_file",
        summary="bench only: CiMPCC with [planner.cimpcc] and [curvature] of a tuned file",
    ),
}


class UnknownMethodError(ValueError):
    """A method name the registry does not know (the message lists the known ones)."""


def planner_methods() -> tuple[str, ...]:
    """The methods the planner service runs (``[planner] method``), in registry order."""
    return tuple(name for name, spec in METHODS.items() if spec.in_planner)


def bench_methods() -> tuple[str, ...]:
    """The methods the bench races (every registered one), in registry order."""
    return tuple(METHODS)


def plans_with_opponents(name: str) -> bool:
    """Whether method `name` plans around the other cars (``MethodSpec.opponents``; a
    bench variant: its base method's); UnknownMethodError when it is not registered."""
    spec = method_spec(name)
    return METHODS[spec.base or spec.name].opponents


def method_spec(name: str, *, in_planner: bool = False) -> MethodSpec:
    """The spec of `name`; UnknownMethodError naming the choices when it is not registered
    (or, with `in_planner`, is a bench variant the planner cannot run)."""
    choices = planner_methods() if in_planner else bench_methods()
    if name not in choices:
        raise UnknownMethodError(f"unknown method {name!r}; choose from {', '.join(choices)}")
    return METHODS[name]


def _attr(obj: object, dotted: str) -> object:
    for part in dotted.split("."):
        obj = getattr(obj, part)
    return obj


@dataclass(frozen=True)
class MethodSetup:
    """A method's planner settings resolved from its spec and a ``[planner]`` section: what
    the planner is built from (``services.planner.registry``).

    Attributes:
        spec: the method.
        weights: its cost's weights (None: no MPC cost).
        structure: the planner settings that fix its problem's structure (``[planner]``
            with the method's own ``horizon_steps`` and ``integrator`` when it has them).
        solver: its solver settings (``[planner.solver]``, with its own tolerances laid
            over them when it has them).
        model: the MPC model (``ModelKind``).
        lead_s: plan from the pose predicted this far ahead with the acting command [s].
        lifted: the lifted problem layout (``services.planner.mpc.problem``).
        speed_cap_mps: bound on the planned speed of a model with the car's speed [m/s],
            or None.
        servo_state: a model with the car's speed holds a slow servo as a state too
            (``services.planner.mpc.planner.model_servo``).
    """

    spec: MethodSpec
    weights: MethodWeights | None
    structure: PlannerSettings
    solver: SolverSettings
    model: ModelKind
    lead_s: float
    lifted: bool
    speed_cap_mps: float | None
    servo_state: bool = False

    @property
    def has_speed_state(self) -> bool:
        """The model holds the car's speed behind its speed loop."""
        return self.model == "kinematic_slip_speed"


def method_setup(settings: PlannerSettings, name: str | None = None) -> MethodSetup:
    """Resolve method `name` (default ``settings.method``) against `settings`."""
    spec = method_spec(name or settings.method)
    weights = _attr(settings, spec.weights) if spec.weights else None
    if not spec.own_structure:
        return MethodSetup(spec, weights, settings, settings.solver, "kinematic", 0.0, False,
                           None)
    own = _attr(settings, spec.section or "")
    update: dict = {"horizon_steps": own.horizon_steps}
    if own.integrator is not None:
        update["integrator"] = own.integrator
    structure = settings.model_copy(update=update)
    solver = settings.solver.model_copy(update=own.solver.model_dump())
    with_speed = own.model == "kinematic_slip_speed"
    return MethodSetup(
        spec, weights, structure, solver, own.model, own.lead_pose_s, own.lifted,
        own.v_max_mps if with_speed else None,
        with_speed and getattr(own, "servo_state", False),
    )
