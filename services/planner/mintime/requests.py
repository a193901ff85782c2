"""Which minimum-time lap each use races on: the car and the settings, built in one place.

A minimum-time lap (``services.planner.mintime.ocp``) is fixed by the track, the car it is
solved for and its ``MinTimeSettings``; the store keys its artefact on exactly these
(``services.planner.mintime.store.cache_key``). These uses race on one (``USES``):

- ``limit``: the car's limit, the bench's reference and ``racestack mintime``'s default
  (``limit_request``): the car as configured, top speed ``[planner.cimpcc] v_up_mps[0]``,
  the default grid and footprint margin;
- ``cimpcc-line``: the line CiMPCC contours (``line_request``): the car's friction ``mu``
  times ``[planner.cimpcc_line] grip_fraction``, its steering within the planner's
  ``[planner.bounds] delta_rad`` (a line the planner cannot steer is no reference), top
  speed ``v_max_mps``, margin ``line_margin_m`` and, with Pacejka tyres, the reserves
  ``slip_fraction`` and ``ellipse_fraction`` (an oversteering car's rear, ``oversteers``,
  ``[planner.raceline] min_time_oversteer_rear_share`` of that ellipse);
- ``raceline``: the raceline baseline's line with ``[planner.raceline] line = "min_time"``
  (``raceline_request``): the car's steering within ``min_time_steering_fraction`` of its
  ``steering_range`` (the car's own lock, or the planner's bounds; 1: all of it), top speed
  ``v_max_mps``, grid ``ds_m``, margin ``min_time_margin_m`` and the Pacejka reserves
  ``min_time_slip_fraction`` and ``min_time_ellipse_fraction`` of ``[planner.raceline]``
  (an oversteering car's rear a share of its own: ``rear_ellipse_fraction``)
  and its high-speed reserve (``min_time_reserve_speed_mps``, ``_fraction``, ``_width_mps``);
  the margin widened for a slow servo (``servo_margin_m``) and, through
  ``for_pose_source``, for the pose source (``truth_margin_m``, ``ekf_margin_m``,
  ``lidar_margin_m``);
- ``raceline-out-lap``: the raceline's out lap on a line of its own (``has_out_lap_line``):
  a car with a slow servo, a cautious start and ``flying_servo_margin_m`` (the flying laps'
  line takes ``flying_servo_margin_m`` as the servo's tube, this one ``servo_margin_m``);
  or a car that races its out lap at full speed (``full_speed_out_lap``: no cautious start,
  or the gym's unbounded ``linear`` tyres) with ``out_lap_margin_m`` (this line that much
  wider a tube).

``laps_of(method, settings)`` says which of them a planner method needs. Pure functions:
no I/O, no solve.
"""

from __future__ import annotations

from typing import NamedTuple

from services.planner.mintime.model import servo_reach
from services.planner.mintime.ocp import MinTimeSettings
from shared.config.methods import METHODS, method_spec
from shared.config.planner import PlannerSettings, RacelineSettings
from shared.config.vehicle import F1TENTH_GYM, DynamicVehicleParams
from shared.vehicle.tyres import axle_peak_friction

#: The car's limit (the bench's reference, ``racestack mintime``'s default).
LIMIT = "limit"
#: The suffix of the out lap's line of a method that races its own minimum-time line
#: (``raceline-out-lap``: ``[planner.raceline] flying_servo_margin_m``, ``has_out_lap_line``).
OUT_LAP = "-out-lap"
#: Every use of a minimum-time lap (``racestack mintime --for``): the limit, each planner
#: method of the registry that races on a line of its own (named by the method) and the out
#: lap's line of each that tracks a planned line.
USES = (
    LIMIT,
    *(n for n, s in METHODS.items() if s.in_planner and s.reference != "centreline"),
    *(n + OUT_LAP for n, s in METHODS.items()
      if s.in_planner and s.reference == "planned_line"),
)


class LapRequest(NamedTuple):
    """One minimum-time lap to solve or load: the car it is solved for and its settings
    (unpacks as ``car, settings``)."""

    car: DynamicVehicleParams
    settings: MinTimeSettings


