"""The extended Kalman filter of the bridge: a planar car, maths only (no I/O, no clock).

State ``s`` (7,), indexed by ``Ekf`` (rear axle, map frame)::

    s = [x m, y m, yaw rad, v m/s, r rad/s, b rad/s, vy m/s]

``v`` is the longitudinal speed, ``r`` the yaw rate, ``b`` the gyro's yaw-rate bias, ``vy``
the rear axle's lateral velocity (body frame, left +). ``vy`` earns its place because a
racing car's rear axle slides: in a turn it moves off its heading, and a unicycle model then
pulls the yaw towards the velocity; raising the position noise ``position_psd`` for the
slide instead costs accuracy (``benchmarks/localization_ekf.py`` compares the three; the
figures are in the README).
The bias earns its place because the IMU is what carries the yaw between poses (and
through a pose drop-out): a MEMS gyro's bias of 0.01-0.03 rad/s turns into 0.3-1 degree of
heading error in 0.5 s, and the pose stream makes it observable (``z_imu = r + b`` against
the yaw the poses show). Speed, yaw rate and ``vy`` are random walks driven by the odometry
and IMU updates (and the poses), so no input model of the car is needed.

Prediction over ``dt`` (midpoint heading, exact for a constant yaw rate to second order)::

    yaw_m = yaw + r dt / 2
    x += (v cos(yaw_m) - vy sin(yaw_m)) dt,   y += (v sin(yaw_m) + vy cos(yaw_m)) dt,
    yaw += r dt,   v, r, b, vy unchanged
    P = F P F^T + Q(dt)

with ``F`` the Jacobian and ``Q`` white acceleration noise: q_a on v along the heading
(``[[dt^3/3, dt^2/2], [dt^2/2, dt]] q_a`` for (position along the heading, v)), q_r the same
for (yaw, r), plus q_p dt on x, y, q_yaw dt on yaw, q_b dt on b and q_vy dt on vy
(``shared.config.localization.EkfNoise``).

Measurements ``z = H s + noise(R)`` with the Joseph-form update
``K = P H^T S^-1``, ``S = H P H^T + R``, ``P = (I - K H) P (I - K H)^T + K R K^T``:

- pose [x, y, yaw] (H selects X, Y, YAW; the yaw innovation wrapped into [-pi, pi));
  its squared Mahalanobis distance ``d2 = nu^T S^-1 nu`` is what the gate tests;
- wheel speed v; odometry yaw rate r; IMU yaw rate ``r + b``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from enum import IntEnum

import numpy as np

from shared.angles import wrap_angle
from shared.config.localization import EkfNoise


class Ekf(IntEnum):
    """Index of the EKF state vector and covariance."""

    X = 0
    Y = 1
    YAW = 2
    V = 3
    R = 4
    BIAS = 5
    VY = 6


#: State dimension.
N = len(Ekf)
#: ``Ekf`` as plain ints for the hot path (an IntEnum index costs a conversion each time).
_X, _Y, _YAW, _V, _R, _BIAS, _VY = (int(i) for i in Ekf)
_POSE_ROWS = (Ekf.X, Ekf.Y, Ekf.YAW)
#: The pose block of P as a view (X, Y, YAW are the first three rows), not a fancy-index copy.
_POSE_BLOCK = np.s_[: Ekf.YAW + 1, : Ekf.YAW + 1]
assert _POSE_ROWS == tuple(range(Ekf.YAW + 1))
_H_POSE = np.zeros((3, N))
_H_POSE[0, Ekf.X] = _H_POSE[1, Ekf.Y] = _H_POSE[2, Ekf.YAW] = 1.0
_H_SPEED = np.zeros((1, N))
_H_SPEED[0, Ekf.V] = 1.0
_H_YAW_RATE = np.zeros((1, N))
_H_YAW_RATE[0, Ekf.R] = 1.0
_H_GYRO = np.zeros((1, N))
_H_GYRO[0, Ekf.R] = _H_GYRO[0, Ekf.BIAS] = 1.0
_EYE = np.eye(N)
#: the state rows each scalar measurement sums (its ``H``'s ones)
_ROWS_SPEED, _ROWS_YAW_RATE, _ROWS_GYRO = (_V,), (_R,), (_R, _BIAS)


@dataclass(frozen=True, slots=True)
class Belief:
    """Mean (7,) and covariance (7, 7) of the state (index with ``Ekf``), at `t_s` [s]."""

    t_s: float
    s: np.ndarray
    P: np.ndarray


def initial_belief(
    t_s: float,
    x_m: float,
    y_m: float,
    yaw_rad: float,
    noise: EkfNoise,
    speed_mps: float = 0.0,
    yaw_rate_radps: float = 0.0,
    bias_radps: float = 0.0,
    pose_cov: np.ndarray | None = None,
) -> Belief:
    """A belief at a pose: covariance from `noise`'s init_* stds (the pose's own 3x3
    `pose_cov`, if given, for x, y, yaw)."""
    s = np.array(
        [x_m, y_m, wrap_angle(yaw_rad), speed_mps, yaw_rate_radps, bias_radps, 0.0], dtype=float
    )
    P = np.diag(
        [
            noise.init_position_std_m**2,
            noise.init_position_std_m**2,
            noise.init_yaw_std_rad**2,
            noise.init_speed_std_mps**2,
            noise.init_yaw_rate_std_radps**2,
            noise.init_bias_std_radps**2,
            noise.init_lateral_std_mps**2,
        ]
    )
    if pose_cov is not None:
        P[np.ix_(_POSE_ROWS, _POSE_ROWS)] = np.maximum(pose_cov, pose_cov.T)
    return Belief(t_s, s, P)


def predict(b: Belief, t_s: float, noise: EkfNoise) -> Belief:
    """The belief moved to `t_s` [s] by the motion model (module docstring); a `t_s` at or
    before ``b.t_s`` returns `b` unchanged.

    Written for the filter's hot path (every measurement and every output predicts: 55 000
    times in a two-lap bench run): plain ``int`` indices and element-wise ``Q`` (the same
    arithmetic, bit for bit, as ``outer(h, h) k`` with ``h = (cos, sin)``), half the time of
    fancy indexing.
    """
    dt = t_s - b.t_s
    if not dt > 0.0:
        return b
    x, y, yaw, v, r, bias, vy = b.s.tolist()
    yaw_m = yaw + 0.5 * r * dt
    c, s_ = math.cos(yaw_m), math.sin(yaw_m)
    dx = (v * c - vy * s_) * dt
    dy = (v * s_ + vy * c) * dt
    s = np.array([x + dx, y + dy, wrap_angle(yaw + r * dt), v, r, bias, vy])
    F = _EYE.copy()
    F[_X, _YAW] = -dy
    F[_X, _V] = c * dt
    F[_X, _VY] = -s_ * dt
    F[_X, _R] = -0.5 * dy * dt
    F[_Y, _YAW] = dx
    F[_Y, _V] = s_ * dt
    F[_Y, _VY] = c * dt
    F[_Y, _R] = 0.5 * dx * dt
    F[_YAW, _R] = dt
    qa, qr = noise.accel_psd, noise.yaw_accel_psd
    q_pos = noise.position_psd * dt
    k3 = qa * dt**3 / 3.0  # along the heading h = (c, s_): outer(h, h) k3
    k2 = qa * dt * dt / 2.0
    Q = np.zeros((N, N))
    Q[_X, _X] = c * c * k3 + q_pos
    Q[_X, _Y] = Q[_Y, _X] = c * s_ * k3
    Q[_Y, _Y] = s_ * s_ * k3 + q_pos
    Q[_X, _V] = Q[_V, _X] = c * k2
    Q[_Y, _V] = Q[_V, _Y] = s_ * k2
    Q[_V, _V] = qa * dt
    Q[_YAW, _YAW] = qr * dt**3 / 3.0 + noise.yaw_psd * dt
    Q[_YAW, _R] = Q[_R, _YAW] = qr * dt * dt / 2.0
    Q[_R, _R] = qr * dt
    Q[_BIAS, _BIAS] = noise.bias_psd * dt
    Q[_VY, _VY] = noise.lateral_accel_psd * dt
    P = F @ b.P @ F.T + Q
    return Belief(t_s, s, 0.5 * (P + P.T))


def _update(b: Belief, H: np.ndarray, nu: np.ndarray, R: np.ndarray) -> Belief:
    """The Kalman correction of `b` by a measurement of model `H` (m, 7), innovation `nu`
    (m,) and covariance `R` (m, m), in Joseph form. The reference the fast paths below
    (``_update_rows``, ``update_pose``) reproduce bit for bit (tests)."""
    S = H @ b.P @ H.T + R
    K = np.linalg.solve(S, H @ b.P).T  # P H^T S^-1 (S and P symmetric)
    s = b.s + K @ nu
    s[Ekf.YAW] = wrap_angle(s[Ekf.YAW])
    A = _EYE - K @ H
    P = A @ b.P @ A.T + K @ R @ K.T
    return Belief(b.t_s, s, 0.5 * (P + P.T))


def _update_rows(b: Belief, rows: tuple[int, ...], h: np.ndarray, nu: float, var: float
                 ) -> Belief:
    """``_update`` for a scalar measurement ``z = sum(s[rows])`` (`h` (7,): ones at `rows`),
    innovation `nu` and variance `var`, on the filter's hot path (every odometry and gyro
    sample, and again on each replay).

    The same arithmetic, bit for bit: ``H P`` is the sum of `rows` of ``P`` (the other
    products are exact zeros), ``S`` a float, ``np.linalg.solve`` of a 1x1 system multiplies
    by ``1 / S`` (what LAPACK does) and the outer products with one inner term are single
    products; only the small-matrix calls around them are gone (15 -> 10 us a call).
    """
    P = b.P
    hp = P[rows[0]] + P[rows[1]] if len(rows) == 2 else P[rows[0]].copy()  # H P (7,)
    S = (hp[rows[0]] + hp[rows[1]] if len(rows) == 2 else hp[rows[0]]) + var
    k = hp * (1.0 / S)  # K (7,)
    s = b.s + k * nu
    s[_YAW] = wrap_angle(s[_YAW])
    A = _EYE - np.outer(k, h)
    P = A @ P @ A.T + np.outer(k * var, k)
    return Belief(b.t_s, s, 0.5 * (P + P.T))


def _pose_nu(b: Belief, z: np.ndarray) -> np.ndarray:
    """The innovation (3,) of a pose `z` = [x, y, yaw]."""
    return np.array([z[0] - b.s[_X], z[1] - b.s[_Y], wrap_angle(z[2] - b.s[_YAW])])


def pose_innovation(b: Belief, z: np.ndarray, R: np.ndarray) -> tuple[np.ndarray, float]:
    """Innovation (3,) of a pose `z` = [x, y, yaw] with covariance `R` (3, 3), and its
    squared Mahalanobis distance ``nu^T (H P H^T + R)^-1 nu``."""
    nu = _pose_nu(b, z)
    S = b.P[_POSE_BLOCK] + R
    return nu, float(nu @ np.linalg.solve(S, nu))


def update_pose(b: Belief, z: np.ndarray, R: np.ndarray) -> Belief:
    """Correct `b` with a pose `z` = [x m, y m, yaw rad] of covariance `R` (3, 3).

    ``_update`` with ``H = _H_POSE`` bit for bit: ``H P`` is the first three rows of ``P``
    and ``K H`` is ``K`` in the first three columns (one exact product each)."""
    nu = _pose_nu(b, z)
    P = b.P
    K = np.linalg.solve(P[_POSE_BLOCK] + R, P[: _YAW + 1]).T  # (7, 3)
    s = b.s + K @ nu
    s[_YAW] = wrap_angle(s[_YAW])
    A = _EYE.copy()
    A[:, : _YAW + 1] -= K
    P = A @ P @ A.T + K @ R @ K.T
    return Belief(b.t_s, s, 0.5 * (P + P.T))


def update_speed(b: Belief, speed_mps: float, std_mps: float) -> Belief:
    """Correct `b` with a wheel speed [m/s] of std `std_mps`."""
    return _update_rows(b, _ROWS_SPEED, _H_SPEED[0], speed_mps - float(b.s[_V]), std_mps**2)


def update_yaw_rate(b: Belief, yaw_rate_radps: float, std_radps: float) -> Belief:
    """Correct `b` with an unbiased yaw rate (wheel odometry) [rad/s]."""
    return _update_rows(b, _ROWS_YAW_RATE, _H_YAW_RATE[0], yaw_rate_radps - float(b.s[_R]),
                        std_radps**2)


def update_gyro(b: Belief, yaw_rate_radps: float, std_radps: float) -> Belief:
    """Correct `b` with a gyro yaw rate ``z = r + b`` [rad/s]."""
    nu = yaw_rate_radps - float(b.s[_R]) - float(b.s[_BIAS])
    return _update_rows(b, _ROWS_GYRO, _H_GYRO[0], nu, std_radps**2)


def pose_covariance(cov: np.ndarray | None, noise: EkfNoise) -> np.ndarray:
    """The 3x3 covariance [x, y, yaw] a pose is applied with: its own (floored at
    ``min_pose_std_m`` / ``min_pose_yaw_std_rad`` on the diagonal) or the settings'."""
    if cov is None:
        p, a = noise.pose_position_std_m**2, noise.pose_yaw_std_rad**2
        return np.diag([p, p, a])
    R = np.array(cov, dtype=float)
    floor = np.array([noise.min_pose_std_m, noise.min_pose_std_m, noise.min_pose_yaw_std_rad])
    d = np.maximum(np.diag(R), floor**2)
    R[np.diag_indices(3)] = d
    # keep it positive definite: clip correlations to |rho| <= 0.99
    sd = np.sqrt(d)
    lim = 0.99 * np.outer(sd, sd)
    R = np.clip(0.5 * (R + R.T), -lim, lim)
    R[np.diag_indices(3)] = d
    if np.linalg.eigvalsh(R)[0] <= 0.0:  # correlations no covariance can have
        return np.diag(d)
    return R
