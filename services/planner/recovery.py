"""Getting back on the track after a spin or a slide: a safety rule outside the optimisation.

A kinematic MPC has no notion of a car that has spun round or slid a metre off the track:
from there it asks for reverse at full speed or its solver fails, and the car stops where
it is. Every method (cimpcc, mpcc, raceline) therefore hands over to this rule while the
car is lost, and takes over again, from a cold start, once the car is back:

- enter when the rear axle is more than ``enter_outside_m`` outside the boundaries, when
  the car's heading differs from the track's by more than ``enter_heading_rad``, or when
  the method has held the car still for ``stall_s`` (a car across the track is a local
  minimum of a contouring cost). "The track's heading" is the projection's, except on the
  inside of a bend, where it is the centreline's nearest the car's within ``|e_con|`` of
  arc either side (``track_heading_error``): in a hairpin whose centreline radius is near
  the half-width (YasMarina, 0.85 m against 1.1 m) a car cutting the apex passes near the
  bend's centre, where the projection's heading lagged the car's by 69 degrees while it
  raced cleanly (2 recoveries a run there before);
- drive forwards at ``speed_mps`` along a guidance field: the wanted heading is the
  track's turned towards the centreline by the offset, ``psi_w = psi_track(s) +
  atan(k_e e_con)`` (``GUIDANCE_GAIN_PER_M``; ``e_con > 0`` right of the centreline), and the
  steering ``delta = clip(k_psi wrap(psi_w - psi))`` (``STEER_GAIN``). A field has no target
  point the car could circle round for ever: from any pose it turns (a car facing backwards
  makes a U-turn at full lock), heads for the centreline and lines up with it;
- leave when the car is inside the boundaries by ``exit_inside_m`` and its heading is
  within ``exit_heading_rad`` of the track's.

While it acts, the rule keeps its own projection, anchored where the car left: each tick it
searches only a window of twice the distance the car moved (at least ``ANCHOR_MIN_M``, at
most ``ANCHOR_WINDOW_M``) around its last arc length, so the anchor follows the car along
its stretch of track and cannot jump to another. Where the track folds back, a car that
slid across the infield is brought back to where it left, as a marshal would have it,
instead of being raced on from another stretch. The method then resumes from that arc
length (``s_m``).

With the default car on its default tracks the rule never acts (no method leaves the
track), so it changes none of the paper's figures; it lets a car whose grip the planner
overestimates (the identified real car) finish its laps, each excursion counted.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from shared.angles import wrap_angle
from shared.config.planner import RecoverySettings
from shared.config.vehicle import DynamicVehicleParams
from shared.track import Track
from shared.vehicle import GRAVITY_MPS2, axle_peak_friction

#: k_e [rad/m] of the guidance field: how steeply the wanted heading points at the line.
GUIDANCE_GAIN_PER_M = 2.0
#: k_psi [rad of steering per rad of heading error].
STEER_GAIN = 1.0
#: Largest and smallest half-width [m] of the anchored projection's search window.
ANCHOR_WINDOW_M = 1.0
ANCHOR_MIN_M = 0.05
#: At most this many samples [-] either side of the projection for the track's heading
#: beside the car (``track_heading_error``).
HEADING_SAMPLES_MAX = 200


@dataclass(frozen=True, slots=True)
class RecoveryCommand:
    """What the rule commands: speed [m/s], steering [rad], and why it is active."""

    speed_mps: float
    steering_rad: float
    reason: str


def track_heading_error(track: Track, yaw_rad: float, s_m: float, e_con_m: float) -> float:
    """|yaw - the track's heading beside the car| [rad] (the module docstring).

    On the inside of a bend (``e_con`` on the side the centreline turns to over ``|e_con|``
    of arc either side of `s_m` [m]) the smallest difference to the centreline's headings
    over that arc: there the car nears the bend's centre, where the nearest point's heading
    says little about the car's (any chord through a point that near the centre is a line
    a car may race). Elsewhere (a straight, the outside of a bend, the line itself) the
    projection's own heading, where it is well defined.
    """
    own = abs(wrap_angle(yaw_rad - float(track.heading_at(s_m))))
    reach = abs(float(e_con_m))
    if reach == 0.0:
        return own
    spacing = track.length_m / track.n_points  # the mean segment: samples at a quarter
    k = min(math.ceil(4.0 * reach / spacing), HEADING_SAMPLES_MAX)
    heading = track.heading_at(s_m + np.linspace(-reach, reach, 2 * k + 1))
    turn = np.unwrap(heading)
    turn = float(turn[-1] - turn[0])  # > 0: the centreline turns left over the arc
    if turn * e_con_m >= 0.0:  # e > 0 is right of the line: left of a left turn is inside
        return own
    d = np.abs((yaw_rad - heading + math.pi) % (2.0 * math.pi) - math.pi)
    return min(own, float(d.min()))


class Recovery:
    """The enter / drive / leave rule (see the module docstring); pure, no I/O.

    Args:
        track: the track.
        settings: thresholds, speed and look-ahead.
        wheelbase_m: the planner's wheelbase L [m].
        steering_limit_rad: the largest steering command [rad] (> 0).
    """

    def __init__(
        self,
        track: Track,
        settings: RecoverySettings,
        wheelbase_m: float,
        steering_limit_rad: float,
    ) -> None:
        self.track = track
        self.settings = settings
        self.wheelbase_m = float(wheelbase_m)
        self.steering_limit_rad = float(steering_limit_rad)
        self.active = False
        #: times the rule took over since the last reset
        self.episodes = 0
        #: the anchored arc length [m] while recovering (and where it left off)
        self.s_m = 0.0
        self._xy = (0.0, 0.0)

    def reset(self) -> None:
        """Back to racing (e.g. a new run)."""
        self.active = False
        self.episodes = 0

    def update(
        self,
        x_m: float,
        y_m: float,
        yaw_rad: float,
        s_m: float,
        e_con_m: float,
        stalled_s: float = 0.0,
    ) -> RecoveryCommand | None:
        """The command while the car is lost, or None while the method should drive.

        Args:
            x_m, y_m, yaw_rad: the car's rear-axle pose [m, m, rad].
            s_m, e_con_m: its projection on the centreline: progress [m] and contour error
                [m] (positive right of the centreline).
            stalled_s: how long the method has commanded (almost) no speed [s].
        """
        cfg = self.settings
        if not cfg.enabled:
            return None
        if self.active:  # anchored: continue from where the car left
            moved = math.hypot(x_m - self._xy[0], y_m - self._xy[1])
            window = min(max(2.0 * moved, ANCHOR_MIN_M), ANCHOR_WINDOW_M)
            s, e = self.track.project(np.array([x_m, y_m]), s_hint=self.s_m, window_m=window)
            s_m, e_con_m = float(s), float(e)
        self.s_m = s_m
        self._xy = (x_m, y_m)
        w_r, w_l = (float(v) for v in self.track.interp_width(s_m))
        outside = max(e_con_m - w_r, -e_con_m - w_l)  # > 0 outside the boundaries [m]
        heading = float(self.track.heading_at(s_m))
        heading_err = abs(wrap_angle(yaw_rad - heading))  # the projection's own
        if self.active or heading_err > cfg.enter_heading_rad:
            # the arc's search only lowers it: needed where it could decide (the exit
            # test, or an entry the own heading would make); 80 us a tick otherwise
            heading_err = track_heading_error(self.track, yaw_rad, s_m, e_con_m)
        if not self.active:
            if outside > cfg.enter_outside_m:
                self._enter()
                reason = f"{outside:.2f} m outside the track"
            elif heading_err > cfg.enter_heading_rad:
                self._enter()
                reason = f"heading {math.degrees(heading_err):.0f} deg off the track's"
            elif stalled_s > cfg.stall_s:
                self._enter()
                reason = f"held still for {stalled_s:.1f} s"
            else:
                return None
        elif outside < -cfg.exit_inside_m and heading_err < cfg.exit_heading_rad:
            self.active = False
            return None
        else:
            reason = "returning to the track"
        # guidance field: head along the track, turned towards the centreline by the offset
        wanted = heading + math.atan(GUIDANCE_GAIN_PER_M * e_con_m)  # e > 0: right of it
        err = wrap_angle(wanted - yaw_rad)
        lim = self.steering_limit_rad
        steer = min(max(STEER_GAIN * err, -lim), lim)
        return RecoveryCommand(cfg.speed_mps, steer, reason)

    def _enter(self) -> None:
        self.active = True
        self.episodes += 1



#: A pose this far [m] from the last one is a teleport (a reset, a car placed back by hand,
#: a relocalisation), not a move: no car covers it in a planner tick. The planner then
#: forgets where the car was and starts cold from a search of the whole track.
TELEPORT_JUMP_M = 1.5

#: The car counts as held still while it stays within this distance [m] of where it stood
#: (larger than the pose noise and than a car rocking between small commands, smaller than
#: one planner tick at racing speed).
STILL_RADIUS_M = 0.25


class StallWatch:
    """How long the car itself has stood still under a method's commands [s].

    Judged by the car's poses, not by the commands: a method that alternates small forward
    and backward commands holds the car still as surely as one that commands nothing. The
    car stands still while it stays within ``STILL_RADIUS_M`` of an anchor; leaving that
    circle moves the anchor to the car and restarts the count. Only ticks the method drove
    count (``update(..., counts=False)`` keeps the count, e.g. a braking or failed tick).
    """

    def __init__(self) -> None:
        self.reset()

    def reset(self) -> None:
        """Forget the anchor and the count."""
        self._anchor: tuple[float, float] | None = None
        self.stalled_s = 0.0

    def update(self, x_m: float, y_m: float, dt_s: float, counts: bool = True) -> float:
        """The car's rear axle at (x, y) [m] after a tick of `dt_s` [s]; returns how long
        it has stood still [s]."""
        if self._anchor is None or math.hypot(
            x_m - self._anchor[0], y_m - self._anchor[1]
        ) > STILL_RADIUS_M:
            self._anchor = (x_m, y_m)
            self.stalled_s = 0.0
        elif counts:
            self.stalled_s += dt_s
        return self.stalled_s


#: Tyres whose force falls past the peak (Pacejka): the hand-over's ramp leaves this share of
#: the friction circle to the longitudinal force, the rest (0.71 of it) to steering.
PEAKY_TYRES_ACCEL_SHARE = 0.7


def handover_accel_mps2(vehicle: DynamicVehicleParams) -> float:
    """The hand-over's ramp rate [m/s^2] for `vehicle`: its acceleration limit ``a_max``; with
    tyres whose force falls past the peak (Pacejka: the identified car's rear spins when
    a full-throttle start takes its whole friction ellipse, issue #21) at most
    ``PEAKY_TYRES_ACCEL_SHARE`` of the friction circle ``min_i mu_i g``."""
    if vehicle.tyre_model != "pacejka":
        return vehicle.accel_max_mps2
    circle = min(axle_peak_friction(vehicle, "front"), axle_peak_friction(vehicle, "rear"))
    return min(vehicle.accel_max_mps2, PEAKY_TYRES_ACCEL_SHARE * circle * GRAVITY_MPS2)


def ramps_from_rest(vehicle: DynamicVehicleParams) -> bool:
    """Whether a near-limit planner starts with the hand-over's ramp from rest: for tyres
    whose force falls past the peak (``handover_accel_mps2``); the gym car's start is as it
    was."""
    return vehicle.tyre_model == "pacejka"


class HandOver:
    """The speed ramp from the recovery rule back to the method.

    After the rule hands the car back, the method starts cold and may ask for its racing
    speed at once (5-8 m/s from the rule's 1 m/s spins a car in a bend). Until its command is
    within reach, each tick's speed command is capped at the last one plus what the car can
    gain in a tick, ``a_max dt`` (its acceleration limit): the method takes over at the car's
    speed and ramps up as the car can.

    Args:
        accel_mps2: the car's acceleration limit a_max [m/s^2].
    """

    def __init__(self, accel_mps2: float) -> None:
        self.accel_mps2 = float(accel_mps2)
        self.active = False
        self._last = 0.0

    def start(self, speed_mps: float) -> None:
        """The rule hands over with the car at (about) `speed_mps` [m/s]."""
        self.active = True
        self._last = abs(float(speed_mps))

    def cap(self, speed_mps: float, dt_s: float) -> float:
        """The method's speed command [m/s], capped while handing over (same sign)."""
        if not self.active:
            return speed_mps
        reach = self._last + self.accel_mps2 * dt_s
        if abs(speed_mps) <= reach:
            self.active = False
            return speed_mps
        self._last = reach
        return math.copysign(reach, speed_mps)
