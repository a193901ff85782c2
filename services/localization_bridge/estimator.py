"""The fused estimate: the EKF (``ekf.py``) over a short history of measurements, with stamp
checks, the pose gate and the drop-out rules. No I/O: the caller passes every stamp and its
own clock ``now_s`` [s] (wall clock in the service, simulation time in the bench).

Measurements are applied at their own stamps. The estimator keeps every measurement of the
last ``history_s`` (an ``_Event``) and the belief after each; a measurement older than the
newest is inserted at its stamp and the beliefs after it are recomputed from there
(re-propagation), so a pose that arrives 30 ms after its capture corrects the state as it
was 30 ms ago and the IMU and odometry since carry it to now. ``estimate(now_s)`` predicts
the newest belief to ``now_s`` (at most ``max_prediction_s``).

Rules, each counted in ``counts`` (by reason) and returned as a ``Verdict``:

- a stamp more than ``future_tolerance_s`` ahead of ``now_s`` is rejected (``future``); one
  older than ``now_s - history_s`` or than the history's base is rejected (``stale``);
- a pose whose innovation's squared Mahalanobis distance exceeds ``gate_chi2`` is not
  applied (``gated``). Re-opening: ``reinit_after_gated`` consecutive gated poses that agree
  with each other (each within ``reinit_agree_m`` and ``reinit_agree_rad`` of the previous
  gated one) re-initialise the filter at the newest (``reinit``): the car really is there;
- pose drop-out: the newest applied pose older than ``degraded_after_s`` makes the estimate
  ``degraded``, older than ``invalid_after_s`` makes it invalid; the next pose then
  re-initialises the filter (``reinit``), with the speed and yaw rate it had.
- a teleport (``teleport``: the car was put elsewhere, announced by the simulator or an
  operator) re-initialises the filter at once at the announced pose and speed (yaw rate 0,
  the gyro bias kept), without waiting for the gate: odometry and IMU stamped after it are
  re-applied; a pose, odometry or IMU reading stamped at or before it is the car before the
  teleport and is rejected (``<kind>_before_teleport``).
- without ``latency_compensation`` every measurement is applied at its arrival (``now_s``),
  as a filter that ignores latency would (the benchmark's comparison).
"""

from __future__ import annotations

import math
from bisect import bisect_right
from collections import Counter
from dataclasses import dataclass
from enum import StrEnum

import numpy as np

from services.localization_bridge.ekf import (
    Belief,
    Ekf,
    initial_belief,
    pose_covariance,
    pose_innovation,
    predict,
    update_gyro,
    update_pose,
    update_speed,
    update_yaw_rate,
)
from shared.angles import wrap_angle
from shared.config.localization import LocalizationSettings


class Verdict(StrEnum):
    """What became of one measurement."""

    APPLIED = "applied"
    INITIALISED = "initialised"  #: the first pose started the filter
    REINIT = "reinit"  #: the filter restarted at this pose (after a drop-out or a gated run)
    TELEPORT = "teleport"  #: the filter restarted at an announced teleport
    GATED = "gated"
    FUTURE = "future"
    STALE = "stale"
    WAITING = "waiting"  #: odometry / IMU before the first pose (kept as the start values)


class _Kind(StrEnum):
    POSE = "pose"
    SPEED = "speed"
    YAW_RATE = "yaw_rate"
    GYRO = "gyro"


@dataclass(slots=True)
class _Event:
    t_s: float
    order: int
    kind: _Kind
    z: np.ndarray
    R: np.ndarray | float

    @property
    def key(self) -> tuple[float, int]:
        return (self.t_s, self.order)


@dataclass(frozen=True, slots=True)
class Estimate:
    """The fused state at `t_s` [s] (rear axle, map frame).

    Attributes:
        x_m, y_m [m], yaw_rad [rad] in [-pi, pi], speed_mps [m/s], yaw_rate_radps [rad/s]
            (bias removed), bias_radps: the gyro bias estimate [rad/s].
        steering_rad: the newest odometry steering [rad] (0 before any).
        cov: (7, 7) covariance, index with ``Ekf``.
        pose_stamp_s: stamp of the newest pose applied [s] (None: none yet).
        pose_age_s: ``t_s - pose_stamp_s`` [s] (inf: none yet).
        degraded: pose older than ``degraded_after_s``; valid: initialised and pose not older
            than ``invalid_after_s`` (the planner brakes otherwise).
    """

    t_s: float
    x_m: float
    y_m: float
    yaw_rad: float
    speed_mps: float
    yaw_rate_radps: float
    bias_radps: float
    steering_rad: float
    cov: np.ndarray
    pose_stamp_s: float | None
    pose_age_s: float
    degraded: bool
    valid: bool