def planning_vehicle(
    vehicle: DynamicVehicleParams, steering_limits_rad: tuple[float, float] | None
) -> DynamicVehicleParams:
    """`vehicle` with its steering range cut to `steering_limits_rad` [rad] (the planner's
    bounds): the line is planned with the steering the tracker may command. Returns
    `vehicle` itself when nothing is cut (or the limits are None).

    Raises:
        ValueError: the limits leave no steering range around 0.
    """
    if steering_limits_rad is None:
        return vehicle
    lo = max(vehicle.steering_min_rad, steering_limits_rad[0])
    hi = min(vehicle.steering_max_rad, steering_limits_rad[1])
    if not lo < 0.0 < hi:
        raise ValueError(f"steering limits {steering_limits_rad} leave no range around 0")
    if (lo, hi) == (vehicle.steering_min_rad, vehicle.steering_max_rad):
        return vehicle
    return DynamicVehicleParams.model_validate(
        {**vehicle.model_dump(), "steering_min_rad": lo, "steering_max_rad": hi}
    )


def full_speed_out_lap(settings: RacelineSettings, car: DynamicVehicleParams | None = None
                       ) -> bool:
    """Whether `car` (None: the gym's) races its out lap at its line's speeds: no cautious
    start (``start_speed_scale`` 1), or the gym's unbounded ``linear`` tyres, whose line
    drifts through bends tighter than the lock turns the car and so is not driven slower
    (``RacelinePlanner.drivable_slower``)."""
    return settings.start_speed_scale >= 1.0 or (car or F1TENTH_GYM).tyre_model == "linear"


def _servo_out_lap(settings: RacelineSettings, car: DynamicVehicleParams | None) -> bool:
    """A slow servo's cautious out lap on the servo's whole tube (``has_out_lap_line``)."""
    return (settings.flying_servo_margin_m is not None
            and settings.flying_servo_margin_m != settings.servo_margin_m
            and settings.start_speed_scale < 1.0
            and servo_reach(car or F1TENTH_GYM) is not None)


def has_out_lap_line(settings: RacelineSettings, car: DynamicVehicleParams | None = None
                     ) -> bool:
    """Whether the raceline races its out lap on a line of its own (``OUT_LAP``): either
    `car` (None: the gym's) has a slow servo (``mintime.model.servo_reach``), the run starts
    cautiously (``start_speed_scale`` < 1) and ``flying_servo_margin_m`` gives the flying
    laps' line another servo tube than ``servo_margin_m``; or the car races its out lap at
    full speed (``full_speed_out_lap``) and ``out_lap_margin_m`` widens that lap's tube."""
    return _servo_out_lap(settings, car) or (
        settings.out_lap_margin_m > 0.0 and full_speed_out_lap(settings, car))


def min_time_settings(
    settings: RacelineSettings, car: DynamicVehicleParams | None = None,
    *, out_lap: bool = False,
) -> MinTimeSettings:
    """The raceline's minimum-time problem: top speed [m/s], grid [m], footprint margin [m]
    of `settings` (``[planner.raceline]``) for `car` (None: the gym's). The margin is
    ``min_time_margin_m``, plus ``servo_margin_m`` for a car with a slow servo
    (``mintime.model.servo_reach``: its tracker inverts the lag and still runs 2-3 cm
    outside the line where a bend begins), plus the pose source's tube when the settings
    come through ``for_pose_source``. With an out lap's line of its own
    (``has_out_lap_line``) the servo's tube is ``flying_servo_margin_m`` but for that line
    (`out_lap`), and a full-speed out lap's line (``full_speed_out_lap``) takes
    ``out_lap_margin_m`` more."""
    margin = settings.min_time_margin_m
    if servo_reach(car or F1TENTH_GYM) is not None:
        flying = settings.flying_servo_margin_m
        if _servo_out_lap(settings, car) and not out_lap and flying is not None:
            margin += flying
        else:
            margin += settings.servo_margin_m
    if out_lap and full_speed_out_lap(settings, car):
        margin += settings.out_lap_margin_m
    return MinTimeSettings(
        v_max_mps=settings.v_max_mps,
        ds_m=settings.ds_m,
        margin_m=min(margin, 1.0),
        slip_fraction=settings.min_time_slip_fraction,
        ellipse_fraction=settings.min_time_ellipse_fraction,
        reserve_speed_mps=settings.min_time_reserve_speed_mps,
        reserve_fraction=settings.min_time_reserve_fraction,
        reserve_width_mps=settings.min_time_reserve_width_mps,
        reserve_steering_weight_s=settings.min_time_reserve_steering_weight_s,
        reserve_margin_m=settings.min_time_reserve_margin_m,
        reserve_yaw_pole_per_s=settings.min_time_reserve_yaw_pole_per_s,
        reserve_rear_fraction=settings.min_time_reserve_rear_fraction,
        reserve_from_mps=settings.min_time_reserve_from_mps,
        rear_ellipse_fraction=rear_ellipse_fraction(settings, car),
    )


