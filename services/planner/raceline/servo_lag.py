"""The servo's lag measured from the car's own yaw response (issue #21).

A planner told the wrong servo steers the wrong way round every bend: the identified car's
servo follows its target with a 0.158 s first-order lag, the default car's with 0.01 s, and
a tracker that believes the fast one asks for the new steering while the wheels still hold
the old, so the car runs wide at each entry and oversteers at each exit (the mismatch cells
of ``benchmarks/robustness.py``: 1009 off-track events in 28 cells with the true pose; 109
with the tracker told the lag). A team does not know its servo's lag until it measures it,
but the planner can: it knows every steering command it sent, and the poses tell the yaw
rate and the speed they produced.

The model, at the rear axle (the pose's reference point), is the kinematic single-track
relation with a gain ``g`` for the understeer and the tyres' own lag::

    r(t) = g v(t) tan(delta_w(t)) / L

with ``delta_w`` the road wheels' angle: each command ``delta_j`` (sent at the pose ``t_j``)
becomes the servo's target after the pure delays ``D`` (compute, actuation, steering), and
the wheels follow the target as a first-order lag ``tau``: ``delta_w' = (target - delta_w) /
tau`` (the simulator's servo, ``services/simulator/actuators.py``, below its rate limit).

For each ``tau`` of a grid (``ServoLagSettings.taus_s``, 0 = no lag) the wheels are simulated
exactly over each pose period (piecewise-constant targets, the lag's closed form, averaged
over the period as the poses' yaw difference averages ``r``), and the gain is the least
squares fit of the measured ``r_k = wrap(psi_k - psi_{k-1}) / T`` on ``x_k = v_k tan(mean
delta_w) / L`` (``v_k``: the displacement along the heading over ``T``), with exponential
forgetting (``memory_s``). The estimate is the grid's best ``tau`` (the sum of squares
``S_rr - S_xr^2 / S_xx`` least), refined by a parabola through its neighbours; it is given
only with enough steering in the data (``min_information``) and a gain in
``GAIN_RANGE``. Samples slower than ``min_speed_mps`` (the relation is ill-conditioned
there), with a pose jump or a yaw rate far beyond any wheel angle's (a slide, a spin:
``SLIDE_RATIO``) are left out.

Pure functions of the samples given (no clock, no I/O): ``RacelinePlanner`` feeds it each
pose and each command it sends.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from shared.angles import wrap_angle
from shared.config.vehicle import GRAVITY_MPS2, DynamicVehicleParams
from shared.vehicle.ops import FLOAT_OPS
from shared.vehicle.single_track import make_dynamic_derivatives
from shared.vehicle.tyres import axle_peak_friction

#: The fitted understeer gain must lie here for an estimate (outside: not a car steering).
GAIN_RANGE = (0.4, 1.5)
#: A sample whose yaw rate exceeds this times the largest over the grid's wheel angles (plus
#: ``SLIDE_FLOOR_RADPS``) is a slide or a spin, not the steering's response: left out.
SLIDE_RATIO = 1.6
SLIDE_FLOOR_RADPS = 0.3
#: The share of the tyres' grip below which the relation holds (``linear_lateral_mps2``):
#: at 0.5 the known cars of the robustness matrix measure their own servo within a few
#: hundredths of a second; with every sample, the gym's drifting linear tyres and the
#: identified car near its peak read 0.05-0.07 s slower than their servos.
LINEAR_SHARE = 0.5
#: The speeds of ``yaw_lag_table`` [m/s].
TABLE_SPEEDS_MPS = np.linspace(0.5, 12.0, 24)
#: A pose this far from the last one [m] over one period is a jump (a reset, a teleport).
JUMP_M = 1.0


@dataclass(frozen=True)
class ServoLagSettings:
    """How the lag is measured.

    Attributes:
        period_s: the pose period ``T`` [s] (the planner's tick).
        pure_delay_s: ``D``, pose -> the servo's target (compute + actuation + steering) [s].
        wheelbase_m: ``L`` [m].
        taus_s: the grid of candidate lags [s], increasing, starting at 0.
        memory_s: the forgetting's time constant [s].
        min_speed_mps: samples slower than this are left out [m/s].
        max_lateral_mps2: samples turning harder than this (``|v r|`` [m/s^2]) are left
            out: the relation holds where the tyres are linear (near their grip, and on
            tyres that drift through their bends, the yaw rate leaves it).
        min_information: the least ``S_xx`` [(rad/s)^2, forgotten as the sums] at the best
            ``tau`` for an estimate: about that many samples' worth of 1 rad/s yaw rate.
    """

    period_s: float
    pure_delay_s: float
    wheelbase_m: float
    taus_s: tuple[float, ...] = field(default_factory=lambda: tuple(
        round(0.01 * i, 2) for i in range(31)))
    memory_s: float = 10.0
    min_speed_mps: float = 1.0
    max_lateral_mps2: float = math.inf
    min_information: float = 50.0

    def __post_init__(self) -> None:
        t = np.asarray(self.taus_s, dtype=float)
        if self.period_s <= 0.0 or self.wheelbase_m <= 0.0 or self.pure_delay_s < 0.0:
            raise ValueError("period and wheelbase must be positive, the delay non-negative")
        if len(t) < 3 or t[0] != 0.0 or np.any(np.diff(t) <= 0.0):
            raise ValueError("taus_s: at least 3 increasing lags starting at 0")


@dataclass(frozen=True)
class ServoLagEstimate:
    """The measured lag.

    Attributes:
        tau_s: the lag [s].
        gain: the fitted understeer gain ``g`` at it [1].
        information: ``S_xx`` at it [(rad/s)^2].
        speed_mps: the samples' mean speed (forgotten as the sums) [m/s].
        sse: the residual sum of squares over the grid [(rad/s)^2], one per ``taus_s``.
    """

    tau_s: float
    gain: float
    information: float
    speed_mps: float
    sse: tuple[float, ...]

    def sse_at(self, tau_s: float, taus_s: tuple[float, ...]) -> float:
        """The residual sum of squares at `tau_s`, interpolated on the grid `taus_s`."""
        return float(np.interp(tau_s, taus_s, self.sse))


def linear_lateral_mps2(vehicle: DynamicVehicleParams) -> float:
    """Where the estimator's samples end [m/s^2]: ``LINEAR_SHARE`` of the weaker axle's grip
    (the gym's unbounded linear tyres: of ``mu g``)."""
    mu = min(axle_peak_friction(vehicle, "front"), axle_peak_friction(vehicle, "rear"))
    if not math.isfinite(mu):
        mu = vehicle.mu
    return LINEAR_SHARE * mu * GRAVITY_MPS2


def yaw_lag_s(vehicle: DynamicVehicleParams, speed_mps: float) -> float:
    """The car's own lag [s] from the road wheels' angle to the yaw rate at `speed_mps`:
    the mean delay ``-H'(0) / H(0)`` of the single-track model linearised straight ahead
    (``shared.vehicle.single_track``, the tyres' small-slip stiffness), ``H(s) = C (s I -
    A)^-1 B`` from the wheel angle to ``r`` over the states ``(beta, r)``. The estimator's
    kinematic relation has no tyres, so what it measures is the servo's lag plus this
    (about 0.04 s for the F1TENTH gym's car at 3-4 m/s)."""
    f = make_dynamic_derivatives(vehicle, FLOAT_OPS, raw=True)
    v = max(float(speed_mps), 0.5)
    h = 1e-5

    def rates(beta: float, r: float, delta: float) -> np.ndarray:
        out = f(v, beta, r, delta, 0.0)
        return np.array([float(out[1]), float(out[2])])

    x0 = rates(0.0, 0.0, 0.0)
    a = np.column_stack([(rates(h, 0.0, 0.0) - x0) / h, (rates(0.0, h, 0.0) - x0) / h])
    b = (rates(0.0, 0.0, h) - x0) / h
    c = np.array([0.0, 1.0])
    a_inv_b = np.linalg.solve(a, b)
    h0 = -float(c @ a_inv_b)  # H(0)
    h1 = -float(c @ np.linalg.solve(a, a_inv_b))  # H'(0)
    return -h1 / h0 if abs(h0) > 1e-12 else 0.0


def yaw_lag_table(vehicle: DynamicVehicleParams) -> tuple[np.ndarray, np.ndarray]:
    """``yaw_lag_s`` on ``TABLE_SPEEDS_MPS``: (speeds [m/s], lags [s]), for ``np.interp``
    (a planner reads it every tick; one linearisation costs about 0.2 ms)."""
    return TABLE_SPEEDS_MPS, np.array([yaw_lag_s(vehicle, v) for v in TABLE_SPEEDS_MPS])


class ServoLagEstimator:
    """Measures the servo's lag from poses and the steering commands (module docstring)."""

    def __init__(self, settings: ServoLagSettings) -> None:
        self.settings = settings
        self._taus = np.asarray(settings.taus_s, dtype=float)
        self._forget = math.exp(-settings.period_s / settings.memory_s)
        self.reset()

    def reset(self) -> None:
        """Forget everything (a new run, a teleport)."""
        n = len(self._taus)
        self._pose: tuple[float, float, float] | None = None
        self._t = 0.0  #: the time of the last pose [s]
        self._wheels = np.zeros(n)  #: each lag's wheel angle at the last pose [rad]
        #: (time the target takes the value [s], value [rad]), oldest first
        self._targets: list[tuple[float, float]] = []
        self._sxx = np.zeros(n)
        self._sxr = np.zeros(n)
        self._srr = 0.0
        self._sv = 0.0  #: the used samples' speeds, forgotten as the sums [m/s]
        self._sn = 0.0  #: ... and their count
        #: the last pose's (measured yaw rate [rad/s], each lag's kinematic one [rad/s])
        self.last_sample: tuple[float, np.ndarray] | None = None
        self.samples = 0  #: samples used since the reset
        self.dropped = 0  #: samples left out (slow, a jump, a slide)

    def commanded(self, steering_rad: float) -> None:
        """The steering command sent for the last pose given to ``observe``."""
        if not math.isfinite(steering_rad) or self._pose is None:
            return
        self._targets.append((self._t + self.settings.pure_delay_s, float(steering_rad)))

    def _advance(self, t1: float) -> np.ndarray:
        """Move each lag's wheels from the last pose's time to `t1`; their mean over it."""
        t0, taus = self._t, self._taus
        # the targets acting over (t0, t1]: the last one switched on by t0, then the rest
        while len(self._targets) > 1 and self._targets[1][0] <= t0:
            self._targets.pop(0)
        if not self._targets:
            return self._wheels.copy()
        pieces: list[tuple[float, float, float]] = []
        a = t0
        cur = self._targets[0][1] if self._targets[0][0] <= t0 else None
        for ts, val in self._targets:
            if ts <= t0:
                continue
            if ts >= t1:
                break
            if cur is not None:
                pieces.append((a, ts, cur))
            a, cur = ts, val
        if cur is not None:
            pieces.append((a, t1, cur))
        mean = np.zeros_like(self._wheels)
        covered = 0.0
        w = self._wheels
        lag = taus > 0.0
        for a_s, b_s, u in pieces:
            h = b_s - a_s
            if h <= 0.0:
                continue
            e = np.ones_like(w)
            frac = np.zeros_like(w)  # the mean's share of the starting error
            e[lag] = np.exp(-h / taus[lag])
            frac[lag] = taus[lag] / h * (1.0 - e[lag])
            mean += h * (u + (w - u) * frac)
            w = u + (w - u) * np.where(lag, e, 0.0)
            covered += h
        span = t1 - t0
        if covered < span:  # before the first target: the wheels held
            mean += (span - covered) * self._wheels
        self._wheels = w
        return mean / span

    def observe(self, x_m: float, y_m: float, yaw_rad: float) -> None:
        """The next pose (rear axle, one period after the last): one sample."""
        if not all(math.isfinite(v) for v in (x_m, y_m, yaw_rad)):
            return
        s = self.settings
        last, self._pose = self._pose, (x_m, y_m, yaw_rad)
        if last is None:
            return
        t1 = self._t + s.period_s
        mean = self._advance(t1)
        self._t = t1
        self._sxx *= self._forget
        self._sxr *= self._forget
        self._srr *= self._forget
        self._sv *= self._forget
        self._sn *= self._forget
        dx, dy = x_m - last[0], y_m - last[1]
        if math.hypot(dx, dy) > JUMP_M:
            self.reset()
            self._pose = (x_m, y_m, yaw_rad)
            return
        v = (dx * math.cos(last[2]) + dy * math.sin(last[2])) / s.period_s
        r = wrap_angle(yaw_rad - last[2]) / s.period_s
        x = v * np.tan(mean) / s.wheelbase_m
        self.last_sample = (r, x) if v >= s.min_speed_mps else None
        if (v < s.min_speed_mps or not self._targets or abs(v * r) > s.max_lateral_mps2
                or abs(r) > SLIDE_RATIO * float(np.max(np.abs(x))) + SLIDE_FLOOR_RADPS):
            self.dropped += 1
            return
        self._sxx += x * x
        self._sxr += x * r
        self._srr += r * r
        self._sv += v
        self._sn += 1.0
        self.samples += 1

    def residual(self, est: ServoLagEstimate) -> float | None:
        """The last pose's yaw rate less what `est` predicts from the wheels [rad/s]
        (positive: the car turns more than its wheels ask, a rear sliding out; None: no
        sample, too slow)."""
        if self.last_sample is None:
            return None
        r, x = self.last_sample
        return r - est.gain * float(np.interp(est.tau_s, self._taus, x))

    def estimate(self) -> ServoLagEstimate | None:
        """The lag the data tell, or None (too little steering in them, no car's gain)."""
        sxx, sxr = self._sxx, self._sxr
        if not np.all(sxx > 0.0):
            return None
        sse = np.maximum(self._srr - sxr * sxr / sxx, 0.0)
        i = int(np.argmin(sse))
        if sxx[i] < self.settings.min_information:
            return None
        gain = float(sxr[i] / sxx[i])
        if not GAIN_RANGE[0] <= gain <= GAIN_RANGE[1]:
            return None
        taus = self._taus
        tau = float(taus[i])
        if 0 < i < len(taus) - 1:  # the parabola through the neighbours (an even grid)
            den = sse[i - 1] - 2.0 * sse[i] + sse[i + 1]
            if den > 0.0:
                step = 0.5 * (sse[i - 1] - sse[i + 1]) / den
                tau += float(np.clip(step, -0.5, 0.5)) * float(taus[i + 1] - taus[i])
        return ServoLagEstimate(tau, gain, float(sxx[i]), self._sv / max(self._sn, 1e-9),
                                tuple(float(e) for e in sse))
