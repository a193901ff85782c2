"""Actuation of the simulated car: command delays, timeout, and the speed / servo P-controllers.

A command (target speed [m/s], target steering [rad]) received at time ``t`` reaches the
speed controller at ``t + actuation_delay`` and the servo at
``t + actuation_delay + steering_delay`` (the F1TENTH gym's 2-step steering buffer at 10 ms
is ``steering_delay = 0.02 s``). The controllers then produce the model inputs:

- speed:  ``a = k (v_target - v)`` with ``k = speed_gain_accel`` while |v| grows and
  ``speed_gain_brake`` while it shrinks (the gym's forward gains);
- servo:  ``sv = (delta_target - delta) / steering_time_constant``;

and the model clips both to its limits (acceleration, steering rate: with the default 0.01 s
time constant the servo runs at the rate limit for errors above 0.032 rad, as in the gym).
"""

from __future__ import annotations

import math
from collections import deque

#: Time comparisons tolerate this much floating-point error [s].
TIME_EPS_S = 1e-9


def speed_control(v_target: float, v: float, gain_accel: float, gain_brake: float) -> float:
    """Acceleration request [m/s^2] of the speed P-controller (before the model's limits).

    Args:
        v_target: target speed [m/s].
        v: current speed [m/s].
        gain_accel: gain [1/s] when the speed magnitude grows (or from standstill).
        gain_brake: gain [1/s] when the speed magnitude shrinks.
    """
    e = v_target - v
    if (e > 0.0 and v >= 0.0) or (e < 0.0 and v <= 0.0):
        return gain_accel * e
    return gain_brake * e


def steering_control(delta_target: float, delta: float, time_constant_s: float) -> float:
    """Steering-rate request [rad/s] of the servo P-controller (before the rate limits)."""
    return (delta_target - delta) / time_constant_s


class CommandDelayLine:
    """Delayed, time-stamped drive commands with NaN handling and a VESC-style timeout.

    Commands are pushed with their receive time; ``targets(t)`` gives the (speed, steering)
    targets acting at time ``t``. Non-finite commands count as "brake": speed 0, steering
    held at the previous command's value. Targets are clipped to the given limits.

    Args:
        speed_delay_s: delay of the speed channel [s] (``actuation_delay_s``).
        steering_delay_s: delay of the steering channel [s] (actuation + steering delay).
        timeout_s: when the newest delayed command is older than this [s] (or there is none),
            the speed target is 0 and the steering target holds.
        speed_limits: (min, max) target speed [m/s].
        steering_limits: (min, max) target steering [rad].
    """

    def __init__(
        self,
        speed_delay_s: float,
        steering_delay_s: float,
        timeout_s: float,
        speed_limits: tuple[float, float],
        steering_limits: tuple[float, float],
    ) -> None:
        if min(speed_delay_s, steering_delay_s) < 0.0 or not timeout_s > 0.0:
            raise ValueError("delays must be >= 0 and the timeout > 0")
        self.speed_delay_s = float(speed_delay_s)
        self.steering_delay_s = float(steering_delay_s)
        self.timeout_s = float(timeout_s)
        self.speed_limits = (float(speed_limits[0]), float(speed_limits[1]))
        self.steering_limits = (float(steering_limits[0]), float(steering_limits[1]))
        self._max_delay = max(self.speed_delay_s, self.steering_delay_s)
        self._queue: deque[tuple[float, float, float]] = deque()
        self._hold_steering = 0.0
        self._last_valid_steering = 0.0
        self.rejected = 0

    def clear(self, hold_steering_rad: float = 0.0) -> None:
        """Forget all commands; the servo holds `hold_steering_rad` until one acts."""
        self._queue.clear()
        self._hold_steering = float(hold_steering_rad)
        self._last_valid_steering = float(hold_steering_rad)
        self.rejected = 0

    @property
    def last_stamp_s(self) -> float | None:
        """Receive time [s] of the newest command, None before the first."""
        return self._queue[-1][0] if self._queue else None

    def push(self, speed_mps: float, steering_rad: float, t_s: float) -> bool:
        """Queue a command received at `t_s` [s]; False when it was non-finite (-> brake).

        Raises:
            ValueError: when `t_s` is not finite or earlier than the previous command.
        """
        t = float(t_s)
        if not math.isfinite(t):
            raise ValueError(f"command time must be finite, got {t_s!r}")
        if self._queue and t < self._queue[-1][0] - TIME_EPS_S:
            raise ValueError(f"command time went backwards: {t} < {self._queue[-1][0]}")
        try:
            v = float(speed_mps)
            d = float(steering_rad)
        except (TypeError, ValueError):
            v = d = math.nan
        ok = math.isfinite(v) and math.isfinite(d)
        if ok:
            v = min(max(v, self.speed_limits[0]), self.speed_limits[1])
            d = min(max(d, self.steering_limits[0]), self.steering_limits[1])
            self._last_valid_steering = d
        else:
            self.rejected += 1
            v, d = 0.0, self._last_valid_steering
        self._queue.append((t, v, d))
        return ok

    def targets(self, t_s: float) -> tuple[float, float, bool]:
        """(speed target [m/s], steering target [rad], timed_out) acting at time `t_s` [s]."""
        q = self._queue
        cut_far = t_s - self._max_delay + TIME_EPS_S
        while len(q) >= 2 and q[1][0] <= cut_far:
            q.popleft()
        cut_v = t_s - self.speed_delay_s + TIME_EPS_S
        cut_d = t_s - self.steering_delay_s + TIME_EPS_S
        speed, timed_out = 0.0, True
        steering = self._hold_steering
        for stamp, v, _d in reversed(q):
            if stamp <= cut_v:
                if cut_v - stamp <= self.timeout_s:
                    speed, timed_out = v, False
                break
        for stamp, _v, d in reversed(q):
            if stamp <= cut_d:
                steering = d
                self._hold_steering = d
                break
        return speed, steering, timed_out