def rear_ellipse_fraction(
    settings: RacelineSettings, car: DynamicVehicleParams | None = None
) -> float | None:
    """The rear axle's own ellipse share [-] of the raceline's line for `car` (None: the
    gym's), or None (the rear as the front, ``min_time_ellipse_fraction``).

    A car on Pacejka tyres whose rear peak friction is below ``min_time_oversteer_balance``
    of its front's oversteers at the limit: in steady cornering each axle uses ``a_y /
    (mu_i g)`` of its grip, so the rear reaches its ellipse first, while the front still
    has grip to spare for the yaw moment a tracking error or a braking turn-in puts on it,
    which a saturated rear cannot answer: the car spins (every such car of the varied
    family, ``shared.evaluation.car_family``, did once a run). Its rear keeps
    ``min_time_oversteer_rear_share`` of ``min_time_ellipse_fraction``. A step in the
    balance, not a ramp: the cars above it race their lines of before."""
    if not oversteers(settings, car):
        return None
    return settings.min_time_ellipse_fraction * settings.min_time_oversteer_rear_share


def oversteers(settings: RacelineSettings, car: DynamicVehicleParams | None = None) -> bool:
    """Whether `car` (None: the gym's) oversteers at the limit: Pacejka tyres whose rear
    peak friction is below ``min_time_oversteer_balance`` of the front's
    (``rear_ellipse_fraction``)."""
    car = car or F1TENTH_GYM
    if car.tyre_model != "pacejka" or settings.min_time_oversteer_balance <= 0.0:
        return False
    balance = axle_peak_friction(car, "rear") / axle_peak_friction(car, "front")
    return balance < settings.min_time_oversteer_balance


#: The pose sources of ``for_pose_source`` and their margin keys of ``[planner.raceline]``.
POSE_MARGINS = {"truth": "truth_margin_m", "ekf": "ekf_margin_m", "lidar": "lidar_margin_m"}
#: ... and their ``[planner.cimpcc_line]`` speed-estimate gains (``speed_estimate_gain``).
POSE_SPEED_GAINS = {"ekf": "ekf_speed_estimate_gain", "lidar": "lidar_speed_estimate_gain"}
#: The stack's ``[localization] pose_source`` -> the pose source of ``for_pose_source``: an
#: ``external`` pose (the simulator's pose sensor, a localiser) reaches the planner through the
#: bridge's EKF (the bench's ``--estimator ekf``), ``lidar`` through the particle filter into
#: the EKF (``--estimator lidar``). The stack never plans on the true pose.
STACK_POSE_SOURCES = {"external": "ekf", "lidar": "lidar"}


def stack_pose_source(pose_source: str) -> str:
    """The pose source (``POSE_MARGINS``) of the stack's ``[localization] pose_source``
    (``STACK_POSE_SOURCES``).

    Raises:
        ValueError: an unknown ``pose_source``.
    """
    if pose_source not in STACK_POSE_SOURCES:
        raise ValueError(f"unknown [localization] pose_source {pose_source!r}; choose one of "
                         f"{', '.join(STACK_POSE_SOURCES)}")
    return STACK_POSE_SOURCES[pose_source]


