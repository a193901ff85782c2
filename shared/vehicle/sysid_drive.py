"""The identification drive: a manoeuvre programme that records a car for ``identify``.

A functional core (no I/O, no clock): ``DriveProgramme.command(obs, state)`` is "given
what the car measures now and where it is on the track, what command next", returning a
new ``DriveState``. It follows the track's centreline (curvature feed-forward, heading and
lateral-error feedback) and runs three phases one after the other:

1. ``speed_steps``: steps of the speed command at a few levels, up and down, large and
   small (small downward steps keep the speed loop off its braking limit, so the braking
   gain shows), at a low lateral-acceleration cap in the bends: tells the speed-loop gains,
   its delay and the acceleration limit.
2. ``steering_steps``: at a low speed, steering steps and a sine sweep added to the
   tracker's steering (faded out as the lateral error grows): tells the steering delay,
   the servo's time constant and its rate limit.
3. ``cornering``: the tracker on the centreline with the speed of each bend set by a
   lateral-acceleration target that rises by a small step every bend; the ``Envelope``
   fits the linear steering response (``delta = L kappa + K a_y``, an understeer gradient
   ``K`` from the low-a_y samples) and, when the measured steering departs from it by more
   than ``saturation_rad`` for ``saturation_hold_s`` (front or rear tyres saturating: the
   grip it has seen), stops the target rising and sets it to ``margin`` times the a_y
   where it saw that; so does a lateral error in a bend beyond ``line_share`` of the
   room (the car cannot hold the line: ``margin`` times the largest a_y seen), and so does a
   target the car does not reach by ``ay_lead_mps2`` (at its grip or its lock). Only the
   rear's departure counts (less steering than linear: oversteer) unless
   ``front_departure``; a front's early softness is no stop, its end is one of the two
   others. Tells the tyres.

Safety, always: the speed of every bend is capped by the envelope (with a braking
distance before it at ``brake_mps2``), and the car brakes to ``v_safe_mps`` when its
lateral error passes the track's half-width less ``edge_margin_m``; steering
perturbations fade to 0 before that.

Units SI: m, s, rad, m/s, m/s^2.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

import numpy as np

from shared.track import Track

#: The phases, in order.
PHASES = ("speed_steps", "steering_steps", "cornering", "done")


@dataclass(frozen=True)
class DriveSettings:
    """The programme's knobs (defaults: a 1:10 car, a 3-minute drive).

    Attributes:
        speed_steps_s, steering_steps_s, cornering_s: duration of each phase [s].
        speed_levels_mps: the speed-step command levels, cycled [m/s].
        speed_step_hold_s: how long each level is held [s].
        steering_speed_mps: the speed of the steering phase [m/s].
        steering_step_rad: amplitude of the steering steps [rad].
        steering_step_hold_s: how long each step is held [s].
        ay_first_mps2: the lateral-acceleration cap of phases 1-2 and the cornering start.
        ay_step_mps2: how much the target rises each bend [m/s^2].
        ay_max_mps2: the target never exceeds this [m/s^2].
        brake_mps2: deceleration planned before a bend [m/s^2].
        accel_mps2: how fast the cornering phase's speed command rises [m/s^2].
        v_max_mps, v_safe_mps: top speed, and the speed it brakes to near the edge [m/s].
        edge_margin_m: the lateral error allowed is the half-width less this [m]
            (the car's half-width and a margin).
        preview_s: the tracker's curvature feed-forward looks this far ahead [s].
        heading_bandwidth_radps, lateral_gain_per_s: its feedback: the heading loop's
            crossover [rad/s] (gain ``bandwidth L / v``), the lateral error of the front
            axle as a heading reference ``atan(gain e / v)``.
        saturation_rad: departure from the linear steering response that counts [rad].
        saturation_hold_s: for how long it must last [s].
        linear_ay_mps2: samples below this |a_y| fit the linear response [m/s^2].
        margin: the target after saturation: this times the a_y where it was seen.
        line_share: a lateral error in a bend beyond this share of the room allowed
            counts as saturation too (the car cannot hold the line).
        front_departure: whether more steering than the linear response (the front
            saturating, understeer) counts as saturation too; by default only less
            steering (the rear saturating, oversteer: the spin) does. A front's early
            softness (a low B) turns the response nonlinear far below the peak and stopped
            the envelope there; an understeering car that runs out of grip or steering
            loses the line instead, which ``line_share`` catches.
        ay_lead_mps2: a target more than this above the largest |a_y| measured is not
            reached (the car at its grip or its steering lock): saturation, the target
            then ``margin`` times the largest |a_y| (``envelope_raise``).
        heading_step_rad: the speed steps go up only with the heading within this of the
            centreline's (not while the car drifts towards an edge out of a bend).
    """

    speed_steps_s: float = 50.0
    steering_steps_s: float = 35.0
    cornering_s: float = 95.0
    speed_levels_mps: tuple[float, ...] = (2.5, 2.2, 4.0, 3.7, 3.4, 1.5, 3.0, 2.8, 4.5,
                                           4.3, 2.0)
    speed_step_hold_s: float = 1.6
    steering_speed_mps: float = 2.0
    steering_step_rad: float = 0.18
    steering_step_hold_s: float = 0.5
    ay_first_mps2: float = 2.5
    ay_step_mps2: float = 0.25
    ay_max_mps2: float = 12.0
    brake_mps2: float = 2.5
    accel_mps2: float = 1.5
    v_max_mps: float = 4.5
    v_safe_mps: float = 1.0
    edge_margin_m: float = 0.3
    preview_s: float = 0.2
    heading_bandwidth_radps: float = 3.0
    lateral_gain_per_s: float = 1.5
    saturation_rad: float = 0.05
    saturation_hold_s: float = 0.3
    linear_ay_mps2: float = 3.0
    margin: float = 0.92
    line_share: float = 1.0
    front_departure: bool = False
    ay_lead_mps2: float = 0.5
    heading_step_rad: float = 0.08

    @property
    def duration_s(self) -> float:
        """The whole programme [s]."""
        return self.speed_steps_s + self.steering_steps_s + self.cornering_s


@dataclass(frozen=True)
class Observation:
    """What the car knows at one command tick.

    Attributes:
        t_s: time [s]. x_m, y_m, yaw_rad: CoG pose. s_m, e_m: arc length on the
        centreline and lateral error (positive right). v_mps: measured speed.
        steering_rad: measured steering angle. yaw_rate_radps, ay_mps2: the IMU's.
    """

    t_s: float
    x_m: float
    y_m: float
    yaw_rad: float
    s_m: float
    e_m: float
    v_mps: float
    steering_rad: float
    yaw_rate_radps: float
    ay_mps2: float


@dataclass(frozen=True)
class Envelope:
    """The lateral-acceleration envelope of the cornering phase.

    Attributes:
        ay_target_mps2: the bends' a_y now [m/s^2].
        ay_seen_mps2: the largest |a_y| measured in a bend so far [m/s^2].
        saturated: saturation was seen; the target no longer rises.
        ay_saturation_mps2: the |a_y| where it was seen (nan before).
        sxx, sxy, n: sums of the linear fit ``delta - L kappa = K a_y``.
        over_s: how long the departure has lasted [s].
        reason: why it saturated ("" before): "steering response", "lost the line" or
            "target not reached".
    """

    ay_target_mps2: float
    ay_seen_mps2: float = 0.0
    saturated: bool = False
    ay_saturation_mps2: float = math.nan
    sxx: float = 0.0
    sxy: float = 0.0
    n: int = 0
    over_s: float = 0.0
    reason: str = ""

    @property
    def understeer_rad_per_mps2(self) -> float:
        """The fitted understeer gradient K [rad/(m/s^2)] (0 before 20 samples)."""
        return self.sxy / self.sxx if self.n >= 20 and self.sxx > 0 else 0.0


def envelope_update(env: Envelope, wheelbase_m: float, v_mps: float, steering_rad: float,
                    yaw_rate_radps: float, ay_mps2: float, dt_s: float,
                    settings: DriveSettings) -> Envelope:
    """One sample of the envelope: fit the linear steering response on low-a_y samples,
    count how long the response departs from it at higher a_y, stop at saturation.

    The linear single-track response: ``delta = L kappa + K a_y`` with ``kappa = r / v``.
    A saturating front axle needs more steering than that (understeer), a saturating
    rear less (the car turns in by itself): either counts.
    """
    if v_mps < 0.8:
        return replace(env, over_s=0.0)
    kappa = yaw_rate_radps / v_mps
    y = steering_rad - wheelbase_m * kappa
    a = abs(ay_mps2)
    sign = 1.0 if ay_mps2 >= 0 else -1.0
    if a < settings.linear_ay_mps2 and a > 0.3:
        env = replace(env, sxx=env.sxx + ay_mps2 * ay_mps2, sxy=env.sxy + ay_mps2 * y,
                      n=env.n + 1)
    k = env.understeer_rad_per_mps2
    departure = sign * (y - k * ay_mps2)  # > 0: more steering than linear (front)
    counted = abs(departure) if settings.front_departure else -departure
    over = env.over_s + dt_s if (a >= settings.linear_ay_mps2 and env.n >= 20 and
                                 counted > settings.saturation_rad) else 0.0
    env = replace(env, over_s=over, ay_seen_mps2=max(env.ay_seen_mps2, a))
    if over >= settings.saturation_hold_s and not env.saturated:
        return replace(env, saturated=True, ay_saturation_mps2=a, reason="steering response",
                       ay_target_mps2=min(env.ay_target_mps2, settings.margin * a))
    return env


def envelope_lost_line(env: Envelope, settings: DriveSettings) -> Envelope:
    """The car cannot hold the line in a bend (its lateral error passed ``line_share`` of
    the room): saturation, at the largest |a_y| it has measured (the grip it has seen)."""
    if env.saturated:
        return env
    return replace(env, saturated=True, ay_saturation_mps2=env.ay_seen_mps2,
                   reason="lost the line",
                   ay_target_mps2=min(env.ay_target_mps2, settings.margin * env.ay_seen_mps2))


def envelope_raise(env: Envelope, settings: DriveSettings) -> Envelope:
    """The target after a bend: one step up, unless saturation was seen (then it stays).
    A target more than ``ay_lead_mps2`` above the largest |a_y| the car has given is
    saturation too ("target not reached": at its grip or its steering lock): the target
    then drops to ``margin`` times what it gave, short of the grip it has seen."""
    if env.saturated:
        return env
    seen = env.ay_seen_mps2
    if seen >= settings.linear_ay_mps2 and env.ay_target_mps2 > seen + settings.ay_lead_mps2:
        return replace(env, saturated=True, ay_saturation_mps2=seen,
                       ay_target_mps2=settings.margin * seen, reason="target not reached")
    return replace(env, ay_target_mps2=min(env.ay_target_mps2 + settings.ay_step_mps2,
                                           settings.ay_max_mps2))


def speed_profile(kappa: np.ndarray, ds_m: float, ay_mps2: float, v_max_mps: float,
                  brake_mps2: float) -> np.ndarray:
    """(n,) speed cap [m/s] along a closed centreline: ``sqrt(ay / |kappa|)`` at most
    `v_max_mps`, lowered before each bend so that `brake_mps2` reaches it (two laps of a
    backward pass, so the wrap is right)."""
    cap = np.minimum(v_max_mps, np.sqrt(ay_mps2 / np.maximum(np.abs(kappa), 1e-6)))
    out = cap.copy()
    n = len(out)
    two_a_ds = 2.0 * brake_mps2 * ds_m
    nxt = out[0]
    for j in range(2 * n - 1, -1, -1):
        i = j % n
        nxt = out[i] = min(out[i], math.sqrt(nxt * nxt + two_a_ds))
    return out


@dataclass(frozen=True)
class DriveState:
    """Where the programme is: phase, its start, the envelope, the bend it is in, the
    speed profile of the envelope's target (recomputed when the target changes)."""

    phase: str = PHASES[0]
    phase_t0_s: float = math.nan
    envelope: Envelope = field(default_factory=lambda: Envelope(0.0))
    in_bend: bool = False
    last_t_s: float = math.nan
    last_speed_mps: float = 0.0
    profile_ay_mps2: float = math.nan
    profile: np.ndarray | None = field(default=None, compare=False, repr=False)


@dataclass(frozen=True)
class Command:
    """The programme's command: speed [m/s] and steering [rad], and why."""

    speed_mps: float
    steering_rad: float
    phase: str
    near_edge: bool = False


class DriveProgramme:
    """The manoeuvre programme on one track for one car (module docstring).

    Args:
        track: the track (its centreline, half-widths and curvature).
        wheelbase_m: the car's wheelbase [m].
        steering_max_rad: the steering limit [rad].
        settings: the programme's knobs.
    """

    def __init__(self, track: Track, wheelbase_m: float, steering_max_rad: float,
                 settings: DriveSettings | None = None) -> None:
        self.track = track
        self.settings = settings or DriveSettings()
        self.wheelbase_m = float(wheelbase_m)
        self.steering_max_rad = float(steering_max_rad)
        k = track.signed_curvature()
        # smoothed over ~0.5 m: the bends as a car follows them
        w = max(1, round(0.5 / track.spacing_m))
        kern = np.ones(2 * w + 1) / (2 * w + 1)
        self.kappa = np.convolve(np.concatenate([k[-w:], k, k[:w]]), kern, mode="valid")
        self.half_width_m = np.minimum(track.w_left_m, track.w_right_m)
        self.bend_kappa = 0.25 * float(np.max(np.abs(self.kappa)))

    def start(self) -> DriveState:
        """The programme's first state."""
        return DriveState(envelope=Envelope(self.settings.ay_first_mps2))

    def _index(self, s_m: float) -> int:
        return int(np.searchsorted(self.track.s_m, s_m % self.track.length_m,
                                   side="right") - 1) % self.track.n_points

    def _profile(self, state: DriveState, ay: float) -> DriveState:
        if state.profile is not None and state.profile_ay_mps2 == ay:
            return state
        prof = speed_profile(self.kappa, self.track.spacing_m, ay, self.settings.v_max_mps,
                             self.settings.brake_mps2)
        return replace(state, profile=prof, profile_ay_mps2=ay)

    def tracker(self, obs: Observation, understeer: float = 0.0) -> float:
        """The centreline tracker [rad]: the curvature `preview_s` ahead (the servo's lag)
        as feed-forward, plus feedback on the heading error towards a heading that closes
        the front axle's lateral error."""
        st = self.settings
        v = max(obs.v_mps, 0.5)
        lf = 0.5 * self.wheelbase_m
        fx = obs.x_m + lf * math.cos(obs.yaw_rad)
        fy = obs.y_m + lf * math.sin(obs.yaw_rad)
        s_f, e_f = self.track.project_near(fx, fy, obs.s_m + lf)
        kappa = float(self.kappa[self._index(s_f + st.preview_s * v)])
        ff = math.atan(self.wheelbase_m * kappa) + understeer * v * v * kappa
        e_psi = obs.yaw_rad - float(self.track.heading_at(s_f))
        e_psi = math.atan2(math.sin(e_psi), math.cos(e_psi))
        # the heading loop's crossover at `heading_bandwidth_radps` whatever the speed (the
        # servo's lag leaves no margin above ~3 rad/s); the lateral loop slower, inside it
        gain = st.heading_bandwidth_radps * self.wheelbase_m / v
        return ff - gain * (e_psi - math.atan(st.lateral_gain_per_s * e_f / v))

    def command(self, obs: Observation, state: DriveState) -> tuple[Command, DriveState]:
        """The next command and state for the observation `obs`."""
        st = self.settings
        if math.isnan(state.phase_t0_s):
            state = replace(state, phase_t0_s=obs.t_s)
        dt = 0.0 if math.isnan(state.last_t_s) else max(obs.t_s - state.last_t_s, 0.0)
        state = replace(state, last_t_s=obs.t_s)
        ends = {"speed_steps": st.speed_steps_s, "steering_steps": st.steering_steps_s,
                "cornering": st.cornering_s}
        if state.phase in ends and obs.t_s - state.phase_t0_s >= ends[state.phase]:
            state = replace(state, phase=PHASES[PHASES.index(state.phase) + 1],
                            phase_t0_s=obs.t_s)
        t = obs.t_s - state.phase_t0_s
        i = self._index(obs.s_m)
        room = float(self.half_width_m[i]) - st.edge_margin_m  # lateral error allowed
        near_edge = abs(obs.e_m) > room
        fade = float(np.clip((room - abs(obs.e_m)) / max(0.7 * room, 1e-3), 0.0, 1.0))
        env = state.envelope
        steer = self.tracker(obs, env.understeer_rad_per_mps2)
        if state.phase == "cornering":
            env = envelope_update(env, self.wheelbase_m, obs.v_mps, obs.steering_rad,
                                  obs.yaw_rate_radps, obs.ay_mps2, dt, st)
            bend = abs(self.kappa[i]) > self.bend_kappa
            if (bend and abs(obs.e_m) > st.line_share * room and t > 5.0
                    and abs(obs.ay_mps2) >= st.linear_ay_mps2):
                env = envelope_lost_line(env, st)
            if state.in_bend and not bend:  # a bend done: the next one a step faster
                env = envelope_raise(env, st)
            state = replace(state, in_bend=bend)
        state = replace(state, envelope=env)
        ay = env.ay_target_mps2 if state.phase == "cornering" else st.ay_first_mps2
        state = self._profile(state, ay)
        assert state.profile is not None
        ahead = self._index(obs.s_m + max(0.3, 0.1 * obs.v_mps))
        cap = float(min(state.profile[i], state.profile[ahead]))
        if state.phase == "speed_steps":
            k = int(t / st.speed_step_hold_s) % len(st.speed_levels_mps)
            speed = min(st.speed_levels_mps[k], cap)
            turning = abs(self.kappa[i]) > self.bend_kappa or abs(obs.yaw_rate_radps) > 0.5
            turning = turning or abs(obs.e_m) > 0.5 * room  # or off the line: no step up
            e_psi = obs.yaw_rad - float(self.track.heading_at(obs.s_m))
            e_psi = math.atan2(math.sin(e_psi), math.cos(e_psi))
            # or heading off the line (drifting towards an edge): no step up either
            turning = turning or abs(e_psi) > st.heading_step_rad
            if turning:  # steps up on the straights only (no power oversteer)
                speed = min(speed, max(state.last_speed_mps, obs.v_mps) + st.accel_mps2 * dt)
        elif state.phase == "steering_steps":
            speed = min(st.steering_speed_mps, cap)
            k = int(t / st.steering_step_hold_s)
            square = st.steering_step_rad * (1.0 if k % 2 == 0 else -1.0) * (
                1.0 if (k // 2) % 3 else 0.5)
            sweep = 0.6 * st.steering_step_rad * math.sin(
                2 * math.pi * (0.3 + 0.05 * t) * t)
            steer += fade * (square if (k // 8) % 2 == 0 else sweep)
        elif state.phase == "cornering":  # out of a bend: a gentle rise (no power oversteer)
            speed = min(cap, max(state.last_speed_mps, obs.v_mps) + st.accel_mps2 * dt)
        else:  # done: roll to a stop on the centreline
            speed = 0.0
        if near_edge:  # brake, but not so hard that the tyres lock or the car spins
            speed = min(speed, max(st.v_safe_mps, 0.8 * obs.v_mps))
        steer = float(np.clip(steer, -self.steering_max_rad, self.steering_max_rad))
        state = replace(state, last_speed_mps=float(speed))
        return Command(float(speed), steer, state.phase, near_edge), state
