"""The raceline baseline of the paper's Table I (RDM+OTG): a global path, a speed profile,
a path tracker. Pure maths, no I/O.

The paper compares CiMPCC with a path-velocity decomposition: a minimum-curvature path
(RDM, Braghin et al. 2008), a velocity plan (OTG, Werling et al. 2010) and a pursuit
tracker (Becker et al. 2023). Ours, built once per track:

1. **Path** (``min_curvature_offsets``): the centreline resampled every ``ds_m``, each point
   moved along its left normal by ``alpha_i``; minimise the integral of the squared
   curvature of the moved points, subject to ``-(w_right - m) <= alpha_i <= w_left - m``
   with ``m`` the margin (IPOPT on the exact discrete curvature).
2. **Speed** (``speed_profile``): ``v <= min(v_max, sqrt(a_lat / |kappa|))``, then a
   forward pass with ``a_accel`` and a backward pass with ``a_brake``, around the loop.
   (Werling's OTG plans jerk-optimal quintics in a Frenet frame; a forward-backward
   profile is the usual simplification and what we do.)
3. **Tracker** (``RacelinePlanner.step``): pure pursuit from the rear axle towards the
   raceline point ``l_0 + k v`` ahead, ``delta = atan(2 L sin(a) / l_d)``; the speed
   command is the profile ``speed_preview_s`` ahead of the car (actuation delays).
   (Becker et al.'s model- and acceleration-based pursuit adds a model of the car; plain
   pure pursuit is what we do.)

``RacelinePlanner`` has the ``Planner`` interface the bench's closed loop uses (``step``,
``reset``, ``settings``), so the bench races it like the MPC methods.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass
from functools import cached_property

import casadi as ca
import numpy as np

from services.planner.planner import BRAKING, RECOVERING, SOLVED, DriveCommand, SolveResult
from services.planner.recovery import Recovery
from shared.config.planner import CurvatureSettings, PlannerSettings, RacelineSettings
from shared.curvature import track_profile
from shared.track import Track, TrackError

METHOD = "raceline"
#: IPOPT statuses accepted besides success: converged as far as its precision allows.
NEAR_OPTIMAL = frozenset({"Solved_To_Acceptable_Level", "Search_Direction_Becomes_Too_Small"})


#: Weight of the offset-smoothness term of the line's energy [1/m^3].
SMOOTHNESS_WEIGHT = 1e-3
#: The line keeps at most this share of the local bend radius on the inside of a bend.
INSIDE_RADIUS_SHARE = 0.5


class RacelineError(TrackError):
    """No raceline can be built on this track with these settings (a clear, one-line error
    in every shell, like any other unusable track)."""


@dataclass(frozen=True)
class Raceline:
    """A closed racing line with its speed profile.

    Attributes:
        track: the line as a ``Track`` (``xy`` the line, widths its distances to the
            boundaries), for projection and interpolation.
        offset_m: (n,) lateral offset of each point from the centreline [m] (left +).
        curvature_1pm: (n,) signed curvature of the line [1/m].
        speed_mps: (n,) planned speed at each point [m/s].
    """

    track: Track
    offset_m: np.ndarray
    curvature_1pm: np.ndarray
    speed_mps: np.ndarray

    def speed_at(self, s_m: float) -> float:
        """Planned speed [m/s] at arc length `s_m` of the line (periodic)."""
        s_cl, v_cl = self._closed_speed
        return float(np.interp(s_m % self.track.length_m, s_cl, v_cl))

    @cached_property
    def _closed_speed(self) -> tuple[np.ndarray, np.ndarray]:
        """(s, v) with the first point repeated at the lap length (for interpolation)."""
        return (np.append(self.track.s_m, self.track.length_m),
                np.append(self.speed_mps, self.speed_mps[0]))

    @property
    def lap_time_s(self) -> float:
        """Lap time of the profile itself [s] (what a perfect tracker would drive)."""
        t = self.track
        seg = np.hypot(*(np.roll(t.xy, -1, axis=0) - t.xy).T)
        v_mid = 0.5 * (self.speed_mps + np.roll(self.speed_mps, -1))
        return float(np.sum(seg / np.maximum(v_mid, 1e-3)))


def resample(track: Track, ds_m: float) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The centreline every ~`ds_m` [m]: (points (n, 2), left normals (n, 2), w_right, w_left)."""
    n = max(20, round(track.length_m / ds_m))
    s = np.arange(n) * track.length_m / n
    xy = track.point_at(s)
    d = np.roll(xy, -1, axis=0) - np.roll(xy, 1, axis=0)
    t = d / np.linalg.norm(d, axis=1, keepdims=True)
    normals = np.column_stack([-t[:, 1], t[:, 0]])
    w_r, w_l = track.interp_width(s)
    return xy, normals, np.asarray(w_r, dtype=float), np.asarray(w_l, dtype=float)


