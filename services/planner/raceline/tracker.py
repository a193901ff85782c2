"""Feed-forward + feedback tracking of a planned lap at the grip limit. Pure maths, no I/O.

One tracker for every planned lap the stack drives: the raceline planner's line
(``services.planner.raceline.planner``) at the planner's 20 Hz, and the replay of the minimum-time
lap (``services.tools.bench.replay``) at 200 Hz. The plan is a ``ReferenceLap``: periodic tables
over the arc length ``s`` of the planned CoG path of position, yaw ``psi_p``, path
curvature ``kappa_p``, speed ``v_p``, the acceleration demand ``a_p`` of the car's speed
loop, the feed-forward steering ``delta_p`` and the plan's clock ``t_p``.

Timing (``TrackerTiming``). A command computed from the pose at time ``t`` is held for the
control period ``T``; it reaches the speed loop after ``d_v`` (compute + actuation delay)
and the road wheels after ``d_d`` (compute + actuation + steering delay + the servo's time
constant). So the speed command acts over the plan's window ``W_v = [t_p(s) + d_v,
t_p(s) + d_v + T]`` and the steering over ``W_d = [t_p(s) + d_d, t_p(s) + d_d + T]``;
``<f>_W`` below is the mean of ``f`` over the plan's positions in ``W`` (``WINDOW_SAMPLE_S``
apart, at least one: the middle).

The law, with ``(s, e)`` the CoG projected onto the planned path (``e`` right +) and
``dpsi = wrap(psi - psi_p(s))``::

    l_d     = clip(l_0 + T_l v_p(s), l_min, l_max)               (speed-dependent look-ahead)
    e_la    = e - l_d sin(dpsi)                  (lateral error of the point l_d ahead)
    delta   = <delta_p>_W_d + k_e(v_p) e_la                                  [rad]
    e_out   = max(0, e tanh(kappa_p(s) / KAPPA_OUTWARD_1PM))    (drift to the outside)
    a_cmd   = <a_p>_W_v - k_out e_out                                        [m/s^2]
    a_cmd  -> max(a_cmd, min(<a_p>_W_v, 0))    (above outward_drive_only_speed_mps v_o,
                                                faded in over OUTWARD_RAMP_MPS above it)
    v_cmd   = <v_p>_W_v + a_cmd / k,   k = k_accel if a_cmd >= 0 else k_brake   [m/s]

The car's speed loop is proportional, ``a = k (v_cmd - v)`` (``speed_gain_accel_per_s``
4.755 / ``speed_gain_brake_per_s`` 19.02 1/s), so ``v_cmd`` gives ``a = a_cmd + k (v_p -
v)``: the planned acceleration fed forward, the speed error fed back at the loop's own
gain (no speed measurement needed). Full acceleration (9.51 m/s^2) asks for a command 2 m/s
above the plan. The outward cut matters at the limit: through most corners of a
minimum-time lap the front axle is at its friction ellipse (and the steering at its end
stop in the tightest), so more steering buys no lateral force there; only giving up
longitudinal force does.

Feed-forward steering ``delta_p``: the minimum-time lap's own steering (the optimum of the
car's single-track model, ``ReferenceLap.from_min_time``), or for a path with a speed
profile (``ReferenceLap.from_path``, ``steady_state_steering``) the steady-state linear
single-track model at the planned speed, with the axle loads of the acceleration demand
(``h`` the CoG height; per unit mass, the moment balance puts ``l_r / L`` of ``a_y`` on the
front axle)::

    f_zf = (g l_r - a_p h) / L,        f_zr = (g l_f + a_p h) / L
    alpha_f = a_y l_r / (L mu C_Sf f_zf),   alpha_r = a_y l_f / (L mu C_Sr f_zr)
    delta_p = atan(L kappa_p) + alpha_f - alpha_r          (kinematic + understeer)
    beta_p  = atan(l_r kappa_p) - alpha_r,                 psi_p = chi_p - beta_p

with ``a_y = v_p^2 kappa_p``, ``chi_p`` the path's course and ``C_Si`` the cornering
stiffness per unit load (``F_yi = mu C_Si F_zi alpha_i``, the gym's tyres); for equal loads
``delta_p = atan(L kappa_p) + K_us a_y``, ``K_us = (1 / C_Sf - 1 / C_Sr) / (mu g)``. A car on
Pacejka tyres takes each ``alpha_i`` from its magic formula instead (``steady_state_steering``
with ``tyre_law``: more slip near the peak than the linear law, whose shortfall the slower
plans used to keep as "dynamic" steering and cut inside with). The
acceleration demand is what the speed loop must give for the profile's ``dv/dt = v_p
dv_p/ds`` against the drag of the steered front tyre (``F_yf sin delta``, ``F_yf = m a_y
l_r / (L cos delta)``) and of the slip (the body's force balance along the velocity)::

    a_p = (dv/dt) cos(beta_p) - a_y sin(beta_p) + a_y (l_r / L) tan(delta_p)

(about 1.7 m/s^2 at 9 m/s^2 of lateral acceleration: without it the car runs 0.3 m/s slow
on a limit circle); loads and demand are solved together by fixed-point iteration.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from functools import cached_property

import numpy as np

from services.planner.mintime.model import DELTA
from services.planner.mintime.ocp import MinTimeLap
from services.planner.raceline.jobs import Job, run_job
from shared.angles import wrap_angle
from shared.config.vehicle import DynamicVehicleParams
from shared.track import Track
from shared.vehicle.steady_state import steady_state_steering

#: Path curvature [1/m] above which a bend's outside is fully defined (tanh scale).
KAPPA_OUTWARD_1PM = 0.1
#: Spacing of the samples of a hold window [s].
WINDOW_SAMPLE_S = 0.01
#: Half-step [s] of the central difference of the planned steering's rate (servo lag).
LAG_RATE_STEP_S = 0.01
#: The outward cut's drive-only rule (``TrackerGains.outward_drive_only_speed_mps``) fades in
#: over this much planned speed [m/s] above its speed: a line capped at that speed (within
#: IPOPT's bound tolerance, ~1e-8 relative) is driven as before.
OUTWARD_RAMP_MPS = 1.0
#: A slower plan (``ReferenceLap.slower``) keeps the plan's dynamic steering and yaw times
#: this power of its speed share (first tuned at 0.85-0.95 on map416, paperlike,
#: gen:1001-1003: 4; with the steady state on the car's own tyre law and the plan picked by
#: the speed asked of the car, races held at 0.8 and 0.9 of the line on the generator's
#: TUNING_SEEDS kept the default and the identified car nearest their lines at 6: their worst
#: loss of clearance to the line's 1.9 / 0.9 / 3.9 / 1.3 cm at 4, 1.5 / 1.2 / 3.7 / 1.3 at 6,
#: 1.3 / 1.6 / 3.6 / 1.5 at 8, default 0.8 / 0.9 then identified 0.8 / 0.9).
DYNAMIC_SHARE_EXPONENT = 6.0


#: The work [node steps] a job's slice of whole-array numpy calls announces at least: a
#: dozen calls cost 75-280 us of CPU however short the line (on a machine where a Python
#: node step of the profile's passes costs 0.7-1.2 us; ``raceline.jobs``).
ARRAY_SLICE_WORK = 200


@dataclass(frozen=True, eq=False)
class ReferenceLap:
    """A planned closed lap as periodic tables over the arc length of its CoG path.

    Node arrays have shape (n,); node k is at ``s_m[k]`` (``s_m[0] = 0``, increasing, below
    ``line.length_m``).

    Attributes:
        line: the planned CoG path as a ``Track`` (for projection; its widths are not used
            here).
        s_m: arc length of the nodes along ``line`` [m].
        yaw_rad: planned car yaw [rad], unwrapped along the lap.
        kappa_1pm: curvature of the path [1/m] (left +).
        v_mps: planned speed [m/s].
        a_mps2: acceleration demand of the speed loop [m/s^2] (acting from node k on).
        delta_rad: feed-forward steering (road-wheel angle) [rad].
        t_s: plan time at the nodes [s] (``t_s[0] = 0``).
        lap_time_s: the plan's lap time [s].
    """

    line: Track
    s_m: np.ndarray
    yaw_rad: np.ndarray
    kappa_1pm: np.ndarray
    v_mps: np.ndarray
    a_mps2: np.ndarray
    delta_rad: np.ndarray
    t_s: np.ndarray
    lap_time_s: float

    def __post_init__(self) -> None:
        n = len(self.s_m)
        for name in ("yaw_rad", "kappa_1pm", "v_mps", "a_mps2", "delta_rad", "t_s"):
            if np.shape(getattr(self, name)) != (n,):
                raise ValueError(f"{name} must have shape ({n},)")
        if not (self.lap_time_s > 0.0 and np.all(np.diff(self.t_s) > 0.0)):
            raise ValueError("the plan's clock must increase")

    @property
    def length_m(self) -> float:
        """Length of the planned path [m]."""
        return self.line.length_m

    @cached_property
    def _closed(self) -> dict[str, np.ndarray]:
        """Each table with its first value repeated at ``s = L`` (yaw: one turn on)."""
        yaw = np.asarray(self.yaw_rad, dtype=float)
        closing = yaw[-1] + wrap_angle(yaw[0] - yaw[-1])
        tables = {
            "s": np.append(self.s_m, self.length_m),
            "yaw": np.append(yaw, closing),
            "t": np.append(self.t_s, self.lap_time_s),
        }
        for name, arr in (("kappa", self.kappa_1pm), ("v", self.v_mps), ("delta", self.delta_rad)):
            tables[name] = np.append(arr, arr[0])
        # the yaw rate d(psi_p)/dt: each segment's, at a node the mean of its two segments
        seg = np.diff(tables["yaw"]) / np.diff(tables["t"])
        node = 0.5 * (seg + np.roll(seg, 1))
        tables["r"] = np.append(node, node[0])
        return tables

    def at(self, name: str, s_m: float | np.ndarray) -> float | np.ndarray:
        """Table `name` ("yaw", "kappa", "v", "delta", "t", "r": the yaw rate [rad/s])
        linearly interpolated at arc
        length(s) `s_m` [m] (periodic; "yaw" in the unwrapped lap's range, "t" in [0, T))."""
        c = self._closed
        out = np.interp(np.mod(s_m, self.length_m), c["s"], c[name])
        return float(out) if np.ndim(out) == 0 else out

    def accel_at(self, s_m: float | np.ndarray) -> float | np.ndarray:
        """Acceleration demand [m/s^2] at `s_m` (piecewise constant: node k's from s_k on)."""
        idx = np.searchsorted(self.s_m, np.mod(s_m, self.length_m), side="right") - 1
        out = self.a_mps2[np.clip(idx, 0, len(self.s_m) - 1)]
        return float(out) if np.ndim(out) == 0 else out

    def s_at_time(self, t_s: float | np.ndarray) -> float | np.ndarray:
        """Arc length [m] the plan reaches at plan time `t_s` [s] (periodic, unwrapped:
        one lap later is ``L`` further)."""
        c = self._closed
        laps = np.floor_divide(t_s, self.lap_time_s)
        out = np.interp(np.mod(t_s, self.lap_time_s), c["t"], c["s"]) + laps * self.length_m
        return float(out) if np.ndim(out) == 0 else out

    # ------------------------------------------------------------------ constructors
    @classmethod
    def from_min_time(cls, lap: MinTimeLap, line: Track | None = None) -> ReferenceLap:
        """The minimum-time lap: its CoG path, yaw, speed, acceleration demand (the OCP's
        input) and steering (the OCP's state), on its own clock.

        Args:
            lap: the lap (``services.planner.mintime.ocp``).
            line: the lap's CoG path as a ``Track`` (points ``(lap.x_m, lap.y_m)``), when
                the caller has one with real widths; None builds one.
        """
        xy = np.column_stack([lap.x_m, lap.y_m])
        if line is None:
            line = Track("min-time line", xy, np.ones(len(xy)), np.ones(len(xy)))
        if line.n_points != len(xy) or not np.allclose(line.xy, xy):
            raise ValueError("line must be the lap's CoG path")
        return cls(
            line=line,
            s_m=np.asarray(line.s_m, dtype=float),
            yaw_rad=np.asarray(lap.yaw_rad, dtype=float),
            kappa_1pm=np.asarray(lap.kappa_radpm, dtype=float),
            v_mps=np.asarray(lap.v_mps, dtype=float),
            a_mps2=np.asarray(lap.inputs[:, 1], dtype=float),
            delta_rad=np.asarray(lap.states[:, DELTA], dtype=float),
            t_s=np.asarray(lap.t_s, dtype=float),
            lap_time_s=float(lap.lap_time_s),
        )

    @classmethod
    def from_path(
        cls,
        line: Track,
        kappa_1pm: np.ndarray,
        v_mps: np.ndarray,
        vehicle: DynamicVehicleParams,
    ) -> ReferenceLap:
        """A path with a speed profile, steered by the steady-state single-track model
        (module docstring); ``dv/dt`` from the profile, ``(v_(k+1)^2 - v_k^2) / (2 ds_k)``.

        Args:
            line: the CoG path (its points are the nodes).
            kappa_1pm: (n,) path curvature at the nodes [1/m] (left +).
            v_mps: (n,) planned speed at the nodes [m/s], positive.
            vehicle: the car (wheelbase, l_r, cornering stiffnesses, mu).
        """
        return run_job(cls.from_path_job(line, kappa_1pm, v_mps, vehicle))

    @classmethod
    def from_path_job(
        cls,
        line: Track,
        kappa_1pm: np.ndarray,
        v_mps: np.ndarray,
        vehicle: DynamicVehicleParams,
        chunk: int | None = None,
    ) -> Job[ReferenceLap]:
        """``from_path`` as a job (``raceline.jobs``; arguments as there): the steady-state
        steering `chunk` nodes a slice (None: all at once), the set-up and the closing
        sums a slice each, of n / 4 node steps or ``ARRAY_SLICE_WORK``, whichever is more."""
        v = np.asarray(v_mps, dtype=float)
        kappa = np.asarray(kappa_1pm, dtype=float)
        if np.any(v <= 0.0):
            raise ValueError("planned speeds must be positive")
        n = len(v)
        yield max(n // 4, ARRAY_SLICE_WORK)
        seg = np.hypot(*(np.roll(line.xy, -1, axis=0) - line.xy).T)
        v_dot = (np.roll(v, -1) ** 2 - v**2) / (2.0 * seg)
        dt = 2.0 * seg / (v + np.roll(v, -1))
        if chunk is None or chunk >= n:
            yield n
            delta, beta, accel = steady_state_steering(kappa, v, v_dot, vehicle,
                                                       tyre_law=True)
        else:
            delta, beta, accel = np.empty(n), np.empty(n), np.empty(n)
            for start in range(0, n, chunk):
                part = slice(start, min(start + chunk, n))
                yield part.stop - start
                delta[part], beta[part], accel[part] = steady_state_steering(
                    kappa[part], v[part], v_dot[part], vehicle, tyre_law=True)
        yield max(n // 4, ARRAY_SLICE_WORK)
        tangent = line.tangent_unit()
        course = np.unwrap(np.arctan2(tangent[:, 1], tangent[:, 0]))
        return cls(
            line=line,
            s_m=np.asarray(line.s_m, dtype=float),
            yaw_rad=course - beta,
            kappa_1pm=kappa,
            v_mps=v,
            a_mps2=accel,
            delta_rad=delta,
            t_s=np.concatenate([[0.0], np.cumsum(dt)[:-1]]),
            lap_time_s=float(dt.sum()),
        )

    def slower(
        self,
        share: float | np.ndarray,
        vehicle: DynamicVehicleParams,
        steady: ReferenceLap | None = None,
    ) -> ReferenceLap:
        """This plan's path at `share` (0, 1] of its speeds (one share, or one per node,
        (n,): a profile re-planned for less grip, ``raceline.grip_profile``): ``from_path``
        at ``share v``
        (the steady-state steering, slip and acceleration demand there) plus the plan's
        own dynamic part scaled by ``share ** DYNAMIC_SHARE_EXPONENT``.

        The dynamic part is what the plan (a minimum-time lap) steers and yaws beyond the
        steady state at its own speeds, ``delta_p - delta_ss(v)`` and ``psi_p -
        psi_ss(v)`` (wrapped): the yaw acceleration of a bend's entry and exit, the load
        transfer. Without it the car ran wide or clipped apexes at 0.85-0.95 of the
        speeds (map416's apex at s = 17.5 m every lap at 0.95, gen-1003 at 0.9). It
        grows with the lateral acceleration's rate, so it fades fast below the plan's
        speed: at ``share ** 2`` the car left the track at 0.85 on map416 and gen-1003,
        at ``share ** 4`` on none of five tracks at 0.85, 0.9 or 0.95
        (``DYNAMIC_SHARE_EXPONENT``: 6 since the steady state follows the car's tyres).

        Args:
            share: the speed share, 0 < share <= 1 (1: this plan), or (n,) one per node.
            vehicle: the car ``from_path`` steers.
            steady: ``from_path`` of this plan's path at its own speeds for `vehicle`, when
                the caller has it (None: made here; ``grip_profile.GripReplan`` reuses one
                across the slower plans it makes).
        """
        return run_job(self.slower_job(share, vehicle, steady))

    def slower_job(
        self,
        share: float | np.ndarray,
        vehicle: DynamicVehicleParams,
        steady: ReferenceLap | None = None,
        chunk: int | None = None,
    ) -> Job[ReferenceLap]:
        """``slower`` as a job (``raceline.jobs``; arguments as there, `chunk` as
        ``from_path_job``'s): its ``from_path`` plans' slices, the dynamic part a slice
        (as ``from_path_job``'s set-up)."""
        shares = np.asarray(share, dtype=float)
        if shares.ndim not in (0, 1) or (shares.ndim == 1 and shares.shape != self.v_mps.shape):
            raise ValueError(f"speed share must be one number or one per node ({len(self.s_m)})")
        if not np.all((shares > 0.0) & (shares <= 1.0)):
            raise ValueError(f"speed share must be in (0, 1], got {share}")
        if np.all(shares == 1.0):
            return self
        share = shares if shares.ndim == 1 else float(shares)
        slow = yield from ReferenceLap.from_path_job(self.line, self.kappa_1pm,
                                                     self.v_mps * share, vehicle, chunk)
        if steady is None:
            steady = yield from ReferenceLap.from_path_job(self.line, self.kappa_1pm,
                                                           self.v_mps, vehicle, chunk)
        yield max(len(self.s_m) // 4, ARRAY_SLICE_WORK)
        k = share**DYNAMIC_SHARE_EXPONENT
        yaw_dyn = np.asarray(wrap_angle(self.yaw_rad - steady.yaw_rad))
        return replace(
            slow,
            delta_rad=slow.delta_rad + k * (self.delta_rad - steady.delta_rad),
            yaw_rad=slow.yaw_rad + k * yaw_dyn,
        )


@dataclass(frozen=True)
class TrackerTiming:
    """When a command acts (module docstring).

    Attributes:
        period_s: control period: each command is held this long [s].
        speed_delay_s: pose -> speed loop (compute + actuation delay) [s].
        steering_delay_s: pose -> road wheels (compute + actuation + steering delay + the
            servo's time constant when ``servo_time_constant_s`` is 0) [s].
        servo_time_constant_s: the servo's first-order lag ``tau`` [s] when it is inverted
            (``Tracker``: the feed-forward becomes ``<delta_p + tau d(delta_p)/dt>_W_d``
            with ``W_d`` after the pure delays only); 0: the lag is counted as a delay.
    """

    period_s: float
    speed_delay_s: float
    steering_delay_s: float
    servo_time_constant_s: float = 0.0

    def __post_init__(self) -> None:
        if not self.period_s > 0.0 or min(
            self.speed_delay_s, self.steering_delay_s, self.servo_time_constant_s
        ) < 0.0:
            raise ValueError("the period must be positive and the delays non-negative")

    def window(self, delay_s: float) -> np.ndarray:
        """Sample times [s] after the pose of a hold window starting `delay_s` after it."""
        n = max(1, round(self.period_s / WINDOW_SAMPLE_S))
        return delay_s + (np.arange(n) + 0.5) * self.period_s / n


@dataclass(frozen=True)
class TrackerGains:
    """Feedback of the tracker (module docstring). The defaults are ``[planner.raceline]``'s,
    tuned at 20 Hz; they also serve the 200 Hz replay.

    Attributes:
        k_lateral_radpm: ``k_e``, steering per metre of look-ahead lateral error [rad/m].
        lookahead_base_m: ``l_0`` [m].
        lookahead_time_s: ``T_l``: the look-ahead grows by this much per m/s [s].
        lookahead_min_m, lookahead_max_m: bounds of ``l_d`` [m].
        k_outward_per_s2: ``k_out``, acceleration cut per metre of drift towards the
            outside of the bend [1/s^2].
        k_lateral_speed_mps: above this planned speed [m/s] ``k_e`` falls as ``(v_k /
            v_p)^2`` (``k_lateral_at``): the look-ahead feedback's heading gain ``k_e l_d
            v / L`` grows with ``v^2`` (``l_d`` with ``v``), and at 9-10 m/s it is past what
            the 20 Hz loop with its delays holds (the car weaved wall to wall on the F1TENTH
            maps' straights); None: ``k_e`` at every speed. At and below it, ``k_e`` itself.
        k_lateral_speed_exponent: ``n`` of that fall, ``k_e (v_k / v_p)^n`` (2: the
            heading gain's bandwidth ``k_e l_d v / L`` held; more: less feedback at speed).
        outward_drive_only_speed_mps: above this planned speed [m/s] the outward cut
            takes the acceleration down to at most ``min(a_p, 0)`` (faded in over
            ``OUTWARD_RAMP_MPS`` above it, so a line capped there within IPOPT's tolerance
            is driven as below it): it gives up drive force
            but adds no braking, which takes the same friction ellipse (at 6-8 m/s in a bend,
            0.3 m wide, the cut braked at 7-9 m/s^2 against the plan's 0-1, the rear let go
            and the car spun); None: the cut at every speed as below it.
    """

    k_lateral_radpm: float = 0.5
    lookahead_base_m: float = 0.0
    lookahead_time_s: float = 0.4
    lookahead_min_m: float = 0.5
    lookahead_max_m: float = 4.0
    k_outward_per_s2: float = 25.0
    k_lateral_speed_mps: float | None = None
    k_lateral_speed_exponent: float = 2.0
    outward_drive_only_speed_mps: float | None = None

    def k_lateral_at(self, v_mps: float) -> float:
        """``k_e`` [rad/m] at planned speed `v_mps` [m/s] (``k_lateral_speed_mps``)."""
        v_k = self.k_lateral_speed_mps
        if v_k is None or v_mps <= v_k:
            return self.k_lateral_radpm
        return self.k_lateral_radpm * (v_k / v_mps) ** self.k_lateral_speed_exponent

    def lookahead_m(self, v_mps: float) -> float:
        """``l_d`` [m] at speed `v_mps` [m/s]."""
        l_d = self.lookahead_base_m + self.lookahead_time_s * max(v_mps, 0.0)
        return min(max(l_d, self.lookahead_min_m), self.lookahead_max_m)


@dataclass(frozen=True)
class TrackerCommand:
    """One command of the tracker and what it was computed from.

    Attributes:
        speed_mps: speed command [m/s]; steering_rad: steering command [rad] (unclipped).
        s_m: arc length of the CoG's projection on the planned path [m].
        e_m: distance from the path [m] (right +); yaw_error_rad: ``psi - psi_p(s)`` [rad].
        accel_mps2: ``a_cmd``, the acceleration asked of the speed loop [m/s^2].
        lookahead_m: ``l_d`` [m].
        feedback_rad: the feedback part of the steering, ``k_e e_la`` [rad].
        steer_s_m: the plan's arc length in the middle of the steering window ``W_d``
            (where this command's steering acts) [m], unwrapped.
    """

    speed_mps: float
    steering_rad: float
    s_m: float
    e_m: float
    yaw_error_rad: float
    accel_mps2: float
    lookahead_m: float
    feedback_rad: float = 0.0
    steer_s_m: float = 0.0


class Tracker:
    """Holds the car on a ``ReferenceLap`` (module docstring).

    Args:
        plan: the lap to follow.
        timing: control period and delays.
        gains: feedback gains.
        speed_gain_accel_per_s, speed_gain_brake_per_s: the car's speed-loop gains ``k``
            [1/s] (``DynamicVehicleParams``).
    """

    def __init__(
        self,
        plan: ReferenceLap,
        timing: TrackerTiming,
        gains: TrackerGains,
        speed_gain_accel_per_s: float,
        speed_gain_brake_per_s: float,
    ) -> None:
        if not (speed_gain_accel_per_s > 0.0 and speed_gain_brake_per_s > 0.0):
            raise ValueError("speed-loop gains must be positive")
        self.plan = plan
        self.timing = timing
        self.gains = gains
        self.k_accel = float(speed_gain_accel_per_s)
        self.k_brake = float(speed_gain_brake_per_s)
        self._w_speed = timing.window(timing.speed_delay_s)
        self._w_steer = timing.window(timing.steering_delay_s)
        self._s_hint: float | None = None
        self._e_la_prev: float | None = None

    @classmethod
    def for_vehicle(
        cls,
        plan: ReferenceLap,
        timing: TrackerTiming,
        gains: TrackerGains,
        vehicle: DynamicVehicleParams,
    ) -> Tracker:
        """A tracker with `vehicle`'s speed-loop gains."""
        return cls(
            plan, timing, gains, vehicle.speed_gain_accel_per_s, vehicle.speed_gain_brake_per_s
        )

    def retime(self, timing: TrackerTiming) -> None:
        """Act on `timing` from the next command (a servo's lag measured while racing)."""
        self.timing = timing
        self._w_speed = timing.window(timing.speed_delay_s)
        self._w_steer = timing.window(timing.steering_delay_s)
        self._e_la_prev = None

    def reset(self, s_hint_m: float | None = None) -> None:
        """Forget where the car was (None: the next call searches the whole path)."""
        self._s_hint = s_hint_m
        self._e_la_prev = None

    def project(self, x_m: float, y_m: float, s_hint_m: float | None = None) -> tuple[float, float]:
        """(s, e) [m] of the point on the planned path (e right +), near the hint if any."""
        hint = self._s_hint if s_hint_m is None else s_hint_m
        line = self.plan.line
        if hint is None:
            s, e = line.project(np.array([x_m, y_m]))
            return float(s), float(e)
        return line.project_near(x_m, y_m, hint)

    def command(
        self,
        x_m: float,
        y_m: float,
        yaw_rad: float,
        s_hint_m: float | None = None,
        offset_m: float = 0.0,
        speed_scale: float = 1.0,
        offset_slope: float = 0.0,
        speed_mps: float | None = None,
    ) -> TrackerCommand:
        """The command from the CoG pose (x, y [m], yaw [rad]); see the module docstring.

        Args:
            x_m, y_m, yaw_rad: the car's CoG position and yaw.
            s_hint_m: arc length on the path near which to project (None: where the last
                call projected, or the whole path on the first).
            offset_m: drive this far right of the path (left: negative) [m]: the errors
                ``e`` are taken from the offset (an overtake, ``raceline.overtake``); the
                returned ``e_m`` stays the distance from the path itself.
            speed_scale: ``c`` in (0, 1]: the plan driven at ``c`` times its speed (the
                lateral acceleration ``c^2`` of it, the acceleration demand ``c^2 a_p``, the
                plan's clock ``c`` times as fast: a car with less grip than planned,
                ``RacelinePlanner``'s grip adaptation); 1: the plan itself.
            offset_slope: d(offset_m)/ds [m/m], how the offset changes along the path (a
                join, ``raceline.join``): the look-ahead's heading error is taken from the
                offset path (``atan`` of it turned right of the path's heading); 0: a
                parallel path.
            speed_mps: the car's own speed [m/s] when known (from its poses): ``k_e`` is
                scheduled on ``min(v_p, speed_mps)``, the speed the feedback acts at. A car
                far below its plan (a standing start: from rest onto a line planned at
                6-10 m/s) has the feedback of its own speed, not the plan's: on the plan's
                the gain fell to a tenth and the car, joining from rest at ``--v-max 10``,
                ran 0.5 m past its line's blend (gen-1006). None: ``v_p``. No effect at
                or below ``k_lateral_speed_mps``.
        """
        p = self.plan
        g = self.gains
        c = float(speed_scale)
        s, e_path = self.project(x_m, y_m, s_hint_m)
        self._s_hint = s
        e = e_path - offset_m
        dpsi = wrap_angle(yaw_rad - p.at("yaw", s))
        v_p = c * p.at("v", s)
        l_d = g.lookahead_m(v_p)
        e_la = e - l_d * math.sin(dpsi + math.atan(offset_slope))
        tau = self.timing.servo_time_constant_s
        if tau > 0.0:  # a slow servo: feed back the error predicted its lag ahead
            prev, self._e_la_prev = self._e_la_prev, e_la
            if prev is not None:
                e_la += tau * (e_la - prev) / self.timing.period_s
        t0 = p.at("t", s)
        w_steer, w_speed = c * self._w_steer, c * self._w_speed  # in the plan's time
        s_steer = p.s_at_time(t0 + w_steer)
        v_gain = v_p if speed_mps is None else min(v_p, max(float(speed_mps), 0.0))
        feedback = g.k_lateral_at(v_gain) * e_la
        steering = float(np.mean(p.at("delta", s_steer))) + feedback
        if tau > 0.0:  # the servo's lag inverted: its target leads by tau times the rate
            h = LAG_RATE_STEP_S
            ahead = p.at("delta", p.s_at_time(t0 + w_steer + c * h))
            behind = p.at("delta", p.s_at_time(t0 + w_steer - c * h))
            steering += tau * float(np.mean(ahead - behind)) / (2.0 * h)
        s_speed = p.s_at_time(t0 + w_speed)
        outward = max(0.0, e * math.tanh(p.at("kappa", s) / KAPPA_OUTWARD_1PM))
        a_plan = c * c * float(np.mean(p.accel_at(s_speed)))
        a_cmd = a_plan - g.k_outward_per_s2 * outward
        v_o = g.outward_drive_only_speed_mps
        if v_o is not None and v_p > v_o:  # the cut gives up drive, never adds braking
            w = min(1.0, (v_p - v_o) / OUTWARD_RAMP_MPS)  # faded in: continuous in v_p
            a_cmd += w * (max(a_cmd, min(a_plan, 0.0)) - a_cmd)
        k = self.k_accel if a_cmd >= 0.0 else self.k_brake
        speed = c * float(np.mean(p.at("v", s_speed))) + a_cmd / k
        s_mid = float(np.atleast_1d(s_steer)[len(np.atleast_1d(s_steer)) // 2])
        return TrackerCommand(speed, steering, s, e_path, dpsi, a_cmd, l_d, feedback, s_mid)
