"""Settings of the track's curvature mapping and of the CiMPCC / MPCC planner.

Defaults are the paper's (Table II and text; ``../shared/docs/cimpcc-notes.md``) unless a
docstring says otherwise. Pairs and triples follow the input layout ``[v_l, delta, v_p]`` and
the velocity pair ``v = [v_l, v_p]`` of the paper.
"""

from __future__ import annotations

from typing import Annotated, Literal

from pydantic import Field, field_validator, model_validator

from shared.car import CAR
from shared.config.base import Choices, Section
from shared.config.methods import CIMPCC, method_spec, planner_methods

NonNeg = Annotated[float, Field(ge=0.0, allow_inf_nan=False)]
Speed = Annotated[float, Field(ge=-20.0, le=20.0, allow_inf_nan=False)]
Triple = tuple[NonNeg, NonNeg, NonNeg]
Pair = tuple[NonNeg, NonNeg]


class CurvatureSettings(Section):
    """Offline curvature -> reference velocity mapping (paper III-A to III-C)."""

    window_m: float = Field(1.2, gt=0.0, le=20.0, description="moving-average window [m of arc]")
    alpha: float = Field(5.0, gt=0.0, le=100.0, description="sensitivity of g(K)=exp(-alpha K^2)")


class MethodWeights(Section):
    """Weights and references of one method; CiMPCC and MPCC are two instances of this.

    The cost (paper eq. 3 and 11), summed over the horizon:
    ``||xi_k||_Q - gamma v_p,k Ts + ||du_k||_R1 + ||u_k - u_ref||_R2
    + (1 - beta) ||v_k - v_low||_R3 + beta ||v_k - v_up||_R3``.

    Attributes:
        q_contour: Q's weight on the contour error e_c (lateral distance to the line)
            [1/m^2].
        q_lag: Q's weight on the lag error e_l (along the line) [1/m^2].
        gamma: progress reward per m/s of v_p per second.
        r1_delta_u: R1 = diag of the weights on the input changes du = (dv_l, d delta,
            dv_p) from one stage to the next.
        r2_input: R2 = diag of the weights on u - u_ref (v_l, delta, v_p).
        u_ref: the input reference (v_l [m/s], delta [rad], v_p [m/s]) R2 pulls towards.
        r3_velocity: R3 = diag of the weights pulling v = (v_l, v_p) to v_low / v_up.
        v_up_mps: upper velocity reference (v_l, v_p), taken where the track is straight
            (beta = 1) [m/s].
        v_low_mps: lower velocity reference (v_l, v_p), taken in tight bends (beta = 0)
            [m/s].
    """

    q_contour: NonNeg = 800.0
    q_lag: NonNeg = 800.0
    gamma: NonNeg = Field(40.0, description="progress reward per m/s of v_p per second")
    r1_delta_u: Triple = (10.0, 3500.0, 0.0)
    r2_input: Triple = (0.0, 10.0, 0.0)
    u_ref: tuple[Speed, Annotated[float, Field(ge=-1.0, le=1.0)], Speed] = (0.0, 0.0, 0.0)
    r3_velocity: Pair = (40.0, 40.0)
    v_up_mps: tuple[Speed, Speed] = (4.18, 3.8)
    v_low_mps: tuple[Speed, Speed] = (2.72, 2.47)


#: The paper's CiMPCC: R2 = diag(0, 10, 0), R3 = diag(40, 40), v_up (4.18, 3.8), v_low 0.65 v_up.
CIMPCC_WEIGHTS = MethodWeights()
#: The paper's MPCC: u_ref = (3.3, 0, 3.0), R2 = diag(40, 10, 40), no curvature term.
MPCC_WEIGHTS = MethodWeights(
    r2_input=(40.0, 10.0, 40.0), u_ref=(3.3, 0.0, 3.0), r3_velocity=(0.0, 0.0)
)
#: cimpcc-line: CiMPCC's weights with a 7x lighter steering-rate weight (R1 delta 3500 ->
#: 500: holding a line within centimetres needs the steering the centreline never asked for)
#: and 12.5x the progress reward (gamma 40 -> 500): against R3 = 40 it asks up to
#: ``gamma Ts / (2 R3)`` = 0.31 m/s more than the 95 %-grip profile's speed (the speed-state
#: model's planned speeds are the car's; the speed cap bounds them), i.e. it races nearer
#: the full grip than its line.
CIMPCC_LINE_WEIGHTS = CIMPCC_WEIGHTS.model_copy(
    update={"r1_delta_u": (10.0, 500.0, 0.0), "gamma": 500.0}
)
#: ... of the light model (``model = "kinematic_slip"``, ``config/cimpcc-line-light.toml``):
#: CiMPCC's progress reward (its commanded speeds are no car's speeds, and a larger reward
#: only runs it wide).
CIMPCC_LINE_LIGHT_WEIGHTS = CIMPCC_LINE_WEIGHTS.model_copy(update={"gamma": 40.0})


