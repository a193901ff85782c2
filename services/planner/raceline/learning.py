"""Iterative learning of the steering feed-forward along the line, lap by lap. Pure maths.

A car that follows the same line lap after lap makes the same tracking error at the same
place every lap: the feed-forward's model of the car (its tyres, its servo, its load
transfer) is wrong there in the same way each time. Measured on the identified car on
map416 (``raceline``, true pose, 5 flying laps): the lateral error along the line has an rms
of 1.4 cm, up to 4 cm outside in a right-hander, and its profile ``e(s)`` correlates at
0.96-0.99 from one lap to the next. The tracker's feedback corrects such an error only after
it has grown, and the outward cut slows the car while it lasts.

Iterative learning control (as Kapania and Gerdes did for a car at the limit, 2015): after
each lap the feedback steering the tracker gave at each place of the line is added, times a
gain, to a correction of the feed-forward there::

    u_(j+1)(s) = clip(Q[u_j(s) + gamma fb_j(s)], -u_max, u_max)                    [rad]

with ``fb_j(s)`` the mean feedback steering ``k_e e_la`` [rad] of lap ``j``'s ticks whose
steering acted at ``s`` (a tick's command is held for the period: it is spread over the
plan's ``[s_d - v T / 2, s_d + v T / 2]``, ``s_d`` the middle of its steering window), ``Q``
a Gaussian smoothing along ``s`` of width ``sigma`` (no growth at the grid's own scale), and
places lap ``j`` did not record keep ``u_j``. The steering is then ``delta_p + u(s_d) +
feedback``. For a constant feed-forward error ``b`` the proportional feedback settles at
``-b``, so ``u`` converges to ``-b`` by ``(1 - gamma)`` per lap and the feedback (and the
error it needed) to zero; the noise of the poses enters ``u`` averaged over a lap's ticks
near ``s`` and shrunk by ``gamma``.

What is learnt holds for one plan at one speed: ``StepLearning.context`` clears it when the
plan or the speed scale changes (a grip cut, a re-planned profile, the cautious out lap's
rise).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class LearningSettings:
    """The learning law's constants (``[planner.raceline] steering_learning_*``).

    Attributes:
        gain: ``gamma`` in [0, 1]: the share of a lap's feedback added to the correction
            (0: no learning).
        spacing_m: the correction's grid along the line [m].
        smooth_m: ``sigma`` of the Gaussian smoothing ``Q`` [m].
        max_rad: ``u_max``: the correction's bound [rad].
    """

    gain: float = 0.5
    spacing_m: float = 0.1
    smooth_m: float = 0.2
    max_rad: float = 0.05

    def __post_init__(self) -> None:
        if not 0.0 <= self.gain <= 1.0:
            raise ValueError(f"learning gain must be in [0, 1], got {self.gain}")
        if not (self.spacing_m > 0.0 and self.smooth_m >= 0.0 and self.max_rad >= 0.0):
            raise ValueError("spacing must be positive, smoothing and bound non-negative")


class StepLearning:
    """The steering correction ``u(s)`` along one closed line, learnt lap by lap (module
    docstring).

    Args:
        length_m: the line's length [m] (the grid wraps around it).
        settings: the law's constants.
    """

    def __init__(self, length_m: float, settings: LearningSettings) -> None:
        if not length_m > 0.0:
            raise ValueError("the line's length must be positive")
        self.settings = settings
        self.length_m = float(length_m)
        self.n = max(1, math.ceil(self.length_m / settings.spacing_m))
        self.spacing_m = self.length_m / self.n
        self.table = np.zeros(self.n)  #: ``u`` at the grid's nodes [rad]
        self._sum = np.zeros(self.n)
        self._count = np.zeros(self.n)
        self._s_prev: float | None = None
        self._context: object = None
        self.laps_learnt = 0  #: laps whose feedback went into ``table``
        half = math.ceil(3.0 * settings.smooth_m / self.spacing_m)
        if settings.smooth_m > 0.0 and half > 0:
            x = np.arange(-half, half + 1) * self.spacing_m
            kernel = np.exp(-0.5 * (x / settings.smooth_m) ** 2)
            self._kernel = kernel / kernel.sum()
        else:
            self._kernel = np.ones(1)

    def clear(self) -> None:
        """Forget everything learnt and the lap under way."""
        self.table[:] = 0.0
        self._sum[:] = 0.0
        self._count[:] = 0.0
        self._s_prev = None
        self.laps_learnt = 0

    def context(self, key: object) -> None:
        """What the correction is for (the plan and its speed scale): a new key clears it."""
        if key != self._context:
            self._context = key
            self.clear()

    def correction(self, s_m: float) -> float:
        """``u`` at arc length `s_m` [m] (linear between the nodes, periodic) [rad]."""
        x = (s_m % self.length_m) / self.spacing_m
        i = int(x) % self.n
        w = x - int(x)
        return float((1.0 - w) * self.table[i] + w * self.table[(i + 1) % self.n])

    def record(self, s_m: float, feedback_rad: float, span_m: float) -> None:
        """One tick's feedback steering `feedback_rad` [rad] that acted over the plan's
        ``[s_m - span_m / 2, s_m + span_m / 2]`` [m]; a pass through the line's start
        (``s`` falling by more than half a lap) ends the lap and learns from it."""
        s = s_m % self.length_m
        if self._s_prev is not None and s < self._s_prev - 0.5 * self.length_m:
            self.end_lap()
        self._s_prev = s
        if not math.isfinite(feedback_rad):
            return
        half = max(0.5 * span_m, 0.5 * self.spacing_m)
        lo = math.floor((s - half) / self.spacing_m + 0.5)
        hi = math.floor((s + half) / self.spacing_m + 0.5)
        idx = np.arange(lo, max(hi, lo + 1)) % self.n
        np.add.at(self._sum, idx, feedback_rad)
        np.add.at(self._count, idx, 1.0)

    def end_lap(self) -> None:
        """Learn from the lap recorded so far (the places it saw) and start the next."""
        seen = self._count > 0.0
        if np.any(seen):
            update = self.table.copy()
            update[seen] += self.settings.gain * self._sum[seen] / self._count[seen]
            k = self._kernel
            if len(k) > 1:
                half = len(k) // 2
                padded = update[np.arange(-half, self.n + half) % self.n]
                smooth = np.convolve(padded, k, mode="valid")
                update = np.where(seen, smooth, update)
            m = self.settings.max_rad
            self.table = np.clip(update, -m, m)
            self.laps_learnt += 1
        self._sum[:] = 0.0
        self._count[:] = 0.0
