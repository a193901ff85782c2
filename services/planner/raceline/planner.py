"""The raceline baseline of the paper's Table I (RDM+OTG): a global line, a speed profile,
a tracker. Pure maths; the only I/O is reading the minimum-time lap's artefact, through an
injectable loader (``services.planner.mintime.store.load_min_time_lap`` by default).

The paper compares CiMPCC with a path-velocity decomposition: a minimum-curvature path
(RDM, Braghin et al. 2008), a velocity plan (OTG, Werling et al. 2010) and a pursuit
tracker (Becker et al. 2023). Ours, built once per track (``[planner.raceline] line``):

- ``"min_time"`` (default): the **minimum-time lap** of the car (``services.planner.
  mintime``: the car's own single-track model at its friction limits, top speed
  ``v_max_mps``, footprint ``min_time_margin_m`` inside the boundaries, steering within
  ``min_time_steering_fraction`` (0.95) of the car's own lock (``[planner.raceline]
  steering_range = "car"``, what the limit assumes; ``"bounds"``: the planner's
  ``[planner.bounds] delta_rad``, the paper's box; the tracker commands the whole range;
  ``mintime.requests.raceline_request``): its
  CoG path, speeds, acceleration demand and steering. Solved once per track, car and
  settings by the tools (``mintime.store.ensure_artefacts``), then read from the cache. A
  car with a slow servo may race its cautious out lap on a second such lap planned with
  the servo's tube and its flying laps on one without (``flying_servo_margin_m``,
  ``mintime.requests.has_out_lap_line``); a car that races its out lap at full speed (the
  gym's ``linear`` tyres) races it on one with ``out_lap_margin_m`` more tube and changes
  lines past ``out_lap_handover_share`` of it, where the two run together.
- ``"min_curvature"``: the line of least curvature (``min_curvature_offsets``): the
  centreline resampled every ``ds_m``, each point moved along its left normal by
  ``alpha_i``; minimise the integral of the squared curvature of the moved points,
  subject to ``-(w_right - m) <= alpha_i <= w_left - m`` with ``m`` = ``margin_m`` (IPOPT
  on the exact discrete curvature); then the speed (``speed_profile``): ``v <= min(v_max,
  sqrt(a_lat / |kappa|))``, a forward pass with ``a_accel`` and a backward pass with
  ``a_brake``, around the loop (Werling's OTG plans jerk-optimal quintics in a Frenet
  frame; a forward-backward profile is the usual simplification); the steering fed
  forward from the steady-state single-track model at the planned speed.

Tracker (``services.planner.raceline.tracker``, the one the minimum-time replay uses): the car's
CoG (from the rear-axle pose and ``l_r``) projected onto the line; the line's steering
over the window the command will act in (``steering_delay_s`` after the pose, for one
planner period) plus ``k_e`` times the lateral error of a point ``l_d = l_0 + T_l v``
ahead; the speed command ``v_p + a_p / k`` through the car's proportional speed loop of
gain ``k``, over the speed channel's window (``speed_delay_s``), with an acceleration cut
when the car drifts to the outside of a bend. (Becker et al.'s model- and
acceleration-based pursuit is the same idea.)

``RacelinePlanner`` has the ``Planner`` interface the bench's closed loop uses (``step``,
``reset``, ``settings``), so the bench races it like the MPC methods. It is given the car
(``vehicle=``, a ``DynamicVehicleParams``; None: ``shared.config.vehicle.F1TENTH_GYM``,
the default ``[vehicle]``); callers pass the configuration's car, ``cfg.vehicle``. Its lap
times are in the README ("Laps at the limit").
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace
from functools import cached_property

import casadi as ca
import numpy as np

from services.planner.interface import BRAKING, RECOVERING, SOLVED, DriveCommand, SolveResult
from services.planner.mintime.model import reserve_ramp, servo_reach
from services.planner.mintime.ocp import MinTimeError, MinTimeLap, MinTimeSettings
from services.planner.mintime.requests import (
    OUT_LAP,
    full_speed_out_lap,
    has_out_lap_line,
    min_time_settings,
    planning_vehicle,
    raceline_steering_limits,
    raceline_steering_range,
)
from services.planner.mintime.store import MinTimeArtefactMissingError, load_min_time_lap
from services.planner.opponents import OpponentEstimate, predict_on_line
from services.planner.raceline.grip_profile import GripReplan, line_grip_mps2
from services.planner.raceline.join import MAX_SLOPE as MAX_JOIN_SLOPE
from services.planner.raceline.join import LineJoin
from services.planner.raceline.learning import LearningSettings, StepLearning
from services.planner.raceline.overtake import FREE, OvertakeParams, OvertakePlan, plan_around
from services.planner.raceline.servo_lag import (
    ServoLagEstimator,
    ServoLagSettings,
    linear_lateral_mps2,
    yaw_lag_table,
)
from services.planner.raceline.tracker import (
    ReferenceLap,
    Tracker,
    TrackerCommand,
    TrackerGains,
    TrackerTiming,
)
from services.planner.recovery import (
    TELEPORT_JUMP_M,
    HandOver,
    Recovery,
    StallWatch,
    handover_accel_mps2,
    ramps_from_rest,
)
from shared.angles import wrap_angle
from shared.config.methods import RACELINE
from shared.config.planner import CurvatureSettings, PlannerSettings, RacelineSettings
from shared.config.vehicle import F1TENTH_GYM, DynamicVehicleParams
from shared.curvature import track_profile
from shared.track import Track, TrackError
from shared.vehicle import GRAVITY_MPS2

#: IPOPT statuses accepted besides success: converged as far as its precision allows.
NEAR_OPTIMAL = frozenset({"Solved_To_Acceptable_Level", "Search_Direction_Becomes_Too_Small"})


#: Weight of the offset-smoothness term of the line's energy [1/m^3].
SMOOTHNESS_WEIGHT = 1e-3
#: The line keeps at most this share of the local bend radius on the inside of a bend.
INSIDE_RADIUS_SHARE = 0.5


class RacelineError(TrackError):
    """No raceline can be built on this track with these settings (a clear, one-line error
    in every shell, like any other unusable track)."""


#: What ``[planner.raceline] steering_delay_s`` holds besides the pure delays [s]: the gym
#: servo's lag and the allowance for the 20 Hz rate, tuned on the gym car; with a slow servo
#: its lag is inverted instead, from the pure delays: compute 2 ms, then actuation 10 +
#: steering 20 ms, which the simulator acts from its next integration sub-step (four of 9.6
#: ms: 38.4 ms; ``benchmarks/sysid.py`` ``acted_delay``), 40.4 ms in the bench's loop. 0.028
#: (a pure delay of 32 ms, without the sub-steps) left the identified car 0.5 % slower on
#: map416 and the varied family's held-out cars 2 spins more (README, "The delays the
#: tracker leads").
SERVO_ALLOWANCE_S = 0.018
#: A full-speed out lap changes to the flying laps' line where the two run within this
#: [m] of each other over this [m] either side, and before this share of the line at the
#: latest (``RacelinePlanner._hand_over_travel_m``).
HANDOVER_GAP_M = 0.005
HANDOVER_WINDOW_M = 0.5
HANDOVER_LAST_SHARE = 0.9
#: Tyres whose force falls past the peak (``recovery.ramps_from_rest``): the car joins the
#: line (the start, after a recovery) at most this fast [m/s] until it is this close to it
#: [m], then the hand-over ramps it up: joining at racing speed from 0.4 m off the line
#: spins the identified car.
JOIN_SPEED_MPS = 2.0
JOIN_TOLERANCE_M = 0.05
#: Speed scales of the steering feed-forward tables used below the line's speed (a car
#: held behind an opponent, joining the line, ramping up after a recovery:
#: ``RacelinePlanner._slow_steering``), and how far below the line's speed [m/s] they act.
FEED_FORWARD_SCALES = (0.4, 0.55, 0.7, 0.85, 1.0)
#: A car with a slow servo this far [m/s] below the speed asked of it steers the slower
#: plans for the speed it travels (``RacelinePlanner._steering_speed``): catching up after
#: the hand-over, not holding a share of the line (there the two differ by centimetres per
#: second).
CATCH_UP_MPS = 0.2
SLOW_SPEED_MPS = 0.05
#: How far ahead the offset from the line is kept inside the track [s of the line's speed].
OFFSET_ROOM_S = 1.0
#: Back towards the line the offset closes as a first-order lag of this time constant below
#: the lateral rate [s]: at the full rate (0.7 m/s) it reached the line with the car 0.17
#: rad across it, and ran on over the apex's wall (Oschersleben, an opponent, the lidar).
RETURN_TAU_S = 0.35
#: An offset below this is the line [m].
OFFSET_ZERO_M = 1e-3
#: The join's blended path (``raceline.join``): its steering is fed forward this far ahead
#: of the car [m] (the pure delays at racing speed), its speed keeps this share of the
#: tyres' grip on its tightest curvature over this far ahead [m].
JOIN_LEAD_M = 0.3
JOIN_GRIP_SHARE = 0.8
JOIN_LOOK_M = 1.5
#: ... and bends at most as tight as this share of the steering limit turns the car.
JOIN_STEER_SHARE = 0.8
#: A car with a slow servo joining at ``JOIN_SPEED_MPS`` moves across at this share of the
#: lateral speed the blend has at the line's top speed: its servo lags the blend's turn
#: back onto the line, and at the full share (a 12 degree blend) the identified car's front
#: corner went over the wall where the line runs 3 cm from it (the start of gen:1027 in
#: the generator's tuning family and of the held-out gen:3; 0.7 and 0.5 both clean there).
SLOW_SERVO_JOIN_SHARE = 0.7
#: A pass starts only once planned this many ticks in a row (the tick before it: the last
#: plan that was not a pass is kept): an estimate that opens a pass for a tick or two
#: does not swerve the car.
PASS_CONFIRM_TICKS = 3
#: Loads (or solves) the minimum-time lap: ``(track, vehicle, settings) -> MinTimeLap``.
MinTimeLoader = Callable[[Track, DynamicVehicleParams, MinTimeSettings], MinTimeLap]


@dataclass(frozen=True)
class Raceline:
    """A closed racing line with its speed profile and the tracker's plan.

    Attributes:
        track: the line as a ``Track`` (``xy`` the line, widths its distances to the
            boundaries), for projection and interpolation.
        offset_m: (n,) lateral offset of each point from the centreline [m] (left +).
        curvature_1pm: (n,) signed curvature of the line [1/m].
        speed_mps: (n,) planned speed at each point [m/s].
        reference: the plan the tracker follows (on ``track``'s points).
        kind: ``"min_time"`` or ``"min_curvature"``.
        min_time: the minimum-time lap the line comes from (``kind == "min_time"``).
    """

    track: Track
    offset_m: np.ndarray
    curvature_1pm: np.ndarray
    speed_mps: np.ndarray
    reference: ReferenceLap
    kind: str = "min_curvature"
    min_time: MinTimeLap | None = None

    def speed_at(self, s_m: float) -> float:
        """Planned speed [m/s] at arc length `s_m` of the line (periodic)."""
        s_cl, v_cl = self._closed_speed
        return float(np.interp(s_m % self.track.length_m, s_cl, v_cl))

    @cached_property
    def _closed_speed(self) -> tuple[np.ndarray, np.ndarray]:
        """(s, v) with the first point repeated at the lap length (for interpolation)."""
        return (
            np.append(self.track.s_m, self.track.length_m),
            np.append(self.speed_mps, self.speed_mps[0]),
        )

    @property
    def lap_time_s(self) -> float:
        """Lap time of the plan itself [s] (what a perfect tracker would drive)."""
        return self.reference.lap_time_s


def resample(track: Track, ds_m: float) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The centreline every ~`ds_m` [m]: (points (n, 2), left normals (n, 2), w_right, w_left)."""
    n = max(20, round(track.length_m / ds_m))
    s = np.arange(n) * track.length_m / n
    xy = track.point_at(s)
    d = np.roll(xy, -1, axis=0) - np.roll(xy, 1, axis=0)
    t = d / np.linalg.norm(d, axis=1, keepdims=True)
    normals = np.column_stack([-t[:, 1], t[:, 0]])
    w_r, w_l = track.interp_width(s)
    return xy, normals, np.asarray(w_r, dtype=float), np.asarray(w_l, dtype=float)


def min_curvature_offsets(
    xy: np.ndarray, normals: np.ndarray, lo: np.ndarray, hi: np.ndarray
) -> np.ndarray:
    """Offsets alpha (n,) [m] along `normals` that minimise the line's curvature energy.

    The line is ``p_i = xy_i + alpha_i * normals_i`` (closed). With ``a = p_i - p_(i-1)``,
    ``b = p_(i+1) - p_i``, the discrete (Menger) curvature at point i is
    ``kappa_i = 2 (a x b) / (|a| |b| |a + b|)``; minimise ``sum_i kappa_i^2 (|a| + |b|) / 2``
    (the integral of kappa^2 along the line) plus ``SMOOTHNESS_WEIGHT * sum_i
    (alpha_(i+1) - alpha_i)^2``, subject to ``lo <= alpha <= hi``. Exact
    curvature, so cutting a corner on the inside is not mistaken for straightening it (the
    bias of second differences of the points); solved with IPOPT from alpha = 0.

    Args:
        xy: (n, 2) centreline points [m], near-uniform spacing.
        normals: (n, 2) unit left normals.
        lo, hi: (n,) bounds [m] (lo < 0 < hi).

    Raises:
        RacelineError: the solver failed.
    """
    n = len(xy)
    alpha = ca.SX.sym("alpha", n)
    px = ca.DM(xy[:, 0]) + alpha * ca.DM(normals[:, 0])
    py = ca.DM(xy[:, 1]) + alpha * ca.DM(normals[:, 1])
    idx_prev = [(i - 1) % n for i in range(n)]
    idx_next = [(i + 1) % n for i in range(n)]
    ax, ay = px - px[idx_prev], py - py[idx_prev]
    bx, by = px[idx_next] - px, py[idx_next] - py
    la = ca.sqrt(ax**2 + ay**2)
    lb = ca.sqrt(bx**2 + by**2)
    lab = ca.sqrt((ax + bx) ** 2 + (ay + by) ** 2)
    kappa = 2 * (ax * by - ay * bx) / (la * lb * lab)
    energy = ca.sum1(kappa**2 * 0.5 * (la + lb))
    # a little smoothness of the offsets keeps IPOPT well conditioned where the coarse
    # source polyline has kinks (1e-3 per m^2 of offset change: negligible elsewhere)
    energy += SMOOTHNESS_WEIGHT * ca.sumsqr(alpha[idx_next] - alpha)
    solver = ca.nlpsol(
        "raceline_nlp",
        "ipopt",
        {"x": alpha, "f": energy},
        {
            "ipopt.print_level": 0,
            "print_time": False,
            "ipopt.sb": "yes",
            "ipopt.max_iter": 500,
            "ipopt.tol": 1e-6,
            "ipopt.acceptable_tol": 1e-4,
            "ipopt.acceptable_iter": 10,
        },
    )
    sol = solver(x0=np.zeros(n), lbx=lo, ubx=hi)
    stats = solver.stats()
    alpha_opt = np.asarray(sol["x"], dtype=float).reshape(-1)
    status = str(stats.get("return_status", "unknown"))
    # "steps too small to matter" is IPOPT's way of saying it cannot improve further
    done = stats.get("success", False) or status in NEAR_OPTIMAL
    if not done or not np.all(np.isfinite(alpha_opt)):
        raise RacelineError(RACELINE, f"no minimum-curvature line (IPOPT: {status})")
    return np.clip(alpha_opt, lo, hi)


def speed_profile(
    curvature_1pm: np.ndarray, seg_m: np.ndarray, settings: RacelineSettings
) -> np.ndarray:
    """Speeds (n,) [m/s] on a closed line: lateral limit, then acceleration and braking.

    Args:
        curvature_1pm: (n,) curvature at the points [1/m].
        seg_m: (n,) length of the segment from point i to point i+1 [m].
        settings: accelerations and the speed cap.
    """
    kappa = np.abs(curvature_1pm)
    v = np.minimum(settings.v_max_mps, np.sqrt(settings.a_lat_mps2 / np.maximum(kappa, 1e-9)))
    n = len(v)
    for _ in range(2):  # twice around, so the loop closes
        for i in range(n):  # forward: accelerate at most a_accel
            j = (i + 1) % n
            v[j] = min(v[j], math.sqrt(v[i] ** 2 + 2 * settings.a_accel_mps2 * seg_m[i]))
        for i in range(n - 1, -1, -1):  # backward: brake at most a_brake
            j = (i + 1) % n
            v[i] = min(v[i], math.sqrt(v[j] ** 2 + 2 * settings.a_brake_mps2 * seg_m[i]))
    return v


def default_min_time_loader(
    track: Track, vehicle: DynamicVehicleParams, settings: MinTimeSettings
) -> MinTimeLap:
    """``services.planner.mintime.store.load_min_time_lap`` with its default cache: reads
    the lap the tools made (``ensure_artefacts``), never solves."""
    return load_min_time_lap(track, vehicle, settings, use=RACELINE)


def _out_lap_loader(
    track: Track, vehicle: DynamicVehicleParams, settings: MinTimeSettings
) -> MinTimeLap:
    """``default_min_time_loader`` for the out lap's line (its error names that lap)."""
    return load_min_time_lap(track, vehicle, settings, use=RACELINE + OUT_LAP)


def build_min_curvature_raceline(
    track: Track, settings: RacelineSettings, vehicle: DynamicVehicleParams = F1TENTH_GYM
) -> Raceline:
    """The minimum-curvature line and its speed profile on `track` (module docstring)."""
    xy, normals, w_r, w_l = resample(track, settings.ds_m)
    m = settings.margin_m
    lo, hi = -(w_r - m), w_l - m
    # on the inside of a bend no further than INSIDE_RADIUS_SHARE of its radius, so the
    # moved points never fold over (neighbouring normals cross at the centre of curvature)
    # (the raw curvature: the kinks of a coarse source polyline are the tightest bends)
    bend = Track("resampled", xy, w_r, w_l).signed_curvature()
    with np.errstate(divide="ignore"):
        radius = np.where(np.abs(bend) > 1e-9, INSIDE_RADIUS_SHARE / np.abs(bend), np.inf)
    hi = np.where(bend > 0, np.minimum(hi, radius), hi)
    lo = np.where(bend < 0, np.maximum(lo, -radius), lo)
    if np.any(lo >= hi):
        raise RacelineError(
            track.source, f"raceline margin {m} m leaves no room where the track is narrowest"
        )
    try:
        alpha = min_curvature_offsets(xy, normals, lo, hi)
    except RacelineError as exc:
        raise RacelineError(track.source, exc.problem) from None
    line = xy + alpha[:, None] * normals
    try:
        line_track = Track(
            f"{track.name}-raceline", line, w_r + alpha, w_l - alpha, source=track.source
        )
    except TrackError as exc:
        problem = f"the raceline is not a valid loop ({exc.problem})"
        raise RacelineError(track.source, problem) from None
    kappa = line_track.signed_curvature()
    k = max(1, settings.curvature_smoothing_points)
    kappa = np.convolve(
        np.concatenate([kappa[-k:], kappa, kappa[:k]]),
        np.ones(2 * k + 1) / (2 * k + 1),
        mode="same",
    )[k:-k]
    seg = np.hypot(*(np.roll(line, -1, axis=0) - line).T)
    v = speed_profile(kappa, seg, settings)
    reference = ReferenceLap.from_path(line_track, kappa, v, vehicle)
    return Raceline(line_track, alpha, kappa, v, reference, kind="min_curvature")


def build_min_time_raceline(
    track: Track,
    settings: RacelineSettings,
    vehicle: DynamicVehicleParams = F1TENTH_GYM,
    steering_limits_rad: tuple[float, float] | None = None,
    loader: MinTimeLoader | None = None,
    *,
    out_lap: bool = False,
) -> Raceline:
    """The minimum-time lap of `vehicle` on `track` as a raceline (module docstring);
    `out_lap`: the out lap's line (``mintime.requests.has_out_lap_line``).

    Raises:
        RacelineError: no minimum-time lap exists (or the line is not a valid loop).
    """
    car = planning_vehicle(vehicle, steering_limits_rad)
    load = loader or (_out_lap_loader if out_lap else default_min_time_loader)
    try:
        lap = load(track, car, min_time_settings(settings, vehicle, out_lap=out_lap))
    except MinTimeArtefactMissingError:
        raise  # its own line: the command that makes the lap
    except MinTimeError as exc:
        raise RacelineError(track.source, f"no minimum-time line: {exc.problem}") from None
    xy = np.column_stack([lap.x_m, lap.y_m])
    s_c, e_c = track.project(xy)
    w_r, w_l = track.interp_width(s_c)
    try:
        line_track = Track(f"{track.name}-raceline", xy, w_r - e_c, w_l + e_c, source=track.source)
    except TrackError as exc:
        problem = f"the minimum-time line is not a valid loop ({exc.problem})"
        raise RacelineError(track.source, problem) from None
    reference = ReferenceLap.from_min_time(lap, line_track)
    return Raceline(
        line_track,
        -np.asarray(e_c, dtype=float),
        np.asarray(lap.kappa_radpm, dtype=float),
        np.asarray(lap.v_mps, dtype=float),
        reference,
        kind="min_time",
        min_time=lap,
    )


def build_raceline(
    track: Track,
    settings: RacelineSettings,
    vehicle: DynamicVehicleParams = F1TENTH_GYM,
    steering_limits_rad: tuple[float, float] | None = None,
    loader: MinTimeLoader | None = None,
) -> Raceline:
    """The raceline ``settings.line`` asks for on `track` for `vehicle` (module docstring).

    Args:
        track: the track.
        settings: ``[planner.raceline]``.
        vehicle: the car the line is planned for.
        steering_limits_rad: the planner's steering bounds (the minimum-time line is
            planned within them); None: the car's own.
        loader: where the minimum-time lap comes from (default: read from the disk cache,
            never solved; missing: ``MinTimeArtefactMissingError``).
    """
    if settings.line == "min_curvature":
        return build_min_curvature_raceline(track, settings, vehicle)
    return build_min_time_raceline(track, settings, vehicle, steering_limits_rad, loader)


def scaled_raceline(
    raceline: Raceline, scale: float, vehicle: DynamicVehicleParams
) -> Raceline:
    """`raceline` driven at `scale` (0, 1] of its speed profile (an opponent below the
    limit, issue #24): the same path, speeds ``x scale``, and the plan rebuilt for that
    profile by ``ReferenceLap.slower`` (the steady-state single-track steering and
    acceleration demand at the new speeds, plus the lap's own dynamic part faded by the
    share's fourth power). Scaling the minimum-time lap's own steering instead left its
    dynamic part wrong and the car ran wide (18 off-track events in two laps of map416 at
    0.85); the steady state alone clipped map416's apex at 0.95 every lap."""
    if not 0.0 < scale <= 1.0:
        raise ValueError(f"speed scale must be in (0, 1], got {scale}")
    if scale == 1.0:
        return raceline
    scaled = raceline.reference.slower(scale, vehicle)
    return replace(raceline, speed_mps=raceline.speed_mps * scale, reference=scaled)


def slower_plans(
    ref: ReferenceLap, vehicle: DynamicVehicleParams
) -> tuple[ReferenceLap, tuple[ReferenceLap, ...]]:
    """`ref`'s path at its own speeds for `vehicle` (``ReferenceLap.from_path``, the steady
    state its slower plans start from) and its plan at each ``FEED_FORWARD_SCALES`` but
    the last (``ReferenceLap.slower``)."""
    steady = ReferenceLap.from_path(ref.line, ref.kappa_1pm, ref.v_mps, vehicle)
    return steady, tuple(ref.slower(k, vehicle, steady=steady)
                         for k in FEED_FORWARD_SCALES[:-1])


def planner_timing(
    settings: PlannerSettings, vehicle: DynamicVehicleParams | None = None
) -> TrackerTiming:
    """The tracker's timing in the planner: one planner period, the configured delays.

    A car with a slow servo (``services.planner.mintime.model.servo_reach``: the identified
    car's 0.158 s) has its lag inverted instead of counted as a delay: the window then
    starts ``SERVO_ALLOWANCE_S`` earlier, after the pure delays, and the tracker leads the
    planned steering by the servo's time constant (``TrackerTiming``).
    """
    o = settings.raceline
    tau = servo_reach(vehicle or F1TENTH_GYM)
    if tau is None:
        return TrackerTiming(settings.dt_s, o.speed_delay_s, o.steering_delay_s)
    return TrackerTiming(settings.dt_s, o.speed_delay_s, pure_servo_delay_s(settings),
                         servo_time_constant_s=tau)


def pure_servo_delay_s(settings: PlannerSettings) -> float:
    """Pose -> the servo's target [s]: ``[planner.raceline] steering_delay_s`` without the
    gym servo's share (``SERVO_ALLOWANCE_S``): the window of a lag that is inverted."""
    return max(settings.raceline.steering_delay_s - SERVO_ALLOWANCE_S, 0.0)


def tracker_gains(settings: RacelineSettings) -> TrackerGains:
    """The tracker's feedback gains from ``[planner.raceline]``."""
    return TrackerGains(
        k_lateral_radpm=settings.k_lateral_radpm,
        lookahead_base_m=settings.lookahead_base_m,
        lookahead_time_s=settings.lookahead_time_s,
        lookahead_min_m=settings.lookahead_min_m,
        lookahead_max_m=settings.lookahead_max_m,
        k_outward_per_s2=settings.k_outward_per_s2,
        k_lateral_speed_mps=settings.k_lateral_speed_mps,
        k_lateral_speed_exponent=settings.k_lateral_speed_exponent,
        outward_drive_only_speed_mps=settings.outward_drive_only_speed_mps,
    )


class RacelinePlanner:
    """The tracker along a precomputed raceline, with the ``Planner`` interface."""

    def __init__(
        self,
        track: Track,
        settings: PlannerSettings,
        curvature: CurvatureSettings | None = None,
        *,
        method: str = RACELINE,
        vehicle: DynamicVehicleParams | None = None,
        raceline: Raceline | None = None,
        min_time_loader: MinTimeLoader | None = None,
        timer: Callable[[], float] = time.perf_counter,
        speed_scale: float | None = None,
        overtake: OvertakeParams | None = None,
    ) -> None:
        """Build the raceline (or reuse one) on `track` for `vehicle` (None: the default
        car, ``F1TENTH_GYM``); `method` is the name its results carry; `speed_scale`
        drives the line's speed profile scaled (``scaled_raceline``; 1: the line's own;
        None: ``[planner.raceline] speed_share``);
        `overtake`: how it plans around opponents (``set_opponents``)."""
        self.method = method
        self.track = track
        self.settings = settings
        self.options = settings.raceline
        self.vehicle = vehicle or F1TENTH_GYM
        #: the told car's servo is slow (``servo_reach``): joining its line from low speed
        #: it steers for the speed it has (``_steering_speed``)
        self._slow_servo = servo_reach(self.vehicle) is not None
        b = settings.bounds
        #: the steering the tracker commands [rad] (``[planner.raceline] steering_range``)
        self._delta_lim = raceline_steering_range(settings, self.vehicle)
        self._speed_lim = (b.v_l_mps[0], b.v_l_mps[1])
        self.raceline = raceline or build_raceline(
            track, settings.raceline, self.vehicle,
            raceline_steering_limits(settings, self.vehicle), min_time_loader,
        )
        if speed_scale is None:
            speed_scale = settings.raceline.speed_share
        self.raceline = scaled_raceline(self.raceline, speed_scale, self.vehicle)
        #: the share of the line's own speeds this planner's profile drives (a slower car)
        self.line_share = float(speed_scale)
        #: the line as built; ``raceline`` is it, or it re-planned for the grip found
        #: (``_replan_for_grip``) until the next ``reset``
        self.built_line = self.raceline
        #: the built line's path at its own speeds (``ReferenceLap.from_path``: each
        #: re-plan's plans start from it) and its plan at each ``FEED_FORWARD_SCALES`` but
        #: the last (``_slow_trackers``), made here, not in the first tick that needs them
        self._built_steady, self._built_slow_plans = slower_plans(
            self.built_line.reference, self.vehicle)
        #: the current ``raceline``'s slower plans
        self._slow_plans = self._built_slow_plans
        #: the out lap's own line and its slower plans (``mintime.requests.has_out_lap_line``:
        #: a slow servo's line with the servo's whole tube, raced while the cautious start
        #: holds the car below its line; ``_cautious_start`` hands over to the built line);
        #: None: the out lap races the built line
        self._out_lap: tuple[Raceline, tuple[ReferenceLap, ...]] | None = None
        #: why the out lap races the flying laps' line though it has one of its own (its
        #: wider tube infeasible on a narrow track, or never made); None: it does not
        self.out_lap_error: str | None = None
        if (raceline is None and self.line_share == 1.0 and settings.raceline.line == "min_time"
                and has_out_lap_line(settings.raceline, self.vehicle)):
            try:
                out = build_min_time_raceline(
                    track, settings.raceline, self.vehicle,
                    raceline_steering_limits(settings, self.vehicle), min_time_loader,
                    out_lap=True)
            except (MinTimeError, RacelineError) as exc:  # the flying line throughout, as before
                # (a slow servo's 5.3 cm tube found no lap on gen-2 for varied:5)
                self.out_lap_error = str(exc)
            else:
                self._out_lap = (out, slower_plans(out.reference, self.vehicle)[1])
                out.track.prepare_projection()
                # made here, not in the first tick (up to 0.2 s on a 400 m map)
                _ = self._out_lap_gaps
        #: the grip re-plan under way (``_replan_for_grip``), a slice per tick
        self._grip_job: GripReplan | None = None
        #: node steps of grip re-plan work done so far (every job, every run): a tick that
        #: raised it carried re-plan work (``benchmarks/planner_ticks.py``)
        self.replan_work_done = 0
        for tr in (track, self.raceline.track):  # their per-tick tables, not in a tick
            tr.prepare_projection()
        self.overtake = overtake or OvertakeParams()
        self.opponents: list[OpponentEstimate] = []
        self.plan: OvertakePlan = FREE  #: the last tick's plan around the opponents
        self.tracker = Tracker.for_vehicle(
            self.raceline.reference,
            planner_timing(settings, self.vehicle),
            tracker_gains(self.options),
            self.vehicle,
        )
        #: the timing the planner was told (``reset`` returns to it)
        self._told_timing = self.tracker.timing
        self.servo_lag: ServoLagEstimator | None = None  #: measures the servo while racing
        if self.options.servo_lag_estimate:
            self.servo_lag = ServoLagEstimator(ServoLagSettings(
                settings.dt_s, pure_servo_delay_s(settings),
                self.vehicle.lf_m + self.vehicle.lr_m,
                max_lateral_mps2=linear_lateral_mps2(self.vehicle)))
            _ = self._yaw_lags  # made here (1-2 ms), not in the tick of the first estimate
        curvature = curvature or CurvatureSettings()
        self.profile = track_profile(track, curvature)
        self._timer = timer
        self.recovery = Recovery(
            track, settings.recovery, settings.wheelbase_m, min(-b.delta_rad[0], b.delta_rad[1])
        )
        self._stall = StallWatch()
        self._handover = HandOver(handover_accel_mps2(self.vehicle))
        #: the steering feed-forward's correction learnt lap by lap (``raceline.learning``)
        self.learning = StepLearning(self.raceline.reference.length_m, LearningSettings(
            gain=self.options.steering_learning_gain,
            smooth_m=self.options.steering_learning_smooth_m,
            max_rad=self.options.steering_learning_max_rad))
        self.reset()

    @property
    def horizon(self) -> int:
        """N of the reported preview (the planner's horizon)."""
        return self.settings.horizon_steps

    def reset(self) -> None:
        """Forget where the car was (next step searches the whole line)."""
        self._s_line: float | None = None
        self._s_track: float | None = None
        self.tracker.reset()
        self.recovery.reset()
        self._stall.reset()
        self._handover.active = False
        self.learning.clear()
        #: the grip adaptation's speed scale (``step``): 1 until the car strays off the line
        #: (the cautious out lap's start scale on a line the car can drive slower)
        o = self.options
        if self.raceline is not self.built_line:  # the line as built, for the told grip
            self._follow(self.built_line, 1.0, self._built_slow_plans)
        self._grip_job = None
        #: the speed scale the current ``raceline``'s profile was re-planned for (1: the
        #: line's own); the tracker drives it at ``speed_scale / profile_scale``
        self.profile_scale = 1.0
        self._scale_seen = 1.0  #: the speed scale at the last tick (a cut: lower)
        self._scale_quiet = 0  #: ticks since the speed scale was last cut
        #: the servo's lag has been measured (or is not measured: the told car's is used)
        self._servo_known = not self.options.servo_lag_estimate
        #: the grip is to be learnt afresh once the scale settles (``grip_relearn_on_servo``)
        self._relearn = False
        # a car racing below its line (``line_share``: a slower car) keeps its pace from
        # the start: held at 0.8 of its own 0.85, 0.68 of the line, whose steering is not
        # the slower plan's, it left map416 twice in every start; held at 0.8 of the line,
        # the car behind followed it at its own held speed for half a lap and with the
        # lidar's view swerved onto the wall 4 times in 50 starts (Oschersleben 600-649)
        cautious = (o.start_speed_scale < 1.0 and self.line_share == 1.0
                    and self.drivable_slower)
        self.speed_scale = o.start_speed_scale if cautious else 1.0
        #: the cautious out lap (``_cautious_start``): "hold", "rise" or None (over)
        self._start_phase: str | None = "hold" if cautious else None
        #: the out lap at the line's speeds (no cautious start), or one whose line is a
        #: full-speed out lap's (``full_speed_out_lap``: the gym's linear tyres, whose line
        #: may be gentle enough to drive slower): on its own line it hands over where the
        #: lines run together (``_hand_over_out_lap``; a cautious start may hand over first,
        #: where its scale reaches 1: gen-1028's rose to 1 only in the second flying lap)
        self._full_speed_out_lap = not cautious or full_speed_out_lap(o, self.vehicle)
        self._hand_over_at_m: float | None = None  #: how far it drives before [m]
        if self._out_lap is not None:  # on the out lap's own line: the cautious start
            # hands over where it ends, a full-speed out lap where the lines run together
            self._follow(self._out_lap[0], 1.0, self._out_lap[1])
        self._start_travel_m = 0.0  #: the line's length driven since the start [m]
        self._grip_shown = 0.0  #: the lateral acceleration held on the line [m/s^2]
        self._start_s: float | None = None  #: the line station of the last tick [m]
        #: reached the line since the start, the last recovery or the last manoeuvre
        #: around a car (the grip adaptation judges only then)
        self._on_line = False
        #: peaky tyres: join the line at JOIN_SPEED_MPS first, then ramp up (``step``)
        self._joining = ramps_from_rest(self.vehicle)
        self._drove = False  #: the last tick's command was the tracker's
        self._speed_cmd = 0.0  #: the last speed command [m/s]
        self._last_xy: tuple[float, float] | None = None  #: the last pose's position [m]
        self._offset = 0.0  #: the lateral offset the tracker drives, ramped [m]
        self.plan = FREE
        self._pass_ticks = 0  #: ticks in a row a pass was planned but not yet started
        self._last_yaw: float | None = None  #: the last pose's yaw [rad]
        self._yaw_rate: float | None = None  #: the yaw rate over the last period [rad/s]
        self._travel_mps: float | None = None  #: the distance over the last period / dt
        self._yaw_ticks = 0  #: ticks in a row with the yaw rate off the plan's (grip)
        #: the join onto the line in progress (``raceline.join``), and whether the next
        #: step starts one (the start, a move, a hand-back from the recovery rule)
        self._join: LineJoin | None = None
        self._join_pending = True
        if self.servo_lag is not None:
            self.servo_lag.reset()
        if self.tracker.timing != self._told_timing:
            self._retime(self._told_timing)
        #: the servo's lag the tracker acts on [s] (the told car's until one is measured)
        self.servo_lag_s = self.vehicle.steering_time_constant_s

    @cached_property
    def _yaw_lags(self) -> tuple[np.ndarray, np.ndarray]:
        """The car's own yaw lag by speed (``servo_lag.yaw_lag_table``)."""
        return yaw_lag_table(self.vehicle)

    def _retime(self, timing: TrackerTiming) -> None:
        """The tracker (and the slower lines' ones) acting on `timing`."""
        self.tracker.retime(timing)
        self.__dict__.pop("_slow_trackers", None)  # rebuilt on their plans when next needed

    def _measure_servo(self, x_m: float, y_m: float, yaw_rad: float) -> None:
        """Feed the servo-lag estimator this tick's pose; when the lag it measures (less the
        car's own yaw lag, ``yaw_lag_s``) is ``servo_lag_switch_s`` from the one acted on,
        the tracker inverts the measured one (``TrackerTiming.servo_time_constant_s``)."""
        est_lag = self.servo_lag
        if est_lag is None:
            return
        est_lag.observe(x_m, y_m, yaw_rad)
        est = est_lag.estimate()
        if est is None:
            return
        self._servo_known = True
        tau = max(est.tau_s - float(np.interp(est.speed_mps, *self._yaw_lags)), 0.0)
        o = self.options
        if abs(tau - self.servo_lag_s) <= o.servo_lag_switch_s:
            return
        measured = self.tracker.timing != self._told_timing  # a measured lag acted on
        self.servo_lag_s = tau
        # the cuts so far were (partly) the servo's: with ``grip_relearn_on_servo``, once
        # the slide has settled, the grip is learnt afresh (``_replan_for_grip``)
        self._relearn = self._relearn or (o.grip_relearn_on_servo and not measured)
        told = self._told_timing
        pure = pure_servo_delay_s(self.settings)
        self._retime(TrackerTiming(told.period_s, told.speed_delay_s, pure,
                                   servo_time_constant_s=tau))

    def set_opponents(self, opponents: Sequence[OpponentEstimate]) -> None:
        """The other cars for the next steps (an empty list: race the line alone)."""
        self.opponents = list(opponents)

    def _plan_around(self, cx: float, cy: float, hint: float | None) -> OvertakePlan:
        """The overtaking plan (``raceline.overtake``) from the CoG and the opponents."""
        if not self.opponents:
            return FREE
        s_e, e_e = self.tracker.project(cx, cy, hint)
        t = self.overtake.times()
        line = self.raceline.track
        ref = self.built_line.reference  # opponents keep their share of its profile
        preds = [predict_on_line(line, o, t, s_e, ref) for o in self.opponents]
        return plan_around(
            self.raceline.reference, s_e, e_e, preds, self._offset, self.overtake,
            v_e_mps=self._speed_cmd, speed_scale=self.tracker_scale,
        )

    @cached_property
    def _slow_trackers(self) -> list[Tracker]:
        """A tracker per ``FEED_FORWARD_SCALES`` (but the last) on the line at that share of
        its speed profile (``ReferenceLap.slower``: the steady-state steering and slip at
        those speeds with the line's dynamic part faded in), for a car held below the
        line's speed. Their plans are made beside the line's (``_slow_plans``: at
        construction, in a grip re-plan's job); a tracker on one is cheap."""
        return [
            Tracker.for_vehicle(plan, self.tracker.timing, self.tracker.gains, self.vehicle)
            for plan in self._slow_plans
        ]

    def _slow_steering(
        self,
        cx: float,
        cy: float,
        yaw: float,
        hint: float,
        speed_mps: float,
        line_rad: float,
        slope: float = 0.0,
    ) -> float:
        """Steering [rad] for a car held at `speed_mps`, below the line's: the line's own
        feed-forward and reference yaw are for its speed (slower, the car needs less of the
        dynamic part of the steering and slips less: it would run inside); interpolated
        between the trackers of the two nearest ``FEED_FORWARD_SCALES`` (the top one is
        the line's own, `line_rad`), for the speed `speed_mps` of ``_steering_speed``."""
        v_p = max(float(self.raceline.reference.at("v", hint)), 0.1)
        ratio = min(max(speed_mps / v_p, FEED_FORWARD_SCALES[0]), 1.0)
        scales = FEED_FORWARD_SCALES
        i = min(int(np.searchsorted(scales, ratio, side="right")) - 1, len(scales) - 2)
        lo = self._slow_trackers[i].command(cx, cy, yaw, hint, offset_m=self._offset,
                                            offset_slope=slope, speed_mps=self._travel_mps)
        if i + 1 == len(scales) - 1:
            hi_rad = line_rad
        else:
            hi = self._slow_trackers[i + 1].command(cx, cy, yaw, hint, offset_m=self._offset,
                                                    offset_slope=slope,
                                                    speed_mps=self._travel_mps)
            hi_rad = hi.steering_rad
        w = (ratio - scales[i]) / (scales[i + 1] - scales[i])
        return (1.0 - w) * lo.steering_rad + w * hi_rad

    def _steering_speed(self, speed_mps: float, tc: TrackerCommand) -> float:
        """The speed [m/s] the slower plans are picked for (``_slow_steering``), from the
        speed command `speed_mps` and the tracker's command `tc`.

        On the line, held at a share of it (the cautious out lap, a grip cut, a car ahead):
        the command, or the tracker's command without the speed loop's lead ``a_cmd / k``
        (``Tracker.command``) when that is lower. Driving, the lead keeps the command above
        the speed the car holds (the proportional loop needs the error): held at 0.9 of
        map416's line the gym car commanded 4.06 m/s at 3.8, took the line's own steering
        for 4.18 m/s and ran 4 cm inside every lap (held at 0.9 on the generator's
        TUNING_SEEDS: 14 off-track events in 5 of 15 races, none without the lead).
        Braking, the command: the speed the car slows to by the time the steering acts.

        Joining the line from low speed (a join's path, the slow join of peaky tyres, the
        hand-over's ramp): the command with its lead for a fast servo, the speed travelled
        over the last period for a slow one (the identified car's 0.158 s: accelerating
        at 0.8 of its line, the command put it at the line's speed and an S-bend's
        steering flipped 0.4 rad early on map416). Without the lead there, a standing
        start at map416's 4.85 m left the track with either car. A slow servo's car more
        than ``CATCH_UP_MPS`` below the speed asked after the hand-over (still
        accelerating to it) steers for its travel speed too: for the speed asked at once,
        the identified car's standing start at map416's 2.31 m left the track."""
        travel = self._travel_mps if self._slow_servo else None
        if self._joining or self._join is not None or self._handover.active:
            return speed_mps if travel is None else travel
        t = self.tracker
        k = t.k_accel if tc.accel_mps2 >= 0.0 else t.k_brake
        asked = min(speed_mps, tc.speed_mps - tc.accel_mps2 / k)
        if travel is not None and travel < asked - CATCH_UP_MPS:
            return travel  # a slow servo's car still catching up with the speed asked
        return asked

    def _offset_room(self, s_m: float) -> tuple[float, float]:
        """(lo, hi) [m]: the offsets from the line (right +) that keep the car's footprint
        ``wall_margin_m`` inside both boundaries over the next ``OFFSET_ROOM_S`` at the
        line's speed from `s_m` (a car back on its own after a pass returns to the line at
        its lateral rate, and the track may narrow faster)."""
        p = self.overtake
        line = self.raceline.track
        v = max(float(self.raceline.reference.at("v", s_m)), 1.0)
        s = s_m + np.linspace(0.0, OFFSET_ROOM_S * v, 6)
        w_r, w_l = line.interp_width(s)
        room = 0.5 * p.ego_width_m + p.wall_margin_m
        return -(float(np.min(w_l)) - room), float(np.min(w_r)) - room

    def _offset_steering(self, s_m: float) -> float:
        """The kinematic steering [rad] the offset path needs beyond the line's at `s_m`:
        ``(l_f + l_r) (kappa / (1 + kappa d) - kappa)`` with ``d`` the offset (right +,
        ``kappa`` left +: inside a left bend the radius is ``1 / kappa + d``, smaller); the
        line's feed-forward alone would leave the feedback ``k_e`` to make it up, a steady
        error towards the line (towards the car being passed)."""
        kappa = float(self.raceline.reference.at("kappa", s_m))
        denom = max(1.0 + kappa * self._offset, 0.3)
        return (self.vehicle.lf_m + self.vehicle.lr_m) * (kappa / denom - kappa)

    def prepare(self) -> None:
        """Nothing to do ahead of time (the ``Planner`` interface)."""

    def step(
        self,
        x_m: float,
        y_m: float,
        yaw_rad: float,
        on_command: Callable[[DriveCommand], None] | None = None,
    ) -> SolveResult:
        """The tracker's command from the rear-axle pose (x, y [m], yaw [rad])."""
        t0 = self._timer()
        line = self.raceline.track
        if not all(math.isfinite(v) for v in (x_m, y_m, yaw_rad)):
            cmd = DriveCommand(0.0, 0.0)
            if on_command is not None:
                on_command(cmd)
            return self._result(
                cmd, x_m, y_m, yaw_rad, 0.0, 0.0, 0.0, "non-finite pose", t0, status=BRAKING
            )
        self._measure_servo(x_m, y_m, yaw_rad)
        last_yaw, self._last_yaw = self._last_yaw, yaw_rad
        self._yaw_rate = (None if last_yaw is None
                          else wrap_angle(yaw_rad - last_yaw) / self.settings.dt_s)
        last, self._last_xy = self._last_xy, (x_m, y_m)
        self._travel_mps = (None if last is None
                            else math.hypot(x_m - last[0], y_m - last[1]) / self.settings.dt_s)
        if last is not None and math.hypot(x_m - last[0], y_m - last[1]) > TELEPORT_JUMP_M:
            self._relocate()  # the car was moved: search the whole track, start afresh
        lr = self.vehicle.lr_m
        cx, cy = x_m + lr * math.cos(yaw_rad), y_m + lr * math.sin(yaw_rad)  # the CoG
        s_t, e_t = self._project_track(x_m, y_m)
        self._s_track = s_t
        was_recovering = self.recovery.active
        stalled = self._stall.update(x_m, y_m, self.settings.dt_s, counts=self._drove)
        self._drove = False
        rec = self.recovery.update(x_m, y_m, yaw_rad, s_t, e_t, stalled)
        hint = self._s_line
        if rec is not None or was_recovering:
            # follow the rule's anchored progress, on the track and (scaled) on the line
            s_t = self._s_track = self.recovery.s_m
            guess = s_t * line.length_m / self.track.length_m
            hint = float(line.project(np.array([cx, cy]), guess, 2.0)[0])
        if rec is not None:
            self._s_line = hint
            self._stall.reset()
            self._speed_cmd = rec.speed_mps
            cmd = DriveCommand(rec.speed_mps, rec.steering_rad)
            if on_command is not None:
                on_command(cmd)
            return self._result(
                cmd,
                x_m,
                y_m,
                yaw_rad,
                hint,
                s_t,
                e_t,
                f"recovery: {rec.reason}",
                t0,
                status=RECOVERING,
            )
        if was_recovering:  # hand back at the car's speed and ramp up
            self._on_line = False
            self._handover.start(self._speed_cmd)
            self._joining = ramps_from_rest(self.vehicle)
            self._join_pending = True
        if self._join_pending:  # from where the car is onto the line, smoothly
            self._join_pending = False
            self._join = self._start_join(cx, cy, hint)
        plan = self._plan_around(cx, cy, hint)
        if plan.mode == "pass" and self.plan.mode != "pass":
            self._pass_ticks += 1
            if self._pass_ticks < PASS_CONFIRM_TICKS:
                plan = self.plan  # the last plan that was not a pass, its cap with it
        else:
            self._pass_ticks = 0
        self.plan = plan
        slope = join_steer = 0.0
        join_cap = math.inf
        if self._join is not None:
            s_j = self.tracker.project(cx, cy, hint)[0]
            if plan is not FREE or self._join.done(s_j):  # a pass ramps on from here
                self._join = None
                if plan is FREE:
                    self._offset = 0.0
            else:
                self._offset = self._join.offset(s_j)
                slope = self._join.slope(s_j)
                join_steer, join_cap = self._join_feed(s_j)
        if self._join is None and (plan is not FREE or self._offset != 0.0):
            # ramp the offset towards the plan's:
            # out twice as fast as the plan assumes (the car lags it), back towards the
            # line at its rate (a fast swing back turns the car's corners over the wall)
            before = self._offset
            out = abs(plan.offset_m) > abs(self._offset)
            rate = self.overtake.lateral_rate_mps * (2.0 if out else 1.0)
            if not out:  # ... and easing in as it nears the line
                rate = min(rate, abs(plan.offset_m - self._offset) / RETURN_TAU_S)
            step = rate * self.settings.dt_s
            self._offset += min(max(plan.offset_m - self._offset, -step), step)
            if plan is FREE and abs(self._offset) < OFFSET_ZERO_M:
                self._offset = 0.0
            if plan is FREE:  # nobody near: back inside the track ahead (a pass or a
                # follow plans its corridor inside it itself)
                lo, hi = self._offset_room(hint if hint is not None else 0.0)
                # (never off the line for it: where the line runs nearer a wall than the
                # room, the bound left the offset jumping round it and never back to 0),
                # at the lateral rate: snapped there in one tick, a follower 0.11 m beside
                # the line whose car ahead was lost swerved back over it onto the wall
                # (Oschersleben seed 623, --source lidar)
                target = min(max(self._offset, min(lo, 0.0)), max(hi, 0.0))
                fast = self.overtake.lateral_rate_mps * self.settings.dt_s
                self._offset = before + min(max(target - before, -fast), fast)
        tc = self.tracker.command(cx, cy, yaw_rad, hint, offset_m=self._offset,
                                  speed_scale=self.tracker_scale, offset_slope=slope,
                                  speed_mps=self._travel_mps)
        self._s_line = tc.s_m
        self._count_travel(tc.s_m)
        self._cautious_start(tc.s_m)
        if plan is FREE and self._join is None and self._offset == 0.0:
            self._hand_over_out_lap(tc.s_m)
        yaw_error = self._yaw_error(tc.s_m)
        if self._start_phase is not None and plan is FREE and self._offset == 0.0:
            self._show_grip(tc.s_m)
        if plan is FREE and (self._join is not None or self._offset == 0.0):
            self._adapt_grip_yaw(yaw_error)
            # judged from the line or a join's path, never beside a car: there the car lags
            # its ramped offset by more than a slide (with grip_error_m 0.3 the adaptation
            # fired in 7 of 10 passes on Oschersleben and slowed the car for good)
            self._adapt_grip(tc.e_m - self._offset)
        else:  # ... nor on the way back from beside one before the car is on its line
            # again (the offset reaches 0 before the car: Oschersleben seed 725 cut the
            # speed scale to 0.92 there, 0.4 m from the line, and left the track)
            self._on_line = False
            self._yaw_ticks = 0
        self._replan_for_grip(tc.s_m)
        speed = tc.speed_mps
        steering = tc.steering_rad
        if plan is not FREE:
            speed = min(speed * plan.speed_factor, plan.speed_cap_mps)
        speed = min(max(speed, self._speed_lim[0]), self._speed_lim[1], join_cap)
        if self._joining:  # peaky tyres reach the line slowly, then ramp from there
            if self._join is not None or abs(tc.e_m) > JOIN_TOLERANCE_M:  # (the blend
                # crosses the line on its way: joined is at its end)
                speed = min(speed, JOIN_SPEED_MPS)
            else:
                self._joining = False
                self._handover.start(self._speed_cmd)
        if self._handover.active:
            speed = self._handover.cap(speed, self.settings.dt_s)
        # the line's own speed command: the grip adaptation's scale is a speed held below
        # the line's too (the tracker's steering is the line's at its own speed)
        line_speed = tc.speed_mps / self.tracker_scale
        slow = speed < min(line_speed, self._speed_lim[1]) - SLOW_SPEED_MPS
        if (self.options.steering_learning_gain > 0.0 and plan is FREE and not slow
                and self.speed_scale >= 1.0
                and (self.raceline is self.built_line
                     or (self._on_out_lap_line and self._full_speed_out_lap))
                and self._join is None and self._offset == 0.0 and not self._joining
                and not self._handover.active):
            # on the line at its speeds, with the grip it was planned for: the correction
            # learnt there, and this tick's feedback learnt from (a car the grip
            # adaptation has cut lacks grip: more steering there only saturates its front;
            # learning on the identified car's re-planned profiles of the gym car's line
            # put it off the track 8 -> 16 times in a cell)
            steering += self._learn_steering(tc)
        if slow:
            # held below the line's speed (behind a car, joining the line, the hand-over's
            # ramp, a grip adaptation): the steering of the line at that speed; the line's
            # own, for its speed, turned the identified car joining at 2 m/s off the inside
            # of map416's first bends (2 off-track events in every out lap)
            steering = self._slow_steering(cx, cy, yaw_rad, tc.s_m,
                                           self._steering_speed(speed, tc), steering, slope)
        if self._join is not None:  # the blended path bends more (less) than the line
            steering += join_steer
        elif self._offset != 0.0:  # the offset path bends more (less) than the line
            steering += self._offset_steering(tc.s_m)
        self._speed_cmd = speed
        self._drove = plan.mode != "follow"  # waiting behind a car is not a stall
        delta = min(max(steering, self._delta_lim[0]), self._delta_lim[1])
        cmd = DriveCommand(speed, delta)
        if on_command is not None:
            on_command(cmd)
        return self._result(cmd, x_m, y_m, yaw_rad, tc.s_m, s_t, e_t, "tracker", t0)

    def _learn_steering(self, tc: TrackerCommand) -> float:
        """The steering correction learnt where `tc`'s steering acts [rad]
        (``raceline.learning``), and `tc`'s feedback learnt from; 0 and nothing learnt
        where the line is planned above ``k_lateral_speed_mps``: there the feedback is
        scheduled down and does not settle on a feed-forward error within a bend (at
        ``--v-max 10`` learning there spun the car in 4 of 15 tuning tracks)."""
        ref = self.raceline.reference
        v_d = self.tracker_scale * float(ref.at("v", tc.steer_s_m))
        v_k = self.options.k_lateral_speed_mps
        if v_k is not None and v_d > v_k + 1e-6:
            return 0.0
        s_d = tc.steer_s_m
        if self.raceline is not self.built_line:  # a full-speed out lap on its own line
            # (``_hand_over_out_lap``), within a few centimetres of the flying laps' one:
            # learnt for that line at the same place (its stations scaled by the lengths),
            # so the first flying lap has the whole out lap's correction, not half of it
            s_d *= self.built_line.track.length_m / self.raceline.track.length_m
        self.learning.context((id(self.built_line.reference), self.tracker_scale,
                               self.tracker.timing))
        lead = v_d * self.options.steering_learning_lead_s
        self.learning.record(s_d - lead, tc.feedback_rad, v_d * self.settings.dt_s)
        return self.learning.correction(s_d)

    @property
    def replanning(self) -> bool:
        """A grip re-plan is under way (``_replan_for_grip``): its slices run in the
        coming ticks."""
        return self._grip_job is not None

    @property
    def tracker_scale(self) -> float:
        """The share of the current ``raceline``'s speeds the tracker drives: the grip
        adaptation's speed scale over the one its profile was re-planned for."""
        return self.speed_scale / self.profile_scale

    def _follow(
        self, raceline: Raceline, profile_scale: float, slow_plans: tuple[ReferenceLap, ...]
    ) -> None:
        """Drive `raceline` (the line or it re-planned for `profile_scale`) from the next
        tick: a tracker on its plan with the timing acted on, the slower lines' trackers
        on `slow_plans` (its plan at ``FEED_FORWARD_SCALES`` but the last) when next
        needed."""
        self.raceline = raceline
        self.profile_scale = profile_scale
        self._slow_plans = slow_plans
        self.tracker = Tracker(raceline.reference, self.tracker.timing, self.tracker.gains,
                               self.tracker.k_accel, self.tracker.k_brake)
        self.tracker.reset(self._s_line)
        self.__dict__.pop("_slow_trackers", None)

    @cached_property
    def _line_grip_mps2(self) -> float:
        """What the line asks in its bends at the grip [m/s^2] (``line_grip_mps2``)."""
        ref = self.built_line.reference
        return line_grip_mps2(ref.v_mps, ref.kappa_1pm)

    def _replan_for_grip(self, s_line_m: float) -> None:
        """``[planner.raceline] grip_profile``: once the grip adaptation's speed scale has
        held ``grip_profile_settle_ticks`` below the one the profile was planned for, the
        line's speed profile re-planned for the grip it says (``raceline.grip_profile``);
        not in the cautious out lap (its scale is a start's, not the grip's), nor before the
        servo's lag is measured (a car's slides then are partly its servo's: re-planned
        from the first cut, the identified car took the gym car's gentle bends faster with
        its 0.158 s servo not inverted, 30 spins in the 15 tuning cells against 3); nor
        for the gym's unbounded ``linear`` tyres (no grip to find: re-planned, gen-20's
        line, tighter than the lock turns the car, drove the car to 4.6 m/s, 10 % over the
        cap, 16-22 times a run). With ``grip_relearn_on_servo`` (off by default), the
        first time the lag measured is acted on, the scale (once settled) returns to
        ``start_speed_scale`` on the line as built: the cuts before came partly from the
        servo.

        The re-plan is a job (``GripReplan``) done ``grip_replan_work_per_tick`` node steps
        per tick; the car drives the line it has at ``tracker_scale`` until the job hands
        over the new one (the scale cut meanwhile then drives it at ``speed_scale /
        profile_scale``, and a re-plan for that scale follows once it settles)."""
        o = self.options
        if self.speed_scale < self._scale_seen:
            self._scale_quiet = 0
        else:
            self._scale_quiet += 1
        self._scale_seen = self.speed_scale
        if self._grip_job is not None:  # a re-plan under way: its next slices
            self._advance_grip_job(s_line_m)
            return
        if self._start_phase is not None or self._scale_quiet < o.grip_profile_settle_ticks:
            return
        if self._relearn:  # the servo's lag measured since the cuts: from the start's
            # scale again, on the line as built
            self._relearn = False
            if self.speed_scale < o.start_speed_scale:
                self.speed_scale = self._scale_seen = o.start_speed_scale
                if self.raceline is not self.built_line:
                    self._follow(self.built_line, 1.0, self._built_slow_plans)
                self._scale_quiet = 0
                return
        if (not o.grip_profile or not self._servo_known
                or self._unbounded_tyres
                or abs(self.speed_scale - self.profile_scale) <= 1e-9):
            return
        grip = o.grip_profile_lateral_share * self._line_grip_mps2
        self._grip_job = GripReplan(self.built_line, self.speed_scale, self.vehicle,
                                    o.grip_profile_long_share, grip,
                                    FEED_FORWARD_SCALES[:-1], self._built_steady)
        self._advance_grip_job(s_line_m)  # its first slices in this tick

    def _advance_grip_job(self, s_line_m: float) -> None:
        """The grip re-plan's next slices (``grip_replan_work_per_tick`` node steps); the
        car on the re-planned line from the next tick once it is done."""
        assert self._grip_job is not None
        job = self._grip_job
        before = job.work_done
        finished = job.advance(self.options.grip_replan_work_per_tick)
        self.replan_work_done += job.work_done - before
        if finished:
            done = job.result
            assert done is not None
            self._grip_job = None
            self._s_line = s_line_m
            self._follow(done.raceline, done.scale, done.slow_plans)

    @cached_property
    def drivable_slower(self) -> bool:
        """Whether the line can be driven below its speeds: its tightest curvature is within
        what the steering lock turns the car kinematically (``tan(delta_max) / L``). A
        minimum-time lap of unbounded (``linear``) tyres drifts through its tightest bends
        1.4-2.8 times tighter than that (README, issue #21): slower, without the line's
        slip, the car turns at its lock's radius and runs wide."""
        return float(np.max(np.abs(self.raceline.reference.kappa_1pm))) <= self._turn_1pm

    @cached_property
    def _unbounded_tyres(self) -> bool:
        """The told car has the gym's ``linear`` tyres: no peak force, so no grip for the
        adaptation to find or for a join to be capped by, and a line that drifts through
        bends tighter than the lock turns the car (``drivable_slower``)."""
        return self.vehicle.tyre_model == "linear"

    @cached_property
    def _turn_1pm(self) -> float:
        """The tightest curvature the steering lock turns the car at, kinematically
        (``tan(delta_max) / L``) [1/m]."""
        wheelbase = self.vehicle.lf_m + self.vehicle.lr_m
        return math.tan(min(-self._delta_lim[0], self._delta_lim[1])) / wheelbase

    def _count_travel(self, s_line_m: float) -> None:
        """The line's length driven since the start (``_start_travel_m``, [m]): the forward
        progress from the last tick's station to `s_line_m` [m] (wrapped)."""
        length = self.raceline.track.length_m
        if (self._start_s is None and self._hand_over_at_m is None
                and self._full_speed_out_lap and self._on_out_lap_line):
            self._hand_over_at_m = self._hand_over_travel_m(s_line_m)
        if self._start_s is not None:
            self._start_travel_m += max(
                0.0, (s_line_m - self._start_s + 0.5 * length) % length - 0.5 * length)
        self._start_s = s_line_m

    @property
    def _on_out_lap_line(self) -> bool:
        """The car races the out lap's own line (``_out_lap``)."""
        return self._out_lap is not None and self.raceline is self._out_lap[0]

    def _hand_over_out_lap(self, s_line_m: float) -> None:
        """A full-speed out lap on a line of its own (``[planner.raceline]
        out_lap_margin_m``, no cautious start): the flying laps' line from the next tick
        once the car has driven to the hand-over (``_hand_over_travel_m``, planned in the
        first tick, ``_count_travel``) and is on its line (no join, no offset, no car
        around: the caller's), at the out lap line's station `s_line_m` [m]. A cautious
        start hands over where its scale reaches 1 (``_cautious_start``)."""
        if not (self._full_speed_out_lap and self._on_out_lap_line
                and self._hand_over_at_m is not None):
            return
        if self._start_travel_m >= self._hand_over_at_m:
            self._follow(self.built_line, 1.0, self._built_slow_plans)

    def _hand_over_travel_m(self, s0_m: float) -> float:
        """How far [m] a full-speed out lap from the out lap line's station `s0_m` [m]
        drives before it changes lines: to the first station past
        ``out_lap_handover_share`` of the line where the two lines run within
        ``HANDOVER_GAP_M`` of each other over ``HANDOVER_WINDOW_M`` either side, or, where
        they never do before ``HANDOVER_LAST_SHARE`` of it, within that of the nearest
        they come there (a line one tube wider all round: at once)."""
        length = self._out_lap[0].track.length_m
        s_k, worst = self._out_lap_gaps
        ahead = (s_k - s0_m) % length
        first = self.options.out_lap_handover_share * length
        window = (ahead >= first) & (ahead <= max(first, HANDOVER_LAST_SHARE * length))
        if not np.any(window):
            return first
        ok = window & (worst <= max(HANDOVER_GAP_M, float(worst[window].min()) + HANDOVER_GAP_M))
        return float(ahead[ok].min())

    @cached_property
    def _out_lap_gaps(self) -> tuple[np.ndarray, np.ndarray]:
        """(stations (n,) [m] of the out lap's line, the largest distance [m] of the flying
        laps' line from it over ``HANDOVER_WINDOW_M`` either side of each (n,))."""
        out = self._out_lap[0].track
        _, e = self.built_line.track.project(out.xy)
        gap = np.abs(np.asarray(e, dtype=float))
        worst = gap.copy()
        for k in range(1, round(HANDOVER_WINDOW_M / out.spacing_m) + 1):  # (periodic)
            worst = np.maximum(worst, np.maximum(np.roll(gap, k), np.roll(gap, -k)))
        return np.asarray(out.s_m, dtype=float), worst

    def _cautious_start(self, s_line_m: float) -> None:
        """The cautious out lap (``[planner.raceline] start_speed_scale``): the speed scale
        held at the start's over ``start_hold_share`` of the line, then raised by
        ``start_rise_per_tick`` to 1; over for good once the grip adaptation cuts it (the
        car slid: the adaptation owns the scale from then on). With an out lap's line of its
        own (``_out_lap``) the car changes to the built line where the scale reaches 1."""
        if self._start_phase is None:
            return
        o = self.options
        length = self.raceline.track.length_m
        if self._start_phase == "hold":
            if self._start_travel_m >= o.start_hold_share * length:
                self._start_phase = "rise"
            return
        top = 1.0
        if o.start_probe_share > 0.0:  # no further above the grip shown than the probe
            top = min(top, (1.0 + o.start_probe_share)
                      * math.sqrt(self._grip_shown / self._line_grip_mps2))
        self.speed_scale = max(self.speed_scale,
                               min(top, self.speed_scale + o.start_rise_per_tick))
        if self.speed_scale >= 1.0:
            self._start_phase = None
            if self._out_lap is not None and self.raceline is self._out_lap[0]:
                # at the line's speeds: on the flying laps' line from the next tick
                self._follow(self.built_line, 1.0, self._built_slow_plans)

    def _show_grip(self, s_line_m: float) -> None:
        """The lateral acceleration [m/s^2] the car held on its line this tick, as the plan
        asks it at the tracker's scale, kept as the grip shown (``start_probe_share``)."""
        if self._on_line and self._yaw_ticks == 0:
            ref = self.raceline.reference
            v = self.tracker_scale * float(ref.at("v", s_line_m))
            shown = v * v * abs(float(ref.at("kappa", s_line_m)))
            self._grip_shown = max(self._grip_shown, shown)

    def _adapt_grip(self, e_line_m: float) -> None:
        """The grip adaptation: a tick with the car's CoG more than ``grip_error_m`` off the
        line (once it has reached the line since the start, the last recovery or the last
        manoeuvre around a car) cuts the speed scale by ``grip_step`` (down to
        ``grip_min_scale``); it never rises again in a run. A car that has the grip it is
        planned for stays within a few centimetres of its line and keeps the plan; one
        planned on another car's grip (the identified car raced on the gym car's line)
        slides wide in its first bends and settles at the speeds it can hold. Never for the
        gym's unbounded ``linear`` tyres: no grip to find, and on a line they cannot drive
        slower (``drivable_slower``) a lower scale does not bring the car back to it."""
        o = self.options
        if not self._on_line:  # joining it (the start, after a recovery or a pass) is no
            # slide
            self._on_line = abs(e_line_m) < 0.5 * o.grip_error_m
            return
        if self._unbounded_tyres:
            # the gym's unbounded tyres have no grip to find: a car off its line is the
            # tracker's error, not a slide, and a cut is for the whole run. Where their line
            # drifts through bends tighter than the lock turns the car, a lower scale even
            # turns the car at its lock's radius, wider still (gen-20 `linear`: one out-lap
            # event, then cut to 1.21-1.25 x the limit); on a line within the lock one cut
            # in the cautious out lap held gen-14 and Silverstone at 0.78 of their lines
            # (1.28-1.45 x the limit) once the line could use the car's whole lock. A
            # default car's line keeps the rule: there a slide is the grip it lacks (on the
            # identified car, without it gen-1003 spun)
            return
        limit = o.grip_error_m
        if self._start_phase is not None:  # the cautious out lap judges more closely
            limit = min(limit, o.start_grip_error_m)
        limit += self._speed_tube_m()
        if o.grip_error_m > 0.0 and abs(e_line_m) > limit:
            self.speed_scale = max(o.grip_min_scale, self.speed_scale * (1.0 - o.grip_step))
            self._start_phase = None  # the car slid: no cautious start to end

    def _speed_tube_m(self) -> float:
        """The line's high-speed tube at the car's planned speed [m]: the footprint margin
        its minimum-time lap keeps there beyond the low-speed one
        (``min_time_reserve_margin_m`` times the reserve's ramp at the plan's speed at the
        tracker's scale; 0 at and below ``min_time_reserve_speed_mps``, so nothing on a
        line capped there). A tracking error within it is what the line made room for,
        not a slide: at 7 m/s on a long bend the car held 0.15 m inside its line at the
        cautious start's scale, and the cut that ended the start left the whole race at
        0.78 of the line (gen-1001 at ``--v-max 10``)."""
        o = self.options
        lap = self.raceline.min_time
        if (lap is None or o.min_time_reserve_margin_m <= 0.0 or self._s_line is None
                or o.min_time_reserve_speed_mps is None
                or o.min_time_reserve_speed_mps >= lap.v_max_mps):
            return 0.0
        v = self.tracker_scale * float(self.raceline.reference.at("v", self._s_line))
        ramp = float(reserve_ramp(v, o.min_time_reserve_speed_mps, o.min_time_reserve_width_mps))
        return o.min_time_reserve_margin_m * ramp

    def _yaw_error(self, s_line_m: float) -> float | None:
        """How far the car's yaw rate over the last period was from its plan's at the car's
        own speed [rad/s] (from the last two poses; the plan's yaw per metre there, half a
        period back, times the distance the car went over the period: a car held below the
        line's speed turns slower too), either way (a rear letting go or a front pushing
        wide), less ``grip_yaw_error_share`` of the plan's (the tight bends a line drifts
        through are followed less exactly). None: no last pose, or the car on a join's
        path."""
        if self._yaw_rate is None or self._travel_mps is None or self._join is not None:
            return None
        ref = self.raceline.reference
        v = self._travel_mps
        s_mid = s_line_m - 0.5 * self.settings.dt_s * v
        per_m = float(ref.at("r", s_mid)) / max(float(ref.at("v", s_mid)), 0.1)
        r_plan = per_m * v
        return abs(self._yaw_rate - r_plan) - self.options.grip_yaw_error_share * abs(r_plan)

    def _adapt_grip_yaw(self, error: float | None) -> None:
        """The grip adaptation on the yaw rate: ``grip_yaw_ticks`` ticks in a row with the
        yaw rate more than ``grip_yaw_error_radps`` from the plan's (the car still on its
        line, its tyres not doing what the plan asks) cut the speed scale by ``grip_step``
        as a slide does."""
        o = self.options
        # (not for the gym's unbounded `linear` tyres: no grip peak to find, and their line
        # drifts through bends tighter than the lock turns the car, where a car a little
        # off the line's slip yaws very differently: held out, gen-7 and gen-20 were cut to
        # 1.15-1.46 x the limit; judged only near such bends, the same)
        if (o.grip_yaw_error_radps <= 0.0 or not self._on_line
                or self._unbounded_tyres):
            self._yaw_ticks = 0
            return
        if error is None or error <= o.grip_yaw_error_radps:
            self._yaw_ticks = 0
            return
        self._yaw_ticks += 1
        if self._yaw_ticks >= o.grip_yaw_ticks:
            self.speed_scale = max(o.grip_min_scale, self.speed_scale * (1.0 - o.grip_step))
            self._start_phase = None

    def _start_join(self, cx: float, cy: float, hint: float | None) -> LineJoin | None:
        """The join onto the line from the CoG (`cx`, `cy`) [m] (``raceline.join``), or
        None when the car is on the line already."""
        line = self.raceline.track
        s_l, e_l = self.tracker.project(cx, cy, hint)
        q = -np.asarray(self.raceline.offset_m, dtype=float)  # right + from the centreline
        e0 = e_l + float(np.interp(s_l, line.s_m, q, period=line.length_m))
        turn = self._turn_1pm
        # the blend's lateral speed is the same joining slowly (peaky tyres, JOIN_SPEED_MPS)
        # as at the line's top speed: a steeper, shorter blend (a long one at 2 m/s left
        # the identified car ramping up into map416's first bend)
        slope = MAX_JOIN_SLOPE
        if self._joining:
            slope *= self._top_speed_mps / JOIN_SPEED_MPS
            if self._slow_servo:  # (``SLOW_SERVO_JOIN_SHARE``)
                slope *= SLOW_SERVO_JOIN_SHARE
        return LineJoin.start(s_l, e0, line.s_m, q, line.length_m, max_slope=slope,
                              line_xy=self._line_points,
                              max_curvature_1pm=JOIN_STEER_SHARE * turn, turn_curvature_1pm=turn)

    def _line_points(self, s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The line's points (k, 2) [m] and right normals (k, 2) at stations `s` (k,) [m]."""
        line = self.raceline.track
        h = line.heading_at(s)
        return line.point_at(s), np.column_stack([np.sin(h), -np.cos(h)])

    def _join_feed(self, s_m: float) -> tuple[float, float]:
        """(steering [rad], speed cap [m/s]) of the join's blended path from line station
        `s_m` (``raceline.join``): the kinematic steering its curvature needs beyond the
        line's, ``JOIN_LEAD_M`` ahead (the command acts after the delays), and the speed
        at which its tightest curvature over the next ``JOIN_LOOK_M`` takes
        ``JOIN_GRIP_SHARE`` of the tyres' grip, at most the line's top speed. For the gym's
        unbounded ``linear`` tyres the curvature is what the path bends beyond the line
        (the line's own bends are driven at its speeds)."""
        join = self._join
        wheelbase = self.vehicle.lf_m + self.vehicle.lr_m
        stations = np.append(s_m + JOIN_LEAD_M, s_m + np.linspace(0.0, JOIN_LOOK_M, 6))
        kappa = join.path_curvatures(stations, self._line_points)  # the lead's, then ahead
        k_path = float(kappa[0])
        k_line = float(self.raceline.reference.at("kappa", s_m + JOIN_LEAD_M))
        steer = math.atan(wheelbase * k_path) - math.atan(wheelbase * k_line)
        k_max = float(np.max(np.abs(kappa[1:])))
        if self._unbounded_tyres:  # unbounded tyres hold the line's own
            # bends at its speeds (drifting through those tighter than the lock): only
            # what the blend bends beyond the line caps the speed. Capped by the line's
            # own curvature too, the car came into such a bend at 2.1 m/s against the
            # plan's 3-4 and ran wide (gen-20 `linear`'s out lap, 10 of 80 standing
            # starts on gen:1001-1008)
            k_line = np.abs(self.raceline.reference.at("kappa", stations[1:]))
            k_max = max(float(np.max(np.abs(kappa[1:]) - k_line)), 0.0)
        grip = JOIN_GRIP_SHARE * self.vehicle.mu * GRAVITY_MPS2
        cap = math.sqrt(grip / k_max) if k_max > 1e-6 else math.inf
        # no lead over the line's top speed: the car is not where the plan's clock expects
        # it, and the lead's 0.3-0.4 m/s took it past the cap
        cap = min(cap, self._top_speed_mps)
        full_gain = self.tracker.gains.k_lateral_speed_mps
        if full_gain is not None:  # ... nor above the tracker's full feedback
            cap = min(cap, full_gain)
        return steer, cap

    @cached_property
    def _top_speed_mps(self) -> float:
        """The line's top speed [m/s] (the cap it was planned at)."""
        return float(np.max(self.raceline.reference.v_mps))

    def _relocate(self) -> None:
        """Forget where the car was (a teleport, ``TELEPORT_JUMP_M``), keeping the counts."""
        self._s_line = self._s_track = None
        self.tracker.reset()
        self._stall.reset()
        self._handover.active = False
        self._drove = False
        self._speed_cmd = 0.0
        self.recovery.active = False
        self._join, self._join_pending = None, True

    def _project_track(self, x: float, y: float) -> tuple[float, float]:
        if self._s_track is None:
            s, e = self.track.project(np.array([x, y]))
            return float(s), float(e)
        return self.track.project_near(x, y, self._s_track)

    def _result(
        self,
        cmd: DriveCommand,
        x: float,
        y: float,
        yaw: float,
        s_line: float,
        s_track: float,
        e_track: float,
        text: str,
        t0: float,
        status: str = SOLVED,
    ) -> SolveResult:
        """The record of one tick: the preview is the raceline ahead at the profile speed."""
        if self.servo_lag is not None:
            self.servo_lag.commanded(cmd.steering_rad)
        N, dt = self.horizon, self.settings.dt_s
        line = self.raceline.track
        states = np.zeros((N + 1, 4))
        inputs = np.zeros((N, 3))
        if status == SOLVED:
            s_k = s_line
            s_prog = s_track
            states[0] = (x, y, yaw, s_track)
            s_all, v_all, prog = np.empty(N), np.empty(N), np.empty(N)
            for k in range(N):  # the profile's speed at each step (sequential)
                v = self.raceline.speed_at(s_k)
                s_k += v * dt
                s_prog += v * dt
                s_all[k], v_all[k], prog[k] = s_k, v, s_prog
            states[1:, :2] = line.point_at(s_all)  # the points, all at once
            states[1:, 2] = line.heading_at(s_all)
            states[1:, 3] = prog
            inputs[:, 0] = inputs[:, 2] = v_all
            inputs[0, 1] = cmd.steering_rad
        beta = np.full(N, float(self.profile.beta_at(s_track)))
        return SolveResult(
            command=cmd,
            states=states,
            inputs=inputs,
            status=status,
            solver_status=text,
            iterations=0,
            solve_time_s=self._timer() - t0,
            beta=beta,
            s_m=s_track,
            e_con_m=e_track,
            consecutive_failures=0 if status == SOLVED else 1,
            method=self.method,
        )