class InputBounds(Section):
    """Box bounds of the inputs (paper Table II).

    Attributes:
        v_l_mps: (min, max) of the speed command v_l [m/s].
        delta_rad: (min, max) of the steering angle delta, within [-1.2, 1.2] [rad].
        v_p_mps: (min, max) of the progress speed v_p [m/s].
    """

    v_l_mps: tuple[Speed, Speed] = (-10.0, 10.0)
    delta_rad: tuple[float, float] = Field((-0.35, 0.35))
    v_p_mps: tuple[Speed, Speed] = (-10.0, 10.0)

    @model_validator(mode="after")
    def _ordered(self) -> InputBounds:
        for name in ("v_l_mps", "delta_rad", "v_p_mps"):
            lo, hi = getattr(self, name)
            if not lo < hi:
                raise ValueError(f"{name}: lower bound {lo} must be below upper bound {hi}")
        if not (-1.2 <= self.delta_rad[0] and self.delta_rad[1] <= 1.2):
            raise ValueError("delta_rad bounds must lie within [-1.2, 1.2] rad")
        return self


class SolverSettings(Section):
    """The NLP solver back-end.

    Attributes:
        backend: the CasADi NLP solver: "fatrop" (structure-exploiting, fast) or "ipopt".
        max_iter: most solver iterations per solve.
        tol: the solver's convergence tolerance.
        mu_init: the solver's initial barrier parameter (interior point).
        bound_push: the initial point's push into the inequalities' interior.
    """

    backend: Literal["fatrop", "ipopt"] = "fatrop"
    compile: bool = Field(True, description="compile problem functions with a C compiler")
    compiler: str = Field("gcc", min_length=1, description="C compiler command")
    cache_dir: str | None = Field(
        None, description="compiled-problem cache; None = $RACESTACK_CACHE or ~/.cache/racestack"
    )
    max_iter: int = Field(100, ge=1, le=10000)
    tol: float = Field(1e-4, gt=0.0, le=1.0)
    mu_init: float = Field(1e-3, gt=0.0, le=1e3)
    bound_push: float | None = Field(
        None, gt=0.0, le=1.0,
        description="how far the solver pushes the initial point into the inequalities' "
        "interior (its bound_push and bound_frac); a warm start near the solution keeps "
        "more of itself with a small push; None: the back-end's default (1e-2)",
    )