def min_curvature_offsets(
    xy: np.ndarray, normals: np.ndarray, lo: np.ndarray, hi: np.ndarray
) -> np.ndarray:
    """Offsets alpha (n,) [m] along `normals` that minimise the line's curvature energy.

    The line is ``p_i = xy_i + alpha_i * normals_i`` (closed). With ``a = p_i - p_(i-1)``,
    ``b = p_(i+1) - p_i``, the discrete (Menger) curvature at point i is
    ``kappa_i = 2 (a x b) / (|a| |b| |a + b|)``; minimise ``sum_i kappa_i^2 (|a| + |b|) / 2``
    (the integral of kappa^2 along the line) plus ``SMOOTHNESS_WEIGHT * sum_i
    (alpha_(i+1) - alpha_i)^2``, subject to ``lo <= alpha <= hi``. Exact
    curvature, so cutting a corner on the inside is not mistaken for straightening it (the
    bias of second differences of the points); solved with IPOPT from alpha = 0.

    Args:
        xy: (n, 2) centreline points [m], near-uniform spacing.
        normals: (n, 2) unit left normals.
        lo, hi: (n,) bounds [m] (lo < 0 < hi).

    Raises:
        RacelineError: the solver failed.
    """
    n = len(xy)
    alpha = ca.SX.sym("alpha", n)
    px = ca.DM(xy[:, 0]) + alpha * ca.DM(normals[:, 0])
    py = ca.DM(xy[:, 1]) + alpha * ca.DM(normals[:, 1])
    idx_prev = [(i - 1) % n for i in range(n)]
    idx_next = [(i + 1) % n for i in range(n)]
    ax, ay = px - px[idx_prev], py - py[idx_prev]
    bx, by = px[idx_next] - px, py[idx_next] - py
    la = ca.sqrt(ax**2 + ay**2)
    lb = ca.sqrt(bx**2 + by**2)
    lab = ca.sqrt((ax + bx) ** 2 + (ay + by) ** 2)
    kappa = 2 * (ax * by - ay * bx) / (la * lb * lab)
    energy = ca.sum1(kappa**2 * 0.5 * (la + lb))
    # a little smoothness of the offsets keeps IPOPT well conditioned where the coarse
    # source polyline has kinks (1e-3 per m^2 of offset change: negligible elsewhere)
    energy += SMOOTHNESS_WEIGHT * ca.sumsqr(alpha[idx_next] - alpha)
    solver = ca.nlpsol(
        "raceline_nlp",
        "ipopt",
        {"x": alpha, "f": energy},
        {"ipopt.print_level": 0, "print_time": False, "ipopt.sb": "yes",
         "ipopt.max_iter": 500, "ipopt.tol": 1e-6, "ipopt.acceptable_tol": 1e-4,
         "ipopt.acceptable_iter": 10},
    )
    sol = solver(x0=np.zeros(n), lbx=lo, ubx=hi)
    stats = solver.stats()
    alpha_opt = np.asarray(sol["x"], dtype=float).reshape(-1)
    status = str(stats.get("return_status", "unknown"))
    # "steps too small to matter" is IPOPT's way of saying it cannot improve further
    done = stats.get("success", False) or status in NEAR_OPTIMAL
    if not done or not np.all(np.isfinite(alpha_opt)):
        raise RacelineError("raceline", f"no minimum-curvature line (IPOPT: {status})")
    return np.clip(alpha_opt, lo, hi)