def _event_key(e: _Event) -> tuple[float, int]:
    return (e.t_s, e.order)


class FusedEstimator:
    """Pose, wheel odometry and IMU in, ``Estimate`` out (module docstring)."""

    def __init__(self, settings: LocalizationSettings) -> None:
        self.settings = settings
        self.noise = settings.noise
        self.counts: Counter[str] = Counter()
        self.reset()

    def reset(self) -> None:
        """Forget everything (the next pose initialises the filter); counts are kept."""
        self.base: Belief | None = None
        self.events: list[_Event] = []
        self.beliefs: list[Belief] = []
        self.pose_stamp_s: float | None = None
        self.steering_rad = 0.0
        self._steering_t = -math.inf
        self._start_speed = 0.0
        self._start_yaw_rate = 0.0
        self._order = 0
        self._gated_run = 0
        self._last_gated: np.ndarray | None = None
        self.teleport_stamp_s: float | None = None

    @property
    def initialised(self) -> bool:
        """Whether a pose has started the filter."""
        return self.base is not None

    # ------------------------------------------------------------------ inputs
    def _check(self, what: str, t_s: float, now_s: float) -> Verdict | None:
        st = self.settings
        if not math.isfinite(t_s) or t_s > now_s + st.future_tolerance_s:
            self.counts[f"{what}_future"] += 1
            return Verdict.FUTURE
        if self.teleport_stamp_s is not None and t_s <= self.teleport_stamp_s:
            self.counts[f"{what}_before_teleport"] += 1
            return Verdict.STALE
        oldest = now_s - st.history_s
        if t_s < oldest or (self.base is not None and t_s < self.base.t_s):
            self.counts[f"{what}_stale"] += 1
            return Verdict.STALE
        return None

    def _stamp(self, t_s: float, now_s: float) -> float:
        """The time a measurement is applied at: its stamp, or its arrival without latency
        compensation (never before the newest event, so arrival order is kept)."""
        if self.settings.latency_compensation:
            return t_s
        newest = self.events[-1].t_s if self.events else -math.inf
        return max(now_s, newest)

    def pose(
        self,
        t_s: float,
        x_m: float,
        y_m: float,
        yaw_rad: float,
        cov: np.ndarray | None,
        now_s: float,
    ) -> Verdict:
        """A pose captured at `t_s` [s] (rear axle [m], yaw [rad], optional 3x3 covariance)."""
        if (bad := self._check("pose", t_s, now_s)) is not None:
            return bad
        if not all(math.isfinite(v) for v in (x_m, y_m, yaw_rad)):
            self.counts["pose_not_finite"] += 1
            return Verdict.STALE
        t = self._stamp(t_s, now_s)
        R = pose_covariance(cov, self.noise)
        z = np.array([x_m, y_m, wrap_angle(yaw_rad)])
        if self.base is None:
            self._restart(t, z, R)
            self.counts["pose_initialised"] += 1
            return Verdict.INITIALISED
        if self.pose_stamp_s is None or now_s - self.pose_stamp_s > self.settings.invalid_after_s:
            self._restart(t, z, R)
            self.counts["pose_reinit_after_dropout"] += 1
            return Verdict.REINIT
        k = self._index(t)
        prior = predict(self._belief_before(k), t, self.noise)
        _, d2 = pose_innovation(prior, z, R)
        if not d2 <= self.settings.gate_chi2:
            return self._gated(t, z, R)
        self._gated_run, self._last_gated = 0, None
        self._insert(k, _Event(t, self._next_order(), _Kind.POSE, z, R))
        self.pose_stamp_s = max(self.pose_stamp_s, t)
        self.counts["pose_applied"] += 1
        return Verdict.APPLIED

    def odom(
        self,
        t_s: float,
        speed_mps: float,
        steering_rad: float,
        yaw_rate_radps: float | None,
        now_s: float,
    ) -> Verdict:
        """Wheel odometry at `t_s` [s]: speed [m/s], steering [rad], optional yaw rate."""
        if (bad := self._check("odom", t_s, now_s)) is not None:
            return bad
        t = self._stamp(t_s, now_s)
        if t >= self._steering_t:
            self.steering_rad, self._steering_t = steering_rad, t
        if self.base is None:
            self._start_speed = speed_mps
            return Verdict.WAITING
        k = self._index(t)
        self._insert(
            k, _Event(t, self._next_order(), _Kind.SPEED, np.array([speed_mps]),
                      self.noise.speed_std_mps)
        )
        if yaw_rate_radps is not None:
            self._insert(
                self._index(t),
                _Event(t, self._next_order(), _Kind.YAW_RATE, np.array([yaw_rate_radps]),
                       self.noise.odom_yaw_rate_std_radps),
            )
        return Verdict.APPLIED

    def imu(self, t_s: float, yaw_rate_radps: float, now_s: float) -> Verdict:
        """A gyro yaw rate [rad/s] at `t_s` [s] (``r + bias``)."""
        if (bad := self._check("imu", t_s, now_s)) is not None:
            return bad
        t = self._stamp(t_s, now_s)
        if self.base is None:
            self._start_yaw_rate = yaw_rate_radps
            return Verdict.WAITING
        self._insert(
            self._index(t),
            _Event(t, self._next_order(), _Kind.GYRO, np.array([yaw_rate_radps]),
                   self.noise.gyro_std_radps),
        )
        return Verdict.APPLIED

    def teleport(
        self,
        t_s: float,
        x_m: float,
        y_m: float,
        yaw_rad: float,
        speed_mps: float,
        now_s: float,
    ) -> Verdict:
        """The car was put at rear-axle pose (`x_m`, `y_m` [m], `yaw_rad` [rad]) moving at
        `speed_mps` [m/s] at `t_s` [s]: re-initialise there now (module docstring). The
        position and yaw start with the ``init_*`` covariance of the settings."""
        st = self.settings
        if not math.isfinite(t_s) or t_s > now_s + st.future_tolerance_s:
            self.counts["teleport_future"] += 1
            return Verdict.FUTURE
        if t_s < now_s - st.history_s or (
            self.teleport_stamp_s is not None and t_s <= self.teleport_stamp_s
        ):
            self.counts["teleport_stale"] += 1
            return Verdict.STALE
        if not all(math.isfinite(v) for v in (x_m, y_m, yaw_rad, speed_mps)):
            self.counts["teleport_not_finite"] += 1
            return Verdict.STALE
        t = self._stamp(t_s, now_s)
        z = np.array([x_m, y_m, wrap_angle(yaw_rad)])
        self._restart(t, z, None, speed_mps=speed_mps, yaw_rate_radps=0.0)
        self.teleport_stamp_s = t_s  # the readings' own stamps are compared with it
        self.counts["teleport_applied"] += 1
        return Verdict.TELEPORT

    # ------------------------------------------------------------------ output
    def estimate(self, now_s: float) -> Estimate:
        """The state predicted to `now_s` [s] (at most ``max_prediction_s`` past the newest
        measurement); an uninitialised estimator gives zeros, invalid."""
        st = self.settings
        newest = self.beliefs[-1] if self.beliefs else self.base
        if newest is None:
            return Estimate(now_s, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, self.steering_rad,
                            np.eye(len(Ekf)), None, math.inf, True, False)
        t = min(now_s, newest.t_s + st.max_prediction_s)
        b = predict(newest, t, self.noise)
        s = b.s
        age = now_s - self.pose_stamp_s if self.pose_stamp_s is not None else math.inf
        return Estimate(
            t_s=now_s,
            x_m=float(s[Ekf.X]),
            y_m=float(s[Ekf.Y]),
            yaw_rad=float(s[Ekf.YAW]),
            speed_mps=float(s[Ekf.V]),
            yaw_rate_radps=float(s[Ekf.R]),
            bias_radps=float(s[Ekf.BIAS]),
            steering_rad=self.steering_rad,
            cov=b.P,
            pose_stamp_s=self.pose_stamp_s,
            pose_age_s=age,
            degraded=age > st.degraded_after_s,
            valid=age <= st.invalid_after_s,
        )

    # ------------------------------------------------------------------ history
    def _next_order(self) -> int:
        self._order += 1
        return self._order

    def _index(self, t_s: float) -> int:
        """Where an event at `t_s` goes (after the events of the same stamp)."""
        return bisect_right(self.events, (t_s, math.inf), key=_event_key)  # no list built

    def _belief_before(self, k: int) -> Belief:
        assert self.base is not None
        return self.beliefs[k - 1] if k > 0 else self.base

    def _apply(self, b: Belief, e: _Event) -> Belief:
        b = predict(b, e.t_s, self.noise)
        if e.kind is _Kind.POSE:
            return update_pose(b, e.z, e.R)  # type: ignore[arg-type]
        if e.kind is _Kind.SPEED:
            return update_speed(b, float(e.z[0]), float(e.R))  # type: ignore[arg-type]
        if e.kind is _Kind.YAW_RATE:
            return update_yaw_rate(b, float(e.z[0]), float(e.R))  # type: ignore[arg-type]
        return update_gyro(b, float(e.z[0]), float(e.R))  # type: ignore[arg-type]

    def _insert(self, k: int, e: _Event) -> None:
        """Insert `e` at `k`, recompute the beliefs from there, drop what left the history."""
        self.events.insert(k, e)
        del self.beliefs[k:]
        b = self._belief_before(k)
        for ev in self.events[k:]:
            b = self._apply(b, ev)
            self.beliefs.append(b)
        if not (np.all(np.isfinite(b.s)) and np.all(np.isfinite(b.P))):
            self.counts["filter_not_finite"] += 1
            self.reset()
            return
        self._prune()

    def _prune(self) -> None:
        horizon = self.events[-1].t_s - self.settings.history_s
        n = 0
        while n < len(self.events) and self.events[n].t_s < horizon:
            n += 1
        if n:
            self.base = self.beliefs[n - 1]
            del self.events[:n]
            del self.beliefs[:n]

    def _restart(
        self,
        t_s: float,
        z: np.ndarray,
        R: np.ndarray | None,
        speed_mps: float | None = None,
        yaw_rate_radps: float | None = None,
    ) -> None:
        """Start the filter at pose `z` taken at `t_s` (covariance `R`, None: the settings'
        init stds), keeping the later odometry and IMU. Speed and yaw rate: the given ones,
        else those the filter had (before the first pose: the newest readings)."""
        if self.base is not None:
            last = self.beliefs[-1] if self.beliefs else self.base
            speed, rate, bias = last.s[Ekf.V], last.s[Ekf.R], last.s[Ekf.BIAS]
        else:
            speed, rate, bias = self._start_speed, self._start_yaw_rate, 0.0
        if speed_mps is not None:
            speed = speed_mps
        if yaw_rate_radps is not None:
            rate = yaw_rate_radps
        later = [e for e in self.events if e.t_s > t_s and e.kind is not _Kind.POSE]
        self.base = initial_belief(
            t_s, float(z[0]), float(z[1]), float(z[2]), self.noise, speed, rate, bias, R
        )
        self.events, self.beliefs = [], []
        self.pose_stamp_s = t_s
        self._gated_run, self._last_gated = 0, None
        for e in later:
            self._insert(len(self.events), e)

    def _gated(self, t_s: float, z: np.ndarray, R: np.ndarray) -> Verdict:
        st = self.settings
        prev = self._last_gated
        agrees = (
            prev is not None
            and math.hypot(z[0] - prev[0], z[1] - prev[1]) <= st.reinit_agree_m
            and abs(wrap_angle(z[2] - prev[2])) <= st.reinit_agree_rad
        )
        self._gated_run = self._gated_run + 1 if agrees else 1
        self._last_gated = z
        if self._gated_run >= st.reinit_after_gated:
            self.counts["pose_reinit_after_gated"] += 1
            self._restart(t_s, z, R)
            return Verdict.REINIT
        self.counts["pose_gated"] += 1
        return Verdict.GATED