class RacelineSettings(Section):
    """The raceline baseline (``services/planner/raceline/planner.py``): line, speed, tracker
    (``services/planner/raceline/tracker.py``)."""

    line: Literal["min_time", "min_curvature"] = Field(
        "min_time",
        description="'min_time': the car's minimum-time lap (solved once per track, cached); "
        "'min_curvature': the least-curved line with a forward-backward speed profile",
    )
    ds_m: float = Field(0.1, gt=0.01, le=1.0, description="spacing of the raceline points [m]")
    margin_m: float = Field(
        0.3, ge=0.0, le=2.0,
        description="min_curvature: keep the line this far inside the boundaries [m]",
    )
    min_time_margin_m: float = Field(
        0.02, ge=0.0, le=1.0,
        description="min_time: keep the car's footprint this far inside the boundaries [m]",
    )
    steering_range: Literal["car", "bounds"] = Field(
        "car",
        description="the steering range the line is planned in and the tracker commands: "
        "'car' the car's own lock ([vehicle] steering_min_rad / steering_max_rad, what the "
        "limit assumes: the F1TENTH car's 0.4189 rad); 'bounds' the planner's [planner."
        "bounds] delta_rad (the paper's Table II box, 0.35 rad; the line gives away 0.3-1.3 "
        "% to the limit on tight tracks with the gym car, up to 5 % with the identified "
        "car's)",
    )
    min_time_steering_fraction: float = Field(
        0.95, ge=0.5, le=1.0,
        description="min_time: the line steers within this fraction of steering_range, "
        "the rest a reserve for the tracker's feedback (1: the "
        "whole range; where a line holds the lock, as the gym's linear tyres do in tight "
        "bends, a car off it has no steering left to come back; 0.95 of the car's lock "
        "chosen on the generator's TUNING_SEEDS: 2 out-lap events in 135 cells against 4 "
        "at 1) [1]",
    )
    min_time_steering_fraction_linear: float | None = Field(
        0.85, ge=0.5, le=1.0,
        description="min_time, the gym's unbounded 'linear' tyres: the line steers within "
        "this fraction of steering_range instead of min_time_steering_fraction. Their line "
        "holds the lock through every tight bend at the speed cap (no grip bounds it, only "
        "the lock), and a car that leaves such a bend a few centimetres off its line has "
        "only the reserve to come back before the exit's kerb (the out lap's first pass, "
        "before the steering is learnt: 2 off-track events in the generator's TUNING_SEEDS' "
        "45 linear cells at 0.95 and 0.9, 0 at 0.85 for 0.2 % more lap time); None: "
        "min_time_steering_fraction [1]",
    )
    servo_margin_m: float = Field(
        0.03, ge=0.0, le=1.0,
        description="min_time, a car with a slow servo (its lag inverted by the tracker, "
        "e.g. the identified car's 0.158 s): this much more margin [m], the tube of its "
        "tracking error (2-3 cm outside the line at a bend's entry; tuned on the "
        "generator's TUNING_SEEDS); no effect on the gym car",
    )
    flying_servo_margin_m: float | None = Field(
        0.01, ge=0.0, le=1.0,
        description="min_time, a car with a slow servo that starts cautiously "
        "(start_speed_scale < 1): the line it races once its out lap is over is planned with "
        "this servo tube instead of servo_margin_m, which then keeps only the out lap's "
        "line (raceline-out-lap: held below its line's speeds the car runs inside at hairpin "
        "exits under hard acceleration; at full speed it needs less). The car changes lines "
        "where the cautious start ends. 0.01 chosen on the generator's tuning seeds "
        "1001-1030 (the identified car's closest pass in its flying laps 1.2 cm at 0, 2.2 cm "
        "at 0.01, inside a line 2.3 / 3.3 cm from the wall); None: one line, "
        "servo_margin_m throughout [m]",
    )
    out_lap_margin_m: float = Field(
        0.02, ge=0.0, le=1.0,
        description="min_time, a car that races its out lap at its line's speeds (no "
        "cautious start: start_speed_scale 1, or the gym's unbounded 'linear' tyres, whose "
        "line cannot be driven slower): the out lap races a line planned with this much "
        "more margin [m] (raceline-out-lap), and the car changes to its flying laps' line "
        "past out_lap_handover_share of the lap, where the two lines run together. The out "
        "lap is not timed, and its car has yet to learn its steering, may be joining its "
        "line and, with the lidar, has a filter still settling; 0: one line",
    )
    out_lap_handover_share: float = Field(
        0.5, ge=0.0, le=0.95,
        description="a full-speed out lap on a line of its own (out_lap_margin_m): the car "
        "changes to its flying laps' line past this share of the line's length, at the "
        "first station where the two lines run within 5 mm of each other over a metre (or, "
        "where they never do before 0.9 of it, within 5 mm of the nearest they come) [1]",
    )
    truth_margin_m: float = Field(
        0.003, ge=0.0, le=1.0,
        description="min_time, the planner on exact poses (the bench's --estimator truth): "
        "this much more margin [m], a tube for the tracker's own error. A line at the "
        "limit's own margin, followed within millimetres, beat the limit by cutting a few "
        "millimetres inside it in bends at the speed cap (F1TENTH maps, 0.25 m grid) or "
        "clipped an apex (gen-1007 on that grid); the other pose sources' tubes hold the "
        "tracker's error already",
    )
    ekf_margin_m: float = Field(
        0.02, ge=0.0, le=1.0,
        description="min_time, the planner on the EKF's poses (the bench's --estimator ekf, "
        "the stack's pose_source 'external'): this much more margin [m], the tube of the "
        "localisation's lateral error (its 95th percentile, 1.85-1.90 cm in the bench on "
        "gen:1002 and map416, RMS 0.9-1.0 cm; ``mintime.requests.for_pose_source``)",
    )
    lidar_margin_m: float = Field(
        0.01, ge=0.0, le=1.0,
        description="min_time, the planner on the lidar particle filter's poses (the bench's "
        "--estimator lidar, the stack's pose_source 'lidar'): this much more margin [m] "
        "(the lateral error's 95th percentile, 0.7 cm in the bench on gen:1002: the walls "
        "pin the car across; its 2.4 cm position RMS is mostly along the track)",
    )
    min_time_slip_fraction: float = Field(
        0.8, ge=0.1, le=1.0,
        description="min_time, Pacejka tyres: each axle's slip angle stays within this share "
        "of its peak slip (past the peak the force falls and the car spins; the identified "
        "rear gives 99 % of its peak force at 0.8 of its peak slip; tuned on the generator's "
        "TUNING_SEEDS); no effect on other tyres",
    )
    min_time_ellipse_fraction: float = Field(
        0.95, ge=0.1, le=1.0,
        description="min_time, Pacejka tyres: each axle's force stays within this share of "
        "its friction ellipse (room for the speed loop's corrections); no effect on other "
        "tyres",
    )
    min_time_oversteer_balance: float = Field(
        0.9, ge=0.0, le=1.0,
        description="min_time, Pacejka tyres: a car whose rear peak friction (mu D) is below "
        "this share of its front's oversteers at the limit, and its rear keeps "
        "min_time_oversteer_rear_share of the ellipse share (a rear at its ellipse has "
        "nothing left for the yaw moment of a front with grip to spare: every such car of the "
        "varied family spun; the identified car's is 0.95); 0: never [1]",
    )
    min_time_oversteer_rear_share: float = Field(
        0.9, ge=0.1, le=1.0,
        description="min_time, Pacejka tyres, an oversteering car (min_time_oversteer_balance)"
        ": its rear axle's force stays within this share of min_time_ellipse_fraction (tuned "
        "on varied:1001-1006 x gen:1001-1003: 0.95 and 0.93 still spun 4 and 3 of 18 cells, "
        "0.9 none) [1]",
    )
    min_time_reserve_speed_mps: float | None = Field(
        4.18, gt=0.0, le=20.0,
        description="min_time, friction-limited tyres: above this speed [m/s] each axle keeps "
        "a reserve of its friction ellipse for the tracker's corrections (the share of its "
        "radius falls smoothly to min_time_reserve_fraction over min_time_reserve_width_mps), "
        "with min_time_reserve_steering_weight_s and min_time_reserve_margin_m; the default "
        "is the paper's 4.18 m/s cap, so every line capped there is the line (and cache key) "
        "of before; None, or at or above v_max_mps: none (tuned on Oschersleben at "
        "--v-max 10, issue 21)",
    )
    min_time_reserve_fraction: float = Field(
        1.0, ge=0.1, le=1.0,
        description="min_time: the share of each axle's friction-ellipse radius the line uses "
        "min_time_reserve_width_mps and more above the reserve's start (the front's alone "
        "when min_time_reserve_rear_fraction is set); 1: the whole ellipse (the front's "
        "default: a saturated front only pushes the car wide; 0.9 for both axles, tuned on "
        "Oschersleben, spun the car on 8 of 15 generated tracks at --v-max 10) [1]",
    )
    min_time_reserve_width_mps: float = Field(
        2.0, ge=0.01, le=20.0,
        description="min_time: the speed range over which the reserve grows from none to "
        "its full share [m/s]",
    )
    min_time_reserve_steering_weight_s: float = Field(
        0.1, ge=0.0, le=10.0,
        description="min_time, with the reserve: a cost on the steering rate, k h sum "
        "S(v) (sv / sv_max)^2 [s] (S the reserve's ramp): a line the 20 Hz tracker can steer "
        "(unpenalised, the lap flicks the wheels at the rate limit for 0.1 s while braking "
        "at 9-10 m/s); 0: none",
    )
    min_time_reserve_margin_m: float = Field(
        0.1, ge=0.0, le=0.5,
        description="min_time, with the reserve: the footprint keeps this much more margin "
        "[m] at speed (times the reserve's ramp S(v): the tracking error's tube grows with "
        "the speed); 0: none",
    )
    min_time_reserve_yaw_pole_per_s: float | None = Field(
        2.0, ge=0.0, le=100.0,
        description="min_time, with the reserve: the line brakes no harder than keeps the "
        "car's yaw (linearised about straight running at its speed and braking) diverging "
        "at most this fast [1/s]; braking moves load off the rear, and above about 4.4 m/s "
        "the gym car then oversteers (at 10 m/s and 9.3 m/s^2 its yaw diverges at 8 1/s, "
        "faster than the 20 Hz tracker's delays catch: spins braking into bends at "
        "--v-max 10); None: no bound (tuned on the generator's tuning seeds at --v-max 10: "
        "without it 10 spins in 15 tracks, with 2 1/s 0-1; 1 and 0 1/s no better)",
    )
    min_time_reserve_from_mps: float | None = Field(
        0.0, ge=0.0, le=20.0,
        description="min_time, with the reserve (a line capped above "
        "min_time_reserve_speed_mps): the speed from which the reserve's grip part (its "
        "ellipse shares and steering cost) fades in over min_time_reserve_width_mps [m/s] "
        "(its margin still grows from min_time_reserve_speed_mps); None: from "
        "min_time_reserve_speed_mps. Lines capped at or below that speed are not changed. "
        "0 (the default): at every speed of such a line, its apexes at 4-5 m/s entered "
        "braking from 7-10 m/s included (faded in from 4.18 m/s the car spun there)",
    )
    min_time_reserve_rear_fraction: float | None = Field(
        0.8, ge=0.1, le=1.0,
        description="min_time, with the reserve: the rear axle's own share of its "
        "friction-ellipse radius at speed (a saturated rear spins the car, a saturated "
        "front only pushes it wide); None: min_time_reserve_fraction for both axles (tuned "
        "on the generator's tuning seeds at --v-max 10: 0.85 spun the car in 5 of 15, 0.75 "
        "cost 2.5 % more lap time than 0.8) [1]",
    )
    a_lat_mps2: float = Field(
        5.5, gt=0.0, le=50.0, description="min_curvature: lateral acceleration limit [m/s^2]"
    )
    a_accel_mps2: float = Field(
        4.0, gt=0.0, le=50.0, description="min_curvature: acceleration limit [m/s^2]"
    )
    a_brake_mps2: float = Field(
        5.0, gt=0.0, le=50.0, description="min_curvature: braking limit [m/s^2]"
    )
    v_max_mps: float = Field(4.18, gt=0.0, le=20.0, description="speed cap (CiMPCC's v_l up)")
    curvature_smoothing_points: int = Field(
        3, ge=1, le=50,
        description="min_curvature: half-width of the moving average on the line's curvature",
    )
    k_lateral_radpm: float = Field(
        0.5, ge=0.0, le=10.0, description="tracker: steering per m of look-ahead error [rad/m]"
    )
    k_lateral_speed_mps: float | None = Field(
        4.18, gt=0.0, le=20.0,
        description="tracker: above this planned speed [m/s] k_lateral falls as (v_k / "
        "v)^2 (the look-ahead feedback's heading gain grows with v^2; at 9-10 m/s the 20 Hz "
        "loop weaved the car wall to wall); the default is the paper's 4.18 m/s cap, so "
        "every lap at or below it is k_lateral's; None: k_lateral at every speed",
    )
    k_lateral_speed_exponent: float = Field(
        3.0, ge=0.0, le=6.0,
        description="tracker: above k_lateral_speed_mps k_lateral falls as (v_k / v)^n, this "
        "n [1] with v the smaller of the planned speed and the car's own (2 holds the "
        "heading feedback's bandwidth k_e l_d v / L; 3, tuned on the generator's tuning "
        "seeds at --v-max 10: 2 spun the car more, 4 left it 0.15 m off its line in long "
        "bends; no effect at or below k_lateral_speed_mps)",
    )
    lookahead_base_m: float = Field(0.0, ge=0.0, le=10.0, description="tracker: l_0 [m]")
    lookahead_time_s: float = Field(
        0.4, ge=0.0, le=5.0, description="tracker: look-ahead per m/s of speed [s]"
    )
    lookahead_min_m: float = Field(0.5, gt=0.0, le=10.0, description="tracker: l_d min [m]")
    lookahead_max_m: float = Field(4.0, gt=0.0, le=20.0, description="tracker: l_d max [m]")
    k_outward_per_s2: float = Field(
        25.0, ge=0.0, le=1000.0,
        description="tracker: acceleration cut per m of drift to a bend's outside [1/s^2]",
    )
    outward_drive_only_speed_mps: float | None = Field(
        4.18, gt=0.0, le=20.0,
        description="tracker: above this planned speed [m/s] (faded in over 1 m/s) the "
        "outward cut gives up drive force only (the acceleration down to min(a_plan, 0)), "
        "never brakes beyond the plan "
        "(braking takes the same friction ellipse: at 6-8 m/s the cut braked at 7-9 m/s^2 in "
        "bends and the car spun); the default is the paper's 4.18 m/s cap (every lap capped "
        "there as before); None: the cut at every speed",
    )
    grip_error_m: float = Field(
        0.3, ge=0.0, le=2.0,
        description="grip adaptation: each tick the car is further than this from the line "
        "[m] the plan's speeds shrink by grip_step (from a join's path; never beside an "
        "opponent or on the way back from one, nor for linear tyres on a line tighter "
        "than the steering lock turns the car, a drift no lower speed holds); 0: off. "
        "The identified car on the gym car's line: 3.0-4.4 x its limit with 16-82 spins a "
        "cell off, 1.41-1.46 with 0-7 spins at 0.3 (README, issue #21)",
    )
    grip_yaw_error_radps: float = Field(
        0.8, ge=0.0, le=20.0,
        description="grip adaptation: a tick the car's yaw rate is further than this from its "
        "plan's [rad/s] (from the last two poses, against the plan's at the speed scale, "
        "either way), grip_yaw_ticks in a row, cuts the scale too: tyres that cannot turn "
        "the car as planned before it strays from its line; 0: off",
    )
    grip_yaw_error_share: float = Field(
        0.25, ge=0.0, le=5.0,
        description="grip adaptation: the yaw-rate error allowed grows by this share of the "
        "plan's yaw rate [1] (the gym's linear tyres drift through their tightest bends, "
        "where the car follows the plan's yaw less exactly)",
    )
    grip_yaw_ticks: int = Field(
        2, ge=1, le=100,
        description="grip adaptation: ticks in a row beyond grip_yaw_error_radps to cut",
    )
    grip_step: float = Field(
        0.02, ge=0.0, le=0.5,
        description="grip adaptation: the speed scale's cut per tick beyond grip_error_m [1]",
    )
    grip_min_scale: float = Field(
        0.7, gt=0.1, le=1.0,
        description="grip adaptation: the lowest speed scale (0.7 of the plan's speeds, "
        "0.49 of its lateral acceleration) [1]",
    )
    grip_profile: bool = Field(
        True,
        description="grip adaptation: read the speed scale as grip (c^2 of the lateral "
        "acceleration the line asks in its bends) and re-plan the line's speed profile within "
        "it on the friction ellipse (straights stay at the cap, gentle bends slow less: "
        "raceline.grip_profile), once the scale has held for grip_profile_settle_ticks; "
        "false: the whole line at c times its speeds",
    )
    grip_profile_long_share: float = Field(
        0.7, gt=0.0, le=1.0,
        description="grip profile: the share of the grip the re-planned profile spends on "
        "braking into and driving out of the bends [1]",
    )
    grip_profile_lateral_share: float = Field(
        0.9, gt=0.0, le=1.0,
        description="grip profile: the share of the grip found the re-planned profile "
        "spends across the track [1] (tuned on gen:1001-1015 with the identified car on "
        "the gym car's line: 0.85 / 0.9 / 0.95 / 1 gave 2 / 2 / 11 / 15 spins)",
    )
    grip_relearn_on_servo: bool = Field(
        False,
        description="grip adaptation: when the servo's lag is first measured and acted on, "
        "the speed scale returns (once settled) to start_speed_scale if it was cut below it "
        "(those cuts came partly from the servo the tracker had not inverted) and the grip "
        "is learnt afresh. Off: held out, the identified car on the gym car's line then "
        "re-planned its profile at 0.8 before it had shown that grip: 10 spins in 8 of 84 "
        "cells against 2 in 2, one cell unfinished, for a median ratio 1.047 against 1.072",
    )
    grip_profile_settle_ticks: int = Field(
        10, ge=1, le=1000,
        description="grip profile: re-planned once the speed scale has not been cut for "
        "this many ticks (a slide cuts it tick after tick; the cuts in between scale the "
        "last profile)",
    )
    grip_replan_work_per_tick: int = Field(
        500, ge=1, le=10_000_000,
        description="grip profile: the re-plan is done a slice per tick, at most this many "
        "node steps of work each (its profile passes and its six plans over the line's "
        "nodes: about 16 per node, a step 0.7-1.2 us of CPU on the 2-core machines); the "
        "car drives the line it has at the scale it has until the re-planned one is done "
        "(15-60 ticks). Done in one tick, the re-plan took 10-20 ms of CPU against the "
        "planner's 2 ms budget",
    )
    speed_share: float = Field(
        1.0, gt=0.1, le=1.0,
        description="race the line at this share of its speeds: a slower car that keeps "
        "the line's path and its dynamic steering (ReferenceLap.slower), e.g. an opponent at "
        "85 % ([[cars]] pace sets it per car); 1: the line's own speeds",
    )
    start_speed_scale: float = Field(
        0.8, gt=0.1, le=1.0,
        description="cautious out lap: a run starts at this share of the line's speeds (the "
        "grip adaptation's scale), held over start_hold_share of the lap, then raised by "
        "start_rise_per_tick back to 1 unless the adaptation cut it; only on a line the car "
        "can drive slower (its tightest curvature within the steering lock's turn; a "
        "linear-tyre line drifts tighter). The identified car on the gym car's line spun in "
        "its first bends before the adaptation acted (README, issue #21); not for a car "
        "racing below its line (speed_share < 1: a slower car keeps its pace); 1: off",
    )
    start_hold_share: float = Field(
        0.5, ge=0.0, le=1.0,
        description="cautious out lap: the share of the line's length driven at "
        "start_speed_scale before it rises [1]",
    )
    start_rise_per_tick: float = Field(
        0.005, gt=0.0, le=1.0,
        description="cautious out lap: the speed scale's rise per tick after the hold (0.1 "
        "a second at 20 Hz: at once, it put two known cars off in their out lap) [1]",
    )
    start_probe_share: float = Field(
        0.2, ge=0.0, le=5.0,
        description="cautious out lap: the rise goes at most this share above the grip the "
        "car has shown, in speed scale (sqrt of the largest lateral acceleration it held on "
        "its line over what the line's bends at the grip ask); 0: no bound [1]. The "
        "identified car on the gym car's line rose to 1 past gentle bends and spun in the "
        "first fast S-bend (gen:1013); 0.1 left two known cars off in their out lap",
    )
    start_grip_error_m: float = Field(
        0.15, gt=0.0, le=2.0,
        description="cautious out lap: the grip adaptation's grip_error_m while it lasts "
        "(the car below its plan strays less; a slide caught at 0.15 m instead of 0.3) [m]",
    )
    steering_learning_gain: float = Field(
        0.5, ge=0.0, le=1.0,
        description="learning the line's steering lap by lap (iterative learning control, "
        "services/planner/raceline/learning.py): after each lap the feedback steering the "
        "tracker gave at each place of the line, times this gain, is added to a correction "
        "of the feed-forward there (for one plan at one speed scale: a cut or a re-plan "
        "starts it afresh; not where the line is planned above k_lateral_speed_mps, nor "
        "once the grip adaptation has cut the speeds); 0: off [1]. Tuned on the "
        "generator's tuning seeds: 0.8 spun the identified car on gen:1005",
    )
    steering_learning_smooth_m: float = Field(
        0.5, ge=0.0, le=5.0,
        description="learning the line's steering: the width (sigma) of the smoothing of "
        "each lap's correction along the line [m]",
    )
    steering_learning_lead_s: float = Field(
        0.2, ge=0.0, le=1.0,
        description="learning the line's steering: a tick's feedback corrects the "
        "feed-forward this long before where its steering acted [s] (the error it answers "
        "was caused that much earlier, through the servo and the car's response; at 0 "
        "the learning put the identified car off map416 in its third lap, 0.1 and 0.2 "
        "converge, 0.3 left a linear car off the track once)",
    )
    steering_learning_max_rad: float = Field(
        0.05, ge=0.0, le=0.5,
        description="learning the line's steering: the correction's bound [rad]",
    )
    servo_lag_estimate: bool = Field(
        True,
        description="measure the servo's lag while racing (the yaw response to the steering "
        "sent, services/planner/raceline/servo_lag.py) and invert the measured lag when it "
        "differs from the car's steering_time_constant_s by more than servo_lag_switch_s",
    )
    servo_lag_switch_s: float = Field(
        0.08, gt=0.0, le=1.0,
        description="how far the measured servo lag must be from the one acted on before the "
        "tracker takes it [s] (the F1TENTH gym's car measures within 0.02 s of its own)",
    )
    speed_delay_s: float = Field(
        0.022, ge=0.0, le=1.0,
        description="tracker: pose -> speed loop [s]: compute 2 ms + actuation 10 ms, which "
        "the simulator acts from its next integration sub-step (up to 9.6 ms later; the "
        "bench's loop: 21.2 ms in all). 0.012 left the car 0.04-0.07 m/s behind its line out "
        "of every slow bend (the identified car on map416: 0.6 % of the lap)",
    )
    steering_delay_s: float = Field(
        0.06, ge=0.0, le=1.0,
        description="tracker: pose -> wheels [s]: compute 2 + actuation 10 + steering 20 + "
        "servo 10 ms, plus an 18 ms allowance for the 20 Hz planner rate",
    )


