"""Direct collocation of the minimum-time lap: the NLP, its bounds and its initial guess.

Pure maths, no I/O. The problem and the transcription are described in
``services.planner.mintime.ocp``; this module builds them for CasADi's ``nlpsol``.

Decision vector (every state and input scaled by ``state_scale`` / ``input_scale`` so that
IPOPT sees values of order one)::

    z = [vec(Z) (NX, d N), vec(U) (NU, N)]

``Z[:, j N + k]`` is the state at collocation point ``j`` (``tau_j``, j = 0..d-1) of
interval ``k``; the last point (``tau = 1``) of interval ``k`` is the grid node ``k + 1``
(mod N), which is also the start of interval ``k + 1``. ``U[:, k]`` acts on interval ``k``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import casadi as ca
import numpy as np

from services.planner.mintime.model import (
    BETA,
    DELTA,
    N_,
    NU,
    NX,
    XI,
    R,
    SpatialModel,
    V,
    friction_circle_mps2,
    point_mass_speed,
    reserve_ramp,
)
from services.planner.mintime.track import ReferenceLine, windowed_min
from shared.config.vehicle import DynamicVehicleParams

#: Radau IIA collocation points on [0, 1] (degree 3).
RADAU_TAU = tuple(float(t) for t in ca.collocation_points(3, "radau"))
#: 1 - n kappa stays above this (the curvilinear frame is singular at the centre of curvature).
NORMAL_SINGULARITY_MARGIN = 0.05
#: Regularisation weights [s] (see ``services.planner.mintime.ocp``).
REG_STEERING_RATE = 1e-4
REG_ACCEL_STEP = 1e-4
#: Loose bounds on the heading error [rad], slip angle [rad] and yaw rate [rad/s] (never
#: active at a solution; they keep IPOPT's trial points physical).
XI_BOUND_RAD = 1.2
BETA_BOUND_RAD = 1.0
YAW_RATE_BOUND_RADPS = 60.0


def radau_matrices(tau: tuple[float, ...]) -> tuple[np.ndarray, np.ndarray]:
    """Collocation matrices of the points ``[0, *tau]`` on [0, 1].

    Returns:
        (C, B): ``C[r, j] = dL_r/dtau (tau_j)`` for the Lagrange basis ``L_r`` of the points
        ``[0, *tau]`` (d+1, d+1), evaluated at all of them; ``B[j] = integral_0^1 L_j``
        (d+1,). The collocation equations are ``sum_r C[r, j] x_r = h f(x_j)`` for j >= 1.
    """
    pts = np.concatenate([[0.0], np.asarray(tau, dtype=float)])
    m = pts.size
    c = np.zeros((m, m))
    b = np.zeros(m)
    for r in range(m):
        poly = np.poly1d([1.0])
        for k in range(m):
            if k != r:
                poly *= np.poly1d([1.0, -pts[k]]) / (pts[r] - pts[k])
        c[r] = np.polyder(poly)(pts)
        b[r] = np.polyint(poly)(1.0)
    return c, b


@dataclass(frozen=True, eq=False)
class Grid:
    """The reference sampled at the grid nodes and the collocation points.

    Attributes:
        n: intervals N; h: their length [m].
        s_nodes: (N,) node arc lengths [m]; kappa_nodes: (N,) curvature there [1/m].
        kappa_col: (d, N) curvature at collocation point j of interval k [1/m].
        kappa_front, kappa_rear: (N,) effective curvature [1/m] over half the car's length
            ahead of and behind each node (for the footprint's corners).
        w_left, w_right: (N,) widths at the nodes [m], each the minimum over the reach of
            the footprint (half its diagonal) plus one interval on either side.
        w_left_col, w_right_col: (d, N) widths at the collocation points [m].
    """

    n: int
    h: float
    s_nodes: np.ndarray
    kappa_nodes: np.ndarray
    kappa_col: np.ndarray
    kappa_front: np.ndarray
    kappa_rear: np.ndarray
    w_left: np.ndarray
    w_right: np.ndarray
    w_left_col: np.ndarray
    w_right_col: np.ndarray


def make_grid(ref: ReferenceLine, p: DynamicVehicleParams, ds_m: float) -> Grid:
    """The grid of spacing about `ds_m` [m] on `ref` (``N = max(20, round(L / ds))``)."""
    n = max(20, round(ref.length_m / ds_m))
    h = ref.length_m / n
    s_nodes = np.arange(n) * h
    nodes = ref.points(s_nodes)
    d = len(RADAU_TAU)
    col = ref.points((s_nodes[None, :] + h * np.asarray(RADAU_TAU)[:, None]).reshape(-1))
    w_l, w_r = ref.widths(nodes.xy)
    w_l_col, w_r_col = ref.widths(col.xy)
    half = math.ceil(0.5 * math.hypot(p.length_m, p.width_m) / h) + 1
    return Grid(
        n,
        h,
        s_nodes,
        nodes.kappa_1pm,
        col.kappa_1pm.reshape(d, n),
        ref.effective_curvature(s_nodes, 0.5 * p.length_m),
        ref.effective_curvature(s_nodes, -0.5 * p.length_m),
        windowed_min(w_l, half),
        windowed_min(w_r, half),
        w_l_col.reshape(d, n),
        w_r_col.reshape(d, n),
    )


def state_scale(p: DynamicVehicleParams, v_max: float) -> np.ndarray:
    """(NX,) typical magnitudes: n, xi, v, beta, r, delta."""
    return np.array([0.5, 0.3, v_max, 0.1, v_max, p.steering_max_rad])


def input_scale(p: DynamicVehicleParams, m: SpatialModel) -> np.ndarray:
    """(NU,) typical magnitudes: steering rate, acceleration."""
    return np.array([p.steering_rate_max_radps, m.accel_limit_mps2])


@dataclass(frozen=True, eq=False)
class Transcription:
    """The NLP ready for ``nlpsol`` and how to read its solution.

    Attributes:
        nlp: ``{"x": z, "f": J, "g": g}`` (MX of mapped SX functions: the derivatives keep
            the per-point structure, so building the solver takes about a second where a
            flat SX graph took ten).
        lbx, ubx, lbg, ubg: bounds (numpy).
        lap_time: ``Function(z) -> T`` [s] (the objective without regularisation).
        grid: the grid; x_scale (NX,), u_scale (NU,): the scales.
    """

    nlp: dict
    lbx: np.ndarray
    ubx: np.ndarray
    lbg: np.ndarray
    ubg: np.ndarray
    lap_time: ca.Function
    grid: Grid
    x_scale: np.ndarray
    u_scale: np.ndarray

    def pack(self, z_states: np.ndarray, u: np.ndarray) -> np.ndarray:
        """Decision vector from unscaled (NX, d N) collocation states and (NU, N) inputs."""
        zs = z_states / self.x_scale[:, None]
        us = u / self.u_scale[:, None]
        return np.concatenate([zs.reshape(-1, order="F"), us.reshape(-1, order="F")])

    def unpack(self, z: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(states (NX, d N), inputs (NU, N)), unscaled, from a decision vector."""
        n, d = self.grid.n, len(RADAU_TAU)
        z = np.asarray(z, dtype=float).reshape(-1)
        k = NX * d * n
        zs = z[:k].reshape(NX, d * n, order="F") * self.x_scale[:, None]
        us = z[k:].reshape(NU, n, order="F") * self.u_scale[:, None]
        return zs, us


def transcribe(
    m: SpatialModel,
    p: DynamicVehicleParams,
    g: Grid,
    v_max: float,
    v_min: float,
    margin: float,
    speed_reserve: tuple[float, ...] | None = None,
) -> Transcription:
    """The collocation NLP of the lap (see ``services.planner.mintime.ocp``).

    `speed_reserve` ``(v_r [m/s], w [m/s], k [s], m_r [m][, v_m [m/s]])``: the high-speed
    reserve's steering-rate cost ``k h sum_k S_k (sv_k / sv_max)^2`` with ``S_k`` the
    reserve's ramp (``model.reserve_ramp``) from ``v_r`` at interval k's starting speed, and
    its margin: the footprint ``m_r S_m`` further inside the boundaries at each node
    (``S_m`` the ramp from ``v_m``, default ``v_r``, at the node's speed); None: neither
    (k = 0, m_r = 0: that one not)."""
    n, h, d = g.n, g.h, len(RADAU_TAU)
    c_mat, b_vec = radau_matrices(RADAU_TAU)
    sx, su = state_scale(p, v_max), input_scale(p, m)
    zs = ca.MX.sym("Z", NX, d * n)
    us = ca.MX.sym("U", NU, n)
    sx_dm, su_dm = ca.DM(sx), ca.DM(su)
    states = zs * ca.repmat(sx_dm, 1, d * n)
    inputs = us * ca.repmat(su_dm, 1, n)
    kappa_row = ca.DM(g.kappa_col.reshape(1, -1))  # column j N + k
    u_tiled = ca.repmat(inputs, 1, d)
    ode = m.ode.map(d * n)
    dx_ds, dt_ds, _v_dot, _chi_dot = ode(states, u_tiled, kappa_row)
    blocks = [zs[:, j * n : (j + 1) * n] for j in range(d)]
    end = blocks[-1]
    start = ca.horzcat(end[:, n - 1], end[:, : n - 1])  # interval k starts at node k
    inv_sx = ca.repmat(1.0 / sx_dm, 1, n)
    eqs = []
    for j in range(1, d + 1):
        lhs = c_mat[0, j] * start
        for r in range(1, d + 1):
            lhs += c_mat[r, j] * blocks[r - 1]
        eqs.append(ca.vec(lhs - h * dx_ds[:, (j - 1) * n : j * n] * inv_sx))
    lap_time = 0
    for j in range(d):
        lap_time += h * b_vec[j + 1] * ca.sum2(dt_ds[:, j * n : (j + 1) * n])
    reg = REG_STEERING_RATE * h * ca.sumsqr(us[0, :])
    da = us[1, :] - ca.horzcat(us[1, n - 1], us[1, : n - 1])
    reg += REG_ACCEL_STEP * ca.sumsqr(da)
    g_parts, lbg, ubg = list(eqs), [np.zeros(NX * n * d)], [np.zeros(NX * n * d)]
    # path constraints at every collocation point and at each interval's start, each with
    # the interval's own input: at a node the input jumps, and both sides must hold
    start_states = ca.horzcat(states[:, d * n - 1], states[:, (d - 1) * n : d * n - 1])
    if speed_reserve is not None and speed_reserve[2] > 0.0:
        v_r, width, weight = speed_reserve[:3]
        ramp = reserve_ramp(start_states[V, :], v_r, width)
        reg += weight * h * ca.sum2(ramp * us[0, :] ** 2)
    path_x = ca.horzcat(states, start_states)
    path_u = ca.horzcat(u_tiled, inputs)
    n_path = (d + 1) * n
    tyres = m.tyres.map(n_path)(path_x, path_u)
    if m.friction_limited and m.reserve is None:
        g_parts.append(ca.vec(tyres[0:2, :]))
        lbg.append(np.full(2 * n_path, -np.inf))
        ubg.append(np.tile([m.axle_use_max(), m.axle_use_max(rear=True)], n_path))
    elif m.friction_limited:  # the high-speed reserve: the bound falls with the speed
        bounds = ca.vertcat(m.use_bound(path_x[V, :]), m.use_bound(path_x[V, :], rear=True))
        g_parts.append(ca.vec(tyres[0:2, :] - bounds))
        lbg.append(np.full(2 * n_path, -np.inf))
        ubg.append(np.zeros(2 * n_path))
    if m.yaw_stability is not None:  # the yaw's divergence under braking bounded
        g_parts.append(ca.vec(m.yaw_stability.map(n_path)(path_x, path_u)))
        lbg.append(np.zeros(n_path))
        ubg.append(np.full(n_path, np.inf))
    if m.peak_slip_rad is not None:
        g_parts.append(ca.vec(tyres[2:4, :]))
        peak = np.tile(np.asarray(m.peak_slip_rad), n_path)
        lbg.append(-peak)
        ubg.append(peak)
    if m.servo_time_constant_s is not None:  # the servo's target within the steering limits
        g_parts.append(ca.vec(path_x[DELTA, :] + m.servo_time_constant_s * path_u[0, :]))
        lbg.append(np.full(n_path, p.steering_min_rad))
        ubg.append(np.full(n_path, p.steering_max_rad))
    if v_max > p.v_switch_mps:
        g_parts.append(ca.vec(path_x[V, :] * path_u[1, :]))
        lbg.append(np.full(n_path, -np.inf))
        ubg.append(np.full(n_path, p.accel_max_mps2 * p.v_switch_mps))
    end_states = states[:, (d - 1) * n :]
    k_front = ca.DM(np.roll(g.kappa_front, -1).reshape(1, -1))
    k_rear = ca.DM(np.roll(g.kappa_rear, -1).reshape(1, -1))
    corners = m.footprint.map(n)(end_states, k_front, k_rear)
    w_l_next, w_r_next = np.roll(g.w_left, -1), np.roll(g.w_right, -1)
    if speed_reserve is not None and speed_reserve[3] > 0.0:  # a wider tube at speed
        v_r, width, _k, m_r = speed_reserve[:4]
        v_m = speed_reserve[4] if len(speed_reserve) > 4 else v_r
        extra = ca.repmat(m_r * reserve_ramp(end_states[V, :], v_m, width), 4, 1)
        g_parts += [ca.vec(corners + extra), ca.vec(corners - extra)]
        lbg += [np.full(4 * n, -np.inf), np.repeat(-(w_r_next - margin), 4)]
        ubg += [np.repeat(w_l_next - margin, 4), np.full(4 * n, np.inf)]
    else:
        g_parts.append(ca.vec(corners))
        lbg.append(np.repeat(-(w_r_next - margin), 4))
        ubg.append(np.repeat(w_l_next - margin, 4))
    z = ca.vertcat(ca.vec(zs), ca.vec(us))
    lbx, ubx = _state_bounds(p, m, g, v_max, v_min, margin, sx, su)
    return Transcription(
        nlp={"x": z, "f": lap_time + reg, "g": ca.vertcat(*g_parts)},
        lbx=lbx,
        ubx=ubx,
        lbg=np.concatenate(lbg),
        ubg=np.concatenate(ubg),
        lap_time=ca.Function("lap_time", [z], [lap_time]),
        grid=g,
        x_scale=sx,
        u_scale=su,
    )


def _state_bounds(
    p: DynamicVehicleParams,
    m: SpatialModel,
    g: Grid,
    v_max: float,
    v_min: float,
    margin: float,
    sx: np.ndarray,
    su: np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:
    """Scaled box bounds of z: the CoG inside the track (and off the frame's singularity)."""
    d, n = len(RADAU_TAU), g.n
    kappa = g.kappa_col.reshape(-1)
    n_hi = g.w_left_col.reshape(-1) - margin
    n_lo = -(g.w_right_col.reshape(-1) - margin)
    with np.errstate(divide="ignore"):
        lim = (1.0 - NORMAL_SINGULARITY_MARGIN) / kappa
    n_hi = np.where(kappa > 0, np.minimum(n_hi, lim), n_hi)
    n_lo = np.where(kappa < 0, np.maximum(n_lo, lim), n_lo)
    lo = np.zeros((NX, d * n))
    hi = np.zeros((NX, d * n))
    lo[N_], hi[N_] = n_lo, n_hi
    lo[XI], hi[XI] = -XI_BOUND_RAD, XI_BOUND_RAD
    lo[V], hi[V] = v_min, min(v_max, p.v_max_mps)
    lo[BETA], hi[BETA] = -BETA_BOUND_RAD, BETA_BOUND_RAD
    lo[R], hi[R] = -YAW_RATE_BOUND_RADPS, YAW_RATE_BOUND_RADPS
    lo[DELTA], hi[DELTA] = p.steering_min_rad, p.steering_max_rad
    ulo = np.tile([[p.steering_rate_min_radps], [-m.accel_limit_mps2]], (1, n))
    uhi = np.tile([[p.steering_rate_max_radps], [m.accel_limit_mps2]], (1, n))
    lbx = np.concatenate([(lo / sx[:, None]).reshape(-1, order="F"),
                          (ulo / su[:, None]).reshape(-1, order="F")])
    ubx = np.concatenate([(hi / sx[:, None]).reshape(-1, order="F"),
                          (uhi / su[:, None]).reshape(-1, order="F")])
    return lbx, ubx


def initial_guess(
    g: Grid, p: DynamicVehicleParams, m: SpatialModel, v_max: float, v_min: float
) -> tuple[np.ndarray, np.ndarray]:
    """(states (NX, d N), inputs (NU, N)): the centreline at the point-mass speed profile
    (friction circle ``min_i mu_i g``), kinematic steering ``atan(L kappa)`` and slip
    ``atan(lr tan(delta) / L)``, heading error ``-beta`` (the velocity along the tangent)."""
    d = len(RADAU_TAU)
    a_lim = m.accel_limit_mps2
    v_pm = point_mass_speed(g.kappa_nodes, g.h, v_max, friction_circle_mps2(p), a_lim, a_lim)
    v_nodes = np.clip(v_pm, v_min, v_max)
    s_col = (g.s_nodes[None, :] + g.h * np.asarray(RADAU_TAU)[:, None]).reshape(-1)
    length = g.n * g.h
    v = np.interp(s_col, np.append(g.s_nodes, length), np.append(v_nodes, v_nodes[0]))
    kappa = g.kappa_col.reshape(-1)
    wb = p.lf_m + p.lr_m
    delta = np.clip(np.arctan(wb * kappa), p.steering_min_rad, p.steering_max_rad)
    beta = np.arctan(p.lr_m * np.tan(delta) / wb)
    x = np.zeros((NX, d * g.n))
    x[V], x[BETA], x[R], x[DELTA], x[XI] = v, beta, v * kappa, delta, -beta
    u = np.zeros((NU, g.n))
    u[1] = np.clip(v_nodes * (np.roll(v_nodes, -1) - v_nodes) / g.h, -a_lim, a_lim)
    d_nodes = np.clip(np.arctan(wb * g.kappa_nodes), p.steering_min_rad, p.steering_max_rad)
    u[0] = np.clip(v_nodes * (np.roll(d_nodes, -1) - d_nodes) / g.h,
                   p.steering_rate_min_radps, p.steering_rate_max_radps)
    return x, u