def for_stack(settings: PlannerSettings, pose_source: str) -> PlannerSettings:
    """`settings` for the stack's planner on ``[localization] pose_source`` `pose_source`
    (``"external"``, ``"lidar"``): ``for_pose_source`` with ``stack_pose_source``. The planner
    service, ``racestack up`` (the laps it makes before starting it) and ``racestack
    mintime --for raceline`` (the command a missing lap names) all build through here, so
    they key the same lap."""
    return for_pose_source(settings, stack_pose_source(pose_source))


def for_pose_source(settings: PlannerSettings, pose: str) -> PlannerSettings:
    """`settings` for a planner that sees poses from `pose` (``POSE_MARGINS``: ``truth``,
    ``ekf``, ``lidar``): the raceline's ``min_time_margin_m`` widened by that source's
    margin (``truth_margin_m``: a tube for the tracker's own error; ``ekf_margin_m``,
    ``lidar_margin_m``: for the localisation error, the tracker's inside them), and
    ``cimpcc-line``'s ``speed_estimate_gain`` that source's (``POSE_SPEED_GAINS``: the
    speed it reads off consecutive filtered poses leans on its speed loop's prediction;
    exact poses keep the planner's own). The settings themselves when nothing changes.

    Raises:
        ValueError: an unknown pose source.
    """
    if pose not in POSE_MARGINS:
        raise ValueError(f"unknown pose source {pose!r}; choose one of {', '.join(POSE_MARGINS)}")
    update: dict[str, object] = {}  # the sections (keywords: a field, not the method)
    extra = float(getattr(settings.raceline, POSE_MARGINS[pose]))
    if extra != 0.0:
        o = settings.raceline
        update.update(raceline=o.model_copy(
            update={"min_time_margin_m": min(o.min_time_margin_m + extra, 1.0)}))
    line = settings.cimpcc_line
    gain_key = POSE_SPEED_GAINS.get(pose)  # exact poses: the planner's own gain
    gain = line.speed_estimate_gain if gain_key is None else float(getattr(line, gain_key))
    if gain != line.speed_estimate_gain:
        update.update(cimpcc_line=line.model_copy(update={"speed_estimate_gain": gain}))
    return settings.model_copy(update=update) if update else settings


def line_request(
    settings: PlannerSettings, car: DynamicVehicleParams | None = None
) -> LapRequest:
    """The lap ``cimpcc-line`` contours (module docstring) for `car` (None: the F1TENTH
    gym's, the default ``[vehicle]``) with the planner `settings`; an oversteering car's
    rear keeps the raceline's share (``min_time_oversteer_rear_share``) of this line's
    ``ellipse_fraction``: without it the varied family's oversteering cars spun 135 times in
    18 cells."""
    line = settings.cimpcc_line
    lo, hi = settings.bounds.delta_rad
    planned = planning_vehicle(car or F1TENTH_GYM, (lo, hi))
    if line.grip_fraction != 1.0:
        planned = planned.model_copy(update={"mu": planned.mu * line.grip_fraction})
    rear = None
    if oversteers(settings.raceline, car):  # the raceline's rear share, on this line's ellipse
        rear = line.ellipse_fraction * settings.raceline.min_time_oversteer_rear_share
    return LapRequest(
        planned,
        MinTimeSettings(
            v_max_mps=line.v_max_mps,
            margin_m=line.line_margin_m,
            slip_fraction=line.slip_fraction,
            ellipse_fraction=line.ellipse_fraction,
            rear_ellipse_fraction=rear,
        ),
    )


def raceline_request(
    settings: PlannerSettings, car: DynamicVehicleParams | None = None,
    *, out_lap: bool = False,
) -> LapRequest:
    """The lap the raceline baseline tracks with ``line = "min_time"`` (module docstring)
    for `car` (None: the F1TENTH gym's) with the planner `settings`; `out_lap`: the line of
    its out lap (``has_out_lap_line``; the same lap when it has none)."""
    return LapRequest(
        planning_vehicle(car or F1TENTH_GYM, raceline_steering_limits(settings, car)),
        min_time_settings(settings.raceline, car, out_lap=out_lap),
    )