class CimpccLineSolver(Section):
    """``cimpcc-line``'s own solver tolerances (the rest is ``[planner.solver]``'s).

    Warm-started from the shifted plan, its solution barely moves between ticks: a looser
    tolerance, a larger first barrier parameter and a small push into the interior save
    iterations without changing the laps (``python -m benchmarks.solve_time --method
    cimpcc-line --plant sim`` counts them; README).
    """

    tol: float = Field(2e-2, gt=0.0, le=1.0, description="convergence tolerance")
    mu_init: float = Field(1e-2, gt=0.0, le=1e3, description="initial barrier parameter")
    bound_push: float | None = Field(
        1e-6, gt=0.0, le=1.0,
        description="push of the warm start into the interior (None: the back-end's)",
    )


class CimpccLineSettings(Section):
    """``cimpcc-line``: CiMPCC's cost contouring the car's minimum-time line.

    The line and its speed profile are the minimum-time lap (``services.planner.mintime.ocp``)
    of the car, solved once per track and cached; the velocity pulls take the profile's
    speed at each predicted stage (beta = 1) (``services/planner/mpc/planner.py``,
    ``services/planner/reference.py``).
    """

    weights: MethodWeights = Field(
        CIMPCC_LINE_WEIGHTS,
        description="the paper's CiMPCC weights but R1 = diag(10, 500, 0) and gamma 500 "
        "(with model 'kinematic_slip' use gamma 40: config/cimpcc-line-light.toml); "
        "v_up/v_low are unused (the speed profile sets them per stage)",
    )
    horizon_steps: int = Field(
        10, ge=2, le=60,
        description="N of this method's problem (10 x 50 ms: 0.5 s ahead, as the paper's; "
        "README: longer horizons with the EKF's poses)",
    )
    model: Literal["kinematic", "kinematic_slip", "kinematic_slip_speed"] = Field(
        "kinematic_slip_speed",
        description="'kinematic': the paper's bicycle (wheelbase_m); 'kinematic_slip': with "
        "the car's steady-state tyre slip and wheelbase (the light model); "
        "'kinematic_slip_speed': the slip fitted up to the limit, and the car's speed a "
        "state behind its speed loop (v_l its command; the line's tyre drag per stage) "
        "(services/planner/mpc/model.py)",
    )
    cap_command: bool = Field(
        True,
        description="model 'kinematic_slip_speed': the speed command too is capped (at what "
        "brings the car just to v_max_mps in one period, plus the speed loop's lead for the "
        "line's tyre drag, faded out just over the cap), so the car's measured speed keeps "
        "the cap; false: only the planned speed is bounded (the car reached 4.23 m/s)",
    )
    traction_fraction: float | None = Field(
        0.8, gt=0.0, le=1.0,
        description="Pacejka tyres, model 'kinematic_slip_speed': the speed command's "
        "acceleration is held within this share of the friction circle min_i mu_i g left "
        "beside the plan's lateral acceleration (a friction ellipse for the drive; the rear "
        "spins when throttle and cornering take its whole grip); None or other tyres: no cap",
    )
    traction_fraction_gym: float | None = Field(
        0.9, gt=0.0, le=1.0,
        description="the same cap for the gym's tyres ('linear_saturated', 'linear'): out of "
        "hairpins at full steering lock the drive pushed the car wide over the boundary "
        "(held-out generated tracks: 15 -> 3 off-track events); None: no cap",
    )
    servo_state: bool = Field(
        True,
        description="model 'kinematic_slip_speed' on a car with a slow servo (its reach "
        "bounds the steering: the identified car's 0.158 s, not the gym's 0.01 s): the "
        "wheels' angle a state behind the servo, the steering input its target",
    )
    speed_estimate_gain: float = Field(
        1.0, gt=0.0, le=1.0,
        description="model 'kinematic_slip_speed': the car's speed at each pose is the speed "
        "loop's prediction plus this share of what the pose's displacement says beyond it "
        "(1: the displacement alone, exact on true poses; a filtered pose's noise over one "
        "period becomes speed noise the command cap multiplies by about 4). The planner "
        "on the EKF's or the lidar's poses takes ekf_speed_estimate_gain / "
        "lidar_speed_estimate_gain instead (``mintime.requests.for_pose_source``)",
    )
    ekf_speed_estimate_gain: float = Field(
        0.4, gt=0.0, le=1.0,
        description="speed_estimate_gain of the planner on the EKF's poses (the bench's "
        "--estimator ekf, the stack's pose_source 'external'); tuned on gen:1001-1003 "
        "(over the cap 4 -> 0 times)",
    )
    lidar_speed_estimate_gain: float = Field(
        0.4, gt=0.0, le=1.0,
        description="speed_estimate_gain of the planner on the lidar particle filter's poses "
        "(--estimator lidar, pose_source 'lidar')",
    )
    lead_pose_s: float = Field(
        0.05, ge=0.0, le=0.5,
        description="plan from the pose (and speed) predicted this far ahead with the acting "
        "command (compute 2 + actuation 10 + steering 20 + servo ~10 ms) [s]; 0: the "
        "measured pose",
    )
    v_max_mps: float = Field(
        4.18, gt=1.0, le=100.0,
        description="top speed of the minimum-time lap [m/s]; model 'kinematic_slip_speed': "
        "also a bound on the planned speed (the cap every method races at)",
    )
    line_margin_m: float = Field(
        0.06, ge=0.0, le=1.0,
        description="the minimum-time lap keeps its footprint this far inside [m] (room for "
        "the tracking error)",
    )
    slip_fraction: float = Field(
        0.8, ge=0.1, le=1.0,
        description="Pacejka tyres: the minimum-time lap keeps each axle's slip angle within "
        "this share of its peak slip (room for the tracking error before the tyre's force "
        "falls); no effect on other tyres",
    )
    ellipse_fraction: float = Field(
        0.95, ge=0.1, le=1.0,
        description="Pacejka tyres: the minimum-time lap keeps each axle's force within this "
        "share of its friction ellipse (room for the speed loop's corrections); no effect on "
        "other tyres",
    )
    grip_fraction: float = Field(
        0.95, gt=0.1, le=1.0,
        description="the minimum-time lap is solved for the car with mu times this (at the "
        "full limit the car drifts wide and loses more time than the 5 % costs)",
    )
    accel_lead_s: float | None = Field(
        None, ge=0.0, le=2.0,
        description="speed command lead over the lap's acceleration input [s]; None: "
        "1 / the car's speed_gain_accel_per_s (its speed loop's gain)",
    )
    brake_lead_s: float | None = Field(
        None, ge=0.0, le=2.0,
        description="... over its braking input [s]; None: 1 / speed_gain_brake_per_s",
    )
    integrator: Literal["rk4", "rk2", "euler"] | None = Field(
        "rk2",
        description="this method's discretisation of its model (None: [planner] "
        "integrator); 'rk2' (the midpoint rule) evaluates the model's derivatives half as "
        "often as 'rk4'",
    )
    lifted: bool = Field(
        False,
        description="track limits and speed pulls on each stage's own state instead of the "
        "prediction from the stage before (services/planner/mpc/problem.py: the same problem "
        "in another layout; README: its solve times)",
    )
    solver: CimpccLineSolver = CimpccLineSolver()


