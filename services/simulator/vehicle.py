"""The simulated car: actuation + dynamic single-track model + RK4, stepped with given time.

No clock is read anywhere: the caller owns simulation time. Two ways to drive it:

- in-process bench: ``sim.step(Command(speed, steering), dt)`` once per control period (the
  command is received at the current sim time, then the car advances ``dt``);
- a service: ``sim.set_command(speed, steering, now)`` whenever a command arrives (``now`` =
  current sim time) and ``sim.step(None, dt)`` on the simulation tick.

``dt`` is split into ``ceil(dt / integration_step_s)`` equal RK4 sub-steps (each at most the
configured step). At low speed, where the lateral dynamics get stiff (eigenvalues ~ 1/v),
a sub-step is split further until ``h |lambda| <= 2.5`` (RK4 stability), which only happens
between ``kinematic_below_mps`` and a few times that speed.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from services.simulator.actuators import CommandDelayLine, speed_control, steering_control
from services.simulator.dynamics import RK4_STABLE_HLAMBDA, SingleTrackModel
from services.simulator.integrate import rk4_step
from services.simulator.state import (
    Command,
    Pose2D,
    StateIndex,
    StateTuple,
    VehicleState,
)
from shared.angles import wrap_angle
from shared.config.simulator import SimulatorSettings

# plain-int copies of the state indices for the hot path
_BETA = int(StateIndex.BETA)
_PSI = int(StateIndex.PSI)
_V = int(StateIndex.V)
_DELTA = int(StateIndex.DELTA)
_HALF_PI = 0.5 * math.pi


@dataclass(frozen=True, slots=True)
class StepResult:
    """The truth after one ``Simulator.step``.

    Attributes:
        t_s: simulation time at the end of the step [s].
        state: true state at ``t_s``.
        accel_long_mps2: body-frame longitudinal acceleration of the CoG, mean over the step
            [m/s^2]: the change of the velocity vector over the step, in the body frame at
            the step's mean yaw (to first order ``a cos(beta) - v sin(beta) (beta' + psi')``).
        accel_lat_mps2: body-frame lateral acceleration (left positive), mean over the step
            [m/s^2] (to first order ``a sin(beta) + v cos(beta) (beta' + psi')``).
        speed_target_mps: speed target acting at the last sub-step (after delays) [m/s].
        steering_target_rad: steering target acting at the last sub-step [rad].
        command_timed_out: the speed target was 0 at the last sub-step because no fresh
            command was acting (timeout or none yet).
        substeps: RK4 sub-steps taken.
    """

    t_s: float
    state: VehicleState
    accel_long_mps2: float
    accel_lat_mps2: float
    speed_target_mps: float
    steering_target_rad: float
    command_timed_out: bool
    substeps: int


class Simulator:
    """One simulated car (see the module docstring).

    Args:
        settings: the simulator settings (vehicle parameters, step, delays, timeout).
    """

    def __init__(self, settings: SimulatorSettings | None = None) -> None:
        self.settings = settings or SimulatorSettings()
        p = self.settings.vehicle
        self.params = p
        self.model = SingleTrackModel(
            p, self.settings.kinematic_below_mps, self.settings.kinematic_blend_mps
        )
        self.commands = CommandDelayLine(
            speed_delay_s=self.settings.actuation_delay_s,
            steering_delay_s=self.settings.actuation_delay_s + self.settings.steering_delay_s,
            timeout_s=self.settings.command_timeout_s,
            speed_limits=(p.v_min_mps, p.v_max_mps),
            steering_limits=(p.steering_min_rad, p.steering_max_rad),
        )
        self._h = self.settings.integration_step_s
        self._actuator_rate = max(
            1.0 / p.steering_time_constant_s, p.speed_gain_accel_per_s, p.speed_gain_brake_per_s
        )
        self._plant = self._make_plant()
        self._s: StateTuple = (0.0,) * 7  # type: ignore[assignment]
        self._t = 0.0
        self.reset(Pose2D(0.0, 0.0, 0.0))

    def _make_plant(self):
        rhs = self.model.rhs
        p = self.params
        tau = p.steering_time_constant_s
        k_acc, k_brk = p.speed_gain_accel_per_s, p.speed_gain_brake_per_s
        k_timeout = self.settings.timeout_brake_gain_per_s

        def plant(
            s: StateTuple, v_target: float, d_target: float, timed_out: bool = False
        ) -> StateTuple:
            """Closed-loop derivative: the P-controllers' outputs into the model.

            With no fresh command (timed out) the speed loop brakes like a VESC's brake
            current: a gain so high that the model's acceleration limit acts down to a
            near standstill.
            """
            sv = steering_control(d_target, s[_DELTA], tau)
            k_b = k_timeout if timed_out else k_brk
            return rhs(s, sv, speed_control(v_target, s[_V], k_acc, k_b))

        return plant

    # ------------------------------------------------------------------ public API
    @property
    def t_s(self) -> float:
        """Current simulation time [s]."""
        return self._t

    @property
    def state(self) -> VehicleState:
        """Current true state."""
        return VehicleState(*self._s)

    @property
    def state_tuple(self) -> StateTuple:
        """Current true state as a tuple in ``StateIndex`` order (no allocation of a class)."""
        return self._s

    @property
    def rejected_commands(self) -> int:
        """Non-finite commands received since the last reset (each was treated as brake)."""
        return self.commands.rejected

    def reset(
        self,
        pose: Pose2D | tuple[float, float, float],
        speed_mps: float = 0.0,
        t_s: float = 0.0,
        steering_rad: float = 0.0,
    ) -> VehicleState:
        """Place the car at `pose` (CoG x, y [m], yaw [rad]) moving straight at `speed_mps`.

        Forgets all commands and seeds the actuators with the command (`speed_mps`,
        `steering_rad`) as if it had been received just long enough ago to act on both
        channels now, so the car keeps going until the first real command arrives (and
        brakes after ``command_timeout_s`` if none does). Yaw rate and slip start at their
        kinematic values for the steering.
        """
        x, y, yaw = (float(v) for v in pose)
        vals = (x, y, yaw, float(speed_mps), float(t_s), float(steering_rad))
        if not all(math.isfinite(v) for v in vals):
            raise ValueError(f"reset values must be finite, got {vals}")
        p = self.params
        delta = min(max(float(steering_rad), p.steering_min_rad), p.steering_max_rad)
        v = min(max(float(speed_mps), p.v_min_mps), p.v_max_mps)
        beta, r = self.model.kinematic_slip_and_yaw_rate(delta, v)
        self._s = (x, y, delta, v, yaw, r, beta)
        self._t = float(t_s)
        self.commands.clear(hold_steering_rad=delta)
        c = self.commands
        self.commands.push(v, delta, self._t - max(c.speed_delay_s, c.steering_delay_s))
        return self.state

    def nudge(self, x_m: float, y_m: float, speed_mps: float, slip_rad: float) -> None:
        """Move the car's CoG to (x, y) [m] with speed [m/s] and slip [rad] (a contact's
        response, ``collision.py``); heading, yaw rate, steering and the commands stay.
        Speed is clamped to the car's range, the slip to the canonical [-pi/2, pi/2]."""
        vals = (x_m, y_m, speed_mps, slip_rad)
        if not all(math.isfinite(v) for v in vals):
            raise ValueError(f"nudge values must be finite, got {vals}")
        p = self.params
        _x, _y, delta, _v, psi, r, _beta = self._s
        v = min(max(float(speed_mps), p.v_min_mps), p.v_max_mps)
        beta = min(max(float(slip_rad), -_HALF_PI), _HALF_PI)
        self._s = (float(x_m), float(y_m), delta, v, psi, r, beta)

    def snapshot(self) -> StepResult:
        """The current truth as a ``StepResult`` (accelerations 0, no sub-steps), e.g. to feed
        the sensors right after ``reset``."""
        v_target, d_target, timed_out = self.commands.targets(self._t)
        return StepResult(
            t_s=self._t,
            state=VehicleState(*self._s),
            accel_long_mps2=0.0,
            accel_lat_mps2=0.0,
            speed_target_mps=v_target,
            steering_target_rad=d_target,
            command_timed_out=timed_out,
            substeps=0,
        )

    def set_command(self, speed_mps: float, steering_rad: float, now_s: float) -> bool:
        """Receive a command at sim time `now_s` [s]; False if non-finite (treated as brake)."""
        return self.commands.push(speed_mps, steering_rad, now_s)

    def step(
        self, command: Command | tuple[float, float] | None = None, dt_s: float | None = None
    ) -> StepResult:
        """Advance the simulation by `dt_s` [s] (default: one integration step).

        Args:
            command: (speed [m/s], steering [rad]) received now, or None (keep the queue:
                the newest command acts until the timeout).
            dt_s: time to advance [s], > 0.

        Returns:
            The truth at the end of the step.
        """
        h_max = self._h
        dt = h_max if dt_s is None else float(dt_s)
        if not (dt > 0.0 and math.isfinite(dt)):
            raise ValueError(f"dt_s must be positive and finite, got {dt_s!r}")
        if command is not None:
            self.commands.push(command[0], command[1], self._t)
        n = max(1, math.ceil(dt / h_max - 1e-9))
        h = dt / n
        s0 = self._s
        s = s0
        t = self._t
        plant = self._plant
        targets = self.commands.targets
        p = self.params
        s_min, s_max = p.steering_min_rad, p.steering_max_rad
        v_min, v_max = p.v_min_mps, p.v_max_mps
        v_target = d_target = 0.0
        timed_out = True
        total = 0
        for i in range(n):
            t_i = self._t + i * h
            v_target, d_target, timed_out = targets(t_i)
            bound = max(self.model.stiffness_bound(abs(s[_V])), self._actuator_rate)
            m = max(1, math.ceil(h * bound / RK4_STABLE_HLAMBDA))
            hm = h / m
            for _ in range(m):
                s_new, _slope = rk4_step(
                    lambda z, vt=v_target, dt_=d_target, to=timed_out: plant(z, vt, dt_, to),
                    s,
                    hm,
                )
                s = self._sanitise(s_new, s, s_min, s_max, v_min, v_max)
            total += m
            t = t_i + h
        self._s = s
        self._t = t
        # mean acceleration over the step from the change of the velocity vector (valid
        # across the canonical flip (v, beta) -> (-v, beta -+ pi)), in the body frame at
        # the step's mean yaw
        c0, c1 = s0[_PSI] + s0[_BETA], s[_PSI] + s[_BETA]
        ax_w = (s[_V] * math.cos(c1) - s0[_V] * math.cos(c0)) / dt
        ay_w = (s[_V] * math.sin(c1) - s0[_V] * math.sin(c0)) / dt
        yaw_mid = 0.5 * (s0[_PSI] + s[_PSI])
        cy, sy = math.cos(yaw_mid), math.sin(yaw_mid)
        return StepResult(
            t_s=t,
            state=VehicleState(*s),
            accel_long_mps2=cy * ax_w + sy * ay_w,
            accel_lat_mps2=-sy * ax_w + cy * ay_w,
            speed_target_mps=v_target,
            steering_target_rad=d_target,
            command_timed_out=timed_out,
            substeps=total,
        )

    @staticmethod
    def _sanitise(
        s_new: tuple[float, ...],
        s_old: StateTuple,
        s_min: float,
        s_max: float,
        v_min: float,
        v_max: float,
    ) -> StateTuple:
        """Clamp steering and speed to their ranges (RK4 stages may overshoot an end stop)
        and keep the slip angle canonical: ``|beta| <= pi/2``, a car sliding backwards has
        ``v < 0`` (``(v, beta)`` and ``(-v, beta -+ pi)`` are the same velocity)."""
        x, y, delta, v, psi, r, beta = s_new  # StateIndex order (checked in state.py)
        if not (
            math.isfinite(x + y + delta + v + psi + r + beta)
        ):  # inputs are sanitised, so this is a bug: refuse to carry NaN on
            raise FloatingPointError(f"non-finite state after a step from {s_old}: {s_new}")
        if beta > _HALF_PI or beta < -_HALF_PI:
            beta = wrap_angle(beta)  # into [-pi, pi)
            if beta > _HALF_PI:
                beta, v = beta - math.pi, -v
            elif beta < -_HALF_PI:
                beta, v = beta + math.pi, -v
        if delta < s_min:
            delta = s_min
        elif delta > s_max:
            delta = s_max
        if v < v_min:
            v = v_min
        elif v > v_max:
            v = v_max
        return (x, y, delta, v, psi, r, beta)