def speed_profile(
    curvature_1pm: np.ndarray, seg_m: np.ndarray, settings: RacelineSettings
) -> np.ndarray:
    """Speeds (n,) [m/s] on a closed line: lateral limit, then acceleration and braking.

    Args:
        curvature_1pm: (n,) curvature at the points [1/m].
        seg_m: (n,) length of the segment from point i to point i+1 [m].
        settings: accelerations and the speed cap.
    """
    kappa = np.abs(curvature_1pm)
    v = np.minimum(settings.v_max_mps, np.sqrt(settings.a_lat_mps2 / np.maximum(kappa, 1e-9)))
    n = len(v)
    for _ in range(2):  # twice around, so the loop closes
        for i in range(n):  # forward: accelerate at most a_accel
            j = (i + 1) % n
            v[j] = min(v[j], math.sqrt(v[i] ** 2 + 2 * settings.a_accel_mps2 * seg_m[i]))
        for i in range(n - 1, -1, -1):  # backward: brake at most a_brake
            j = (i + 1) % n
            v[i] = min(v[i], math.sqrt(v[j] ** 2 + 2 * settings.a_brake_mps2 * seg_m[i]))
    return v


def build_raceline(track: Track, settings: RacelineSettings) -> Raceline:
    """The minimum-curvature line and its speed profile on `track`."""
    xy, normals, w_r, w_l = resample(track, settings.ds_m)
    m = settings.margin_m
    lo, hi = -(w_r - m), w_l - m
    # on the inside of a bend no further than INSIDE_RADIUS_SHARE of its radius, so the
    # moved points never fold over (neighbouring normals cross at the centre of curvature)
    # (the raw curvature: the kinks of a coarse source polyline are the tightest bends)
    bend = Track("resampled", xy, w_r, w_l).signed_curvature()
    with np.errstate(divide="ignore"):
        radius = np.where(np.abs(bend) > 1e-9, INSIDE_RADIUS_SHARE / np.abs(bend), np.inf)
    hi = np.where(bend > 0, np.minimum(hi, radius), hi)
    lo = np.where(bend < 0, np.maximum(lo, -radius), lo)
    if np.any(lo >= hi):
        raise RacelineError(
            track.source, f"raceline margin {m} m leaves no room where the track is narrowest"
        )
    try:
        alpha = min_curvature_offsets(xy, normals, lo, hi)
    except RacelineError as exc:
        raise RacelineError(track.source, exc.problem) from None
    line = xy + alpha[:, None] * normals
    try:
        line_track = Track(f"{track.name}-raceline", line, w_r + alpha, w_l - alpha,
                           source=track.source)
    except TrackError as exc:
        problem = f"the raceline is not a valid loop ({exc.problem})"
        raise RacelineError(track.source, problem) from None
    kappa = line_track.signed_curvature()
    k = max(1, settings.curvature_smoothing_points)
    kappa = np.convolve(np.concatenate([kappa[-k:], kappa, kappa[:k]]),
                        np.ones(2 * k + 1) / (2 * k + 1), mode="same")[k:-k]
    seg = np.hypot(*(np.roll(line, -1, axis=0) - line).T)
    return Raceline(line_track, alpha, kappa, speed_profile(kappa, seg, settings))