class RecoverySettings(Section):
    """Back to the track after a spin or slide (``services.planner.recovery``; a safety
    rule outside the optimisation, for every method alike)."""

    enabled: bool = Field(True, description="hand over to the rule while the car is lost")
    enter_outside_m: float = Field(
        0.3, ge=0.0, le=10.0, description="enter when the rear axle is this far outside [m]"
    )
    enter_heading_rad: float = Field(
        1.2, gt=0.0, le=3.1416, description="... or the heading this far off the track's [rad]"
    )
    stall_s: float = Field(
        1.0, gt=0.0, le=60.0, description="... or the method held the car still this long [s]"
    )
    exit_inside_m: float = Field(
        0.1, ge=0.0, le=2.0, description="leave once this far inside the boundaries [m]"
    )
    exit_heading_rad: float = Field(
        0.5, gt=0.0, le=3.1416, description="... with the heading within this [rad]"
    )
    speed_mps: float = Field(1.0, gt=0.0, le=5.0, description="speed while recovering [m/s]")


class PlannerSettings(Section):
    """The CiMPCC / MPCC planner: one problem, two weight sets.

    Attributes:
        integrator: discretisation of the model over dt_s: "rk4" (4th-order Runge-Kutta),
            "rk2" (the midpoint rule) or "euler".
    """

    method: Annotated[str, Choices(planner_methods)] = Field(
        CIMPCC,
        description="the planner the service runs: a method of the registry "
        "(shared/config/methods.py)",
    )
    cimpcc: MethodWeights = CIMPCC_WEIGHTS
    mpcc: MethodWeights = MPCC_WEIGHTS
    cimpcc_line: CimpccLineSettings = CimpccLineSettings()
    horizon_steps: int = Field(10, ge=2, le=60, description="N_p = N_c")
    dt_s: float = Field(
        0.05, gt=0.0, le=0.5, description="model step Ts [s]; also the planner period"
    )
    integrator: Literal["rk4", "rk2", "euler"] = "rk4"
    wheelbase_m: float = Field(
        CAR.wheelbase_m, gt=0.05, le=2.0, description="L of the kinematic bicycle [m]"
    )
    bounds: InputBounds = InputBounds()
    beta_mode: Literal["current", "per_stage"] = Field(
        "current",
        description="'current': one beta at the car's s (paper); 'per_stage': NSC at each "
        "predicted s of the previous plan",
    )
    track_margin_m: float = Field(
        0.12, ge=0.0, le=1.0, description="boundaries pulled in by this much (authors' code)"
    )
    slack_weight_linear: NonNeg = Field(1.0e3, description="cost per m of boundary violation")
    slack_weight_quadratic: NonNeg = Field(1.0e4, description="cost per m^2 of violation")
    delta_u_on_applied: bool = Field(
        False, description="also weigh u_0 - (last applied command) with R1 (paper: off)"
    )
    max_consecutive_failures: int = Field(
        3, ge=1, le=100, description="failed solves in a row before the planner brakes"
    )
    solver: SolverSettings = SolverSettings()
    raceline: RacelineSettings = RacelineSettings()
    off_track_speed_mps: float = Field(
        1.5,
        ge=0.0,
        le=20.0,
        description="safety: while the car is outside the track, |speed command| is capped here",
    )
    recovery: RecoverySettings = RecoverySettings()
    stale_state_s: float = Field(
        0.1, gt=0.0, le=5.0, description="planner service: state older than this -> brake"
    )
    opponent_stale_s: float = Field(
        0.25,
        gt=0.0,
        le=5.0,
        description="planner service, a method that plans around opponents: an "
        "``opponents`` record whose scan is older than this is dropped (counted) and the "
        "planner races as if nobody were seen [s]",
    )
    command_yield_s: float = Field(
        0.001,
        ge=0.0,
        le=0.02,
        description="planner service: after publishing a command, leave the CPU this long "
        "before the plan record and the next warm start, so the command leaves at once "
        "(matters on machines with few cores; 0: no pause)",
    )

    @field_validator("method")
    @classmethod
    def _registered(cls, name: str) -> str:
        method_spec(name, in_planner=True)  # UnknownMethodError (a ValueError) names them
        return name

    def weights(self, method: str | None = None) -> MethodWeights:
        """The weight set of `method` (default: the configured one); ValueError for a
        method without an MPC cost."""
        spec = method_spec(method or self.method)
        if spec.weights is None:
            raise ValueError(f"method {spec.name!r} has no MPC weights")
        w = self
        for part in spec.weights.split("."):
            w = getattr(w, part)
        return w