def raceline_steering_range(
    settings: PlannerSettings, car: DynamicVehicleParams | None = None
) -> tuple[float, float]:
    """The steering range [rad] the raceline's tracker commands (``[planner.raceline]
    steering_range``): `car`'s own lock (None: the F1TENTH gym's) with ``"car"``, the
    planner's ``[planner.bounds] delta_rad`` with ``"bounds"``."""
    if settings.raceline.steering_range == "car":
        v = car or F1TENTH_GYM
        return v.steering_min_rad, v.steering_max_rad
    lo, hi = settings.bounds.delta_rad
    return lo, hi


def raceline_steering_limits(
    settings: PlannerSettings, car: DynamicVehicleParams | None = None
) -> tuple[float, float]:
    """The steering range [rad] the raceline's minimum-time line is planned within:
    ``raceline_steering_range`` (the car's lock or the planner's bounds) times
    ``[planner.raceline] min_time_steering_fraction`` (the tracker itself commands the whole
    range), or ``min_time_steering_fraction_linear`` when it is set and `car` has the gym's
    unbounded ``linear`` tyres."""
    o = settings.raceline
    f = o.min_time_steering_fraction
    if o.min_time_steering_fraction_linear is not None and (
            car or F1TENTH_GYM).tyre_model == "linear":
        f = o.min_time_steering_fraction_linear
    lo, hi = raceline_steering_range(settings, car)
    return f * lo, f * hi


def limit_request(
    settings: PlannerSettings, car: DynamicVehicleParams | None = None,
    ds_m: float | None = None,
) -> LapRequest:
    """The car's limit (module docstring): `car` (None: the F1TENTH gym's) as it is, top
    speed ``settings.cimpcc.v_up_mps[0]`` [m/s], the default margin and grid (or `ds_m`
    [m]: the robustness benchmark's ``--min-time-ds`` on the long F1TENTH maps)."""
    grid = {} if ds_m is None else {"ds_m": ds_m}
    return LapRequest(
        car or F1TENTH_GYM, MinTimeSettings(v_max_mps=settings.cimpcc.v_up_mps[0], **grid)
    )


def request_for(
    use: str, settings: PlannerSettings, car: DynamicVehicleParams | None = None
) -> LapRequest:
    """The lap of `use` (one of ``USES``) with the planner `settings` for `car`.

    Raises:
        ValueError: `use` is not one of ``USES``.
    """
    if use == LIMIT:
        return limit_request(settings, car)
    out_lap = use.endswith(OUT_LAP) and use in USES
    spec = METHODS.get(use.removesuffix(OUT_LAP) if out_lap else use)
    if spec is not None and spec.reference == "min_time_line":
        return line_request(settings, car)
    if spec is not None and spec.reference == "planned_line":
        return raceline_request(settings, car, out_lap=out_lap)
    raise ValueError(f"unknown minimum-time lap {use!r}; choose one of {', '.join(USES)}")


def laps_of(
    method: str, settings: PlannerSettings, car: DynamicVehicleParams | None = None
) -> tuple[str, ...]:
    """The minimum-time laps (``USES``) planner `method` races on with `settings` for `car`
    (None: the gym's): the line for ``cimpcc-line``, the raceline's for ``raceline`` with
    ``line = "min_time"`` (and its out lap's, ``has_out_lap_line``), none for the others
    (``cimpcc``, ``mpcc``, a minimum-curvature raceline, ...)."""
    spec = method_spec(method)
    name = spec.base or spec.name
    if spec.reference == "min_time_line":
        return (name,)
    if spec.reference == "planned_line" and settings.raceline.line == "min_time":
        if has_out_lap_line(settings.raceline, car):
            return (name, name + OUT_LAP)
        return (name,)
    return ()