class RacelinePlanner:
    """Pure pursuit along a precomputed raceline, with the ``Planner`` interface."""

    method = METHOD

    def __init__(
        self,
        track: Track,
        settings: PlannerSettings,
        curvature: CurvatureSettings | None = None,
        *,
        raceline: Raceline | None = None,
        timer: Callable[[], float] = time.perf_counter,
    ) -> None:
        """Build the raceline (or reuse one) on `track`."""
        self.track = track
        self.settings = settings
        self.options = settings.raceline
        self.raceline = raceline or build_raceline(track, settings.raceline)
        curvature = curvature or CurvatureSettings()
        self.profile = track_profile(track, curvature)
        self._timer = timer
        b = settings.bounds
        self._delta_lim = (b.delta_rad[0], b.delta_rad[1])
        self.recovery = Recovery(
            track, settings.recovery, settings.wheelbase_m, min(-b.delta_rad[0], b.delta_rad[1])
        )
        self.reset()

    @property
    def horizon(self) -> int:
        """N of the reported preview (the planner's horizon)."""
        return self.settings.horizon_steps

    def reset(self) -> None:
        """Forget where the car was (next step searches the whole line)."""
        self._s_line: float | None = None
        self._s_track: float | None = None
        self.recovery.reset()

    def prepare(self) -> None:
        """Nothing to do ahead of time (the ``Planner`` interface)."""

    def step(
        self,
        x_m: float,
        y_m: float,
        yaw_rad: float,
        on_command: Callable[[DriveCommand], None] | None = None,
    ) -> SolveResult:
        """The pursuit command from the rear-axle pose (x, y [m], yaw [rad])."""
        t0 = self._timer()
        line = self.raceline.track
        o = self.options
        if not all(math.isfinite(v) for v in (x_m, y_m, yaw_rad)):
            cmd = DriveCommand(0.0, 0.0)
            if on_command is not None:
                on_command(cmd)
            return self._result(cmd, x_m, y_m, yaw_rad, 0.0, 0.0, 0.0, "non-finite pose", t0,
                                status=BRAKING)
        s_l = self._project(line, x_m, y_m, self._s_line)
        s_t, e_t = self._project_track(x_m, y_m)
        self._s_line, self._s_track = s_l, s_t
        was_recovering = self.recovery.active
        rec = self.recovery.update(x_m, y_m, yaw_rad, s_t, e_t)
        if rec is not None or was_recovering:
            # follow the rule's anchored progress, on the track and (scaled) on the line
            s_t = self._s_track = self.recovery.s_m
            hint = s_t * line.length_m / self.track.length_m
            s_l = self._s_line = float(line.project(np.array([x_m, y_m]), hint, 2.0)[0])
        if rec is not None:
            cmd = DriveCommand(rec.speed_mps, rec.steering_rad)
            if on_command is not None:
                on_command(cmd)
            return self._result(cmd, x_m, y_m, yaw_rad, s_l, s_t, e_t, f"recovery: {rec.reason}",
                                t0, status=RECOVERING)
        v_ref = self.raceline.speed_at(s_l)
        l_d = min(max(o.lookahead_base_m + o.lookahead_gain_s * v_ref, o.lookahead_min_m),
                  o.lookahead_max_m)
        tx, ty = line.point_at(s_l + l_d)
        a = math.atan2(float(ty) - y_m, float(tx) - x_m) - yaw_rad
        delta = math.atan2(2.0 * self.settings.wheelbase_m * math.sin(a), l_d)
        delta = min(max(delta, self._delta_lim[0]), self._delta_lim[1])
        speed = self.raceline.speed_at(s_l + v_ref * o.speed_preview_s)
        cmd = DriveCommand(speed, delta)
        if on_command is not None:
            on_command(cmd)
        return self._result(cmd, x_m, y_m, yaw_rad, s_l, s_t, e_t, "pure pursuit", t0)

    def _project(self, t: Track, x: float, y: float, hint: float | None) -> float:
        if hint is None:
            return float(t.project(np.array([x, y]))[0])
        return t.project_near(x, y, hint)[0]

    def _project_track(self, x: float, y: float) -> tuple[float, float]:
        if self._s_track is None:
            s, e = self.track.project(np.array([x, y]))
            return float(s), float(e)
        return self.track.project_near(x, y, self._s_track)

    def _result(
        self,
        cmd: DriveCommand,
        x: float,
        y: float,
        yaw: float,
        s_line: float,
        s_track: float,
        e_track: float,
        text: str,
        t0: float,
        status: str = SOLVED,
    ) -> SolveResult:
        """The record of one tick: the preview is the raceline ahead at the profile speed."""
        N, dt = self.horizon, self.settings.dt_s
        line = self.raceline.track
        states = np.zeros((N + 1, 4))
        inputs = np.zeros((N, 3))
        if status == SOLVED:
            s_k = s_line
            s_prog = s_track
            states[0] = (x, y, yaw, s_track)
            for k in range(1, N + 1):
                v = self.raceline.speed_at(s_k)
                s_k += v * dt
                s_prog += v * dt
                px, py = line.point_at(s_k)
                states[k] = (float(px), float(py), float(line.heading_at(s_k)), s_prog)
                inputs[k - 1] = (v, cmd.steering_rad if k == 1 else 0.0, v)
        beta = np.full(N, float(self.profile.beta_at(s_track)))
        return SolveResult(
            command=cmd,
            states=states,
            inputs=inputs,
            status=status,
            solver_status=text,
            iterations=0,
            solve_time_s=self._timer() - t0,
            beta=beta,
            s_m=s_track,
            e_con_m=e_track,
            consecutive_failures=0 if status == SOLVED else 1,
            method=METHOD,
        )
