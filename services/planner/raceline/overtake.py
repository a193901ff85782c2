"""Racing the line around opponents: a lateral corridor and a gap, planned over a horizon
(issue #24). Pure maths, no I/O; used by ``RacelinePlanner`` when it is given opponents.

Frame: the racing line (``Track``, ``e`` right +, its widths the distances to the boundaries).
The ego's CoG is at ``(s_e, e_e)``; each opponent is predicted keeping its share of the line's
speed profile and its offset (``services.planner.opponents.predict_on_line``) at the stages
``t_k = k dt_p``,
``k = 0 .. K-1`` (``OvertakeParams.stages``, ``stage_s``).

The plan of one tick is a lateral target ``d`` (right +) and a speed cap:

1. Ego progress: along the line's clock, but no further than from its speed now gaining
   ``ego_accel_mps2``: ``s_k = min(s_plan(t_plan(s_e) + t_k), s_e + v_e t_k + a t_k^2 / 2)``.
2. Opponent j is *near* at stage k when ``-(L + m_lon) < s_jk - s_k < L + m_lon + T_gap
   v_p(s_k)`` and *beside* when ``|s_jk - s_k| < L + m_lon`` (L, W the means of the two
   cars' lengths and widths). Nobody near: the line, no cap.
3. A pass leaves each opponent on one side (two opponents: four combinations). Its
   corridor per stage is the track (``W_e / 2 + m_wall`` inside both boundaries) and, at
   the stages beside opponent j, ``e_k >= e_jk + W + m_lat`` (passing on its right) or
   ``e_k <= e_jk - (W + m_lat)`` (its left). ``corridor_path`` finds the path nearest the
   line inside it that the car can follow (``lateral_rate_mps`` after ``lateral_lag_s``),
   or none. Cost, a proxy of the time lost: the mean ``|e_k|`` (plus ``change_weight``
   for changing the side of a pass under way); the cheapest feasible pass wins, which
   chooses the side by what is faster and safe. The target ``d`` is the path where the car
   must be when it first comes beside (it moves out early: the real car lags the plan),
   within the track over the way there.
4. No feasible pass: **follow** -- towards the line, but on its side of any car it
   overlaps now (never squeezed into it), with a speed cap behind each opponent ahead
   that the path conflicts with::

       v_cap = max(0, v_s,j + k_gap (s_j0 - s_e - L - g_min - T_gap v_s,j))        [m/s]

   and the same cap applies whenever an opponent ahead is in lateral conflict now (a margin
   of safety over the prediction). The ego never aims into a predicted footprint and slows
   behind one it cannot pass: it never initiates contact.
5. Off the line the planned speed is scaled to the bend's radius at the offset,
   ``sqrt(clip(1 + kappa e_k, f_min^2, 1))`` (``kappa`` left +: inside a left bend
   ``e < 0``), the smallest over the next ``curve_preview_s``, so the pass keeps the grip
   margin. (Below the line's speed ``RacelinePlanner`` steers from steady-state trackers.)
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from services.planner.opponents import OpponentPrediction
from services.planner.raceline.tracker import ReferenceLap
from shared.car import CAR


@dataclass(frozen=True)
class OvertakeParams:
    """Tuning of the overtaking plan (module docstring symbols).

    Attributes:
        stages: K, prediction stages (>= 2).
        stage_s: dt_p, stage spacing [s].
        margin_lateral_m: m_lat, lateral clearance between the footprints [m].
        margin_longitudinal_m: m_lon, longitudinal clearance [m].
        gap_time_s: T_gap, time gap kept ahead of the ego [s].
        gap_min_m: g_min, bumper-to-bumper gap kept when following [m].
        gain_gap_per_s: k_gap, speed per metre of gap error when following [1/s].
        wall_margin_m: m_wall, clearance to the track boundaries [m].
        lateral_rate_mps: r, lateral speed the plan assumes (the planner ramps its
            target twice as fast, so the car can keep up with the plan) [m/s].
        lateral_lag_s: t_lag, the tracker's lag before the car moves sideways [s].
        change_weight: w_change, cost of changing the side of a pass [m].
        curve_factor_min: f_min, lowest speed factor off the line [1].
        curve_preview_s: how far ahead the bend's radius scales the speed [s].
        target_time_s: the tracker's target is the planned path this far ahead [s].
        ego_accel_mps2: how fast the ego's predicted speed returns to the line's [m/s^2].
        ego_length_m, ego_width_m: the ego's footprint [m].
    """

    stages: int = 30
    stage_s: float = 0.1
    margin_lateral_m: float = 0.08
    margin_longitudinal_m: float = 0.15
    gap_time_s: float = 0.15
    gap_min_m: float = 0.35
    gain_gap_per_s: float = 1.5
    wall_margin_m: float = 0.04
    lateral_rate_mps: float = 0.7
    lateral_lag_s: float = 0.15
    change_weight: float = 0.5
    curve_factor_min: float = 0.6
    curve_preview_s: float = 1.0
    target_time_s: float = 0.5
    ego_accel_mps2: float = 3.0
    ego_length_m: float = CAR.length_m
    ego_width_m: float = CAR.width_m

    def times(self) -> np.ndarray:
        """(K,) stage times [s]."""
        return np.arange(self.stages) * self.stage_s


@dataclass(frozen=True)
class OvertakePlan:
    """One tick's plan.

    Attributes:
        offset_m: lateral target from the line (right +) [m].
        speed_cap_mps: speed cap [m/s] (inf: none).
        speed_factor: the bend's factor on the planned speed off the line [1].
        mode: "line" (free), "pass" (a safe offset), "follow" (no safe pass).
        blocking: ids of the opponents the plan reacted to.
    """

    offset_m: float
    speed_cap_mps: float
    speed_factor: float
    mode: str
    blocking: tuple[int, ...] = ()


FREE = OvertakePlan(0.0, math.inf, 1.0, "line")


def ego_progress(
    ref: ReferenceLap,
    s0_m: float,
    times_s: np.ndarray,
    v0_mps: float | None = None,
    accel_mps2: float = 3.0,
) -> np.ndarray:
    """(K,) ego arc length [m] at `times_s` from `s0_m`: along the line's clock (its speed
    profile), or no further than from the speed `v0_mps` gaining `accel_mps2` (a car held
    behind another does not jump back to the line's speed)."""
    t = np.asarray(times_s, dtype=float)
    t0 = float(ref.at("t", s0_m))
    on_plan = s0_m + np.asarray(ref.s_at_time(t0 + t), dtype=float) - float(ref.s_at_time(t0))
    if v0_mps is None:
        return on_plan
    return np.minimum(on_plan, s0_m + v0_mps * t + 0.5 * accel_mps2 * t**2)


def corridor_path(
    e0: float, lo: np.ndarray, hi: np.ndarray, t: np.ndarray, p: OvertakeParams
) -> np.ndarray | None:
    """The lateral path (K,) [m] nearest the line within the corridor ``lo <= e_k <= hi``
    that the car can follow from `e0`: moving at most ``lateral_rate_mps`` after
    ``lateral_lag_s``; None when no such path exists.

    The bounds are first tightened backwards (``lo_k >= lo_(k+1) - r dt``, ``hi_k <=
    hi_(k+1) + r dt``: what stage k+1 needs must be reachable from stage k), then the
    path is built forwards, each stage the point of its tightened interval nearest the
    line reachable from the last: exact for a one-dimensional rate-limited corridor.
    """
    lo, hi = lo.astype(float).copy(), hi.astype(float).copy()
    K = len(t)
    step = p.lateral_rate_mps * np.diff(t)
    for k in range(K - 2, -1, -1):
        lo[k] = max(lo[k], lo[k + 1] - step[k])
        hi[k] = min(hi[k], hi[k + 1] + step[k])
    if np.any(lo > hi + 1e-9):
        return None
    path = np.empty(K)
    e = e0
    for k in range(K):
        reach = p.lateral_rate_mps * max(t[k] - p.lateral_lag_s, 0.0)
        a, b = max(lo[k], e0 - reach), min(hi[k], e0 + reach)
        if k > 0:
            a, b = max(a, e - step[k - 1]), min(b, e + step[k - 1])
        if a > b + 1e-9:
            return None
        e = min(max(0.0, a), b)
        path[k] = e
    return path


def plan_around(
    ref: ReferenceLap,
    s_e_m: float,
    e_e_m: float,
    opponents: list[OpponentPrediction],
    previous_offset_m: float,
    params: OvertakeParams,
    v_e_mps: float | None = None,
) -> OvertakePlan:
    """The plan of one tick (module docstring).

    Args:
        ref: the line and its speed profile (``ref.line`` widths: to the boundaries).
        s_e_m, e_e_m: the ego's CoG on the line (arc length, offset right +) [m].
        opponents: predictions on the same line at ``params.times()``.
        previous_offset_m: the last tick's target [m] (its sign: the side of a pass).
        v_e_mps: the ego's speed now [m/s] (None: on the profile; ``ego_progress``).
    """
    if not opponents:
        return FREE
    p = params
    line = ref.line
    L_line = line.length_m
    t = p.times()
    s_e = ego_progress(ref, s_e_m, t, v_e_mps, p.ego_accel_mps2)  # (K,)
    v_e = np.asarray(ref.at("v", s_e), dtype=float)
    ds = np.stack([o.s_m for o in opponents]) - s_e[None, :]  # (J, K) ahead of the ego
    ds = (ds + 0.5 * L_line) % L_line - 0.5 * L_line
    e_o = np.stack([o.e_m for o in opponents])
    length = 0.5 * (p.ego_length_m + np.array([o.length_m for o in opponents]))[:, None]
    width = 0.5 * (p.ego_width_m + np.array([o.width_m for o in opponents]))[:, None]
    clear = width + p.margin_lateral_m  # (J, 1)
    near = (ds > -(length + p.margin_longitudinal_m)) & (
        ds < length + p.margin_longitudinal_m + p.gap_time_s * v_e[None, :]
    )  # (J, K)
    if not near.any():
        return FREE
    beside = np.abs(ds) < length + p.margin_longitudinal_m  # (J, K): side by side
    w_r, w_l = line.interp_width(s_e)
    room = 0.5 * p.ego_width_m + p.wall_margin_m
    lo_track = -(np.asarray(w_l, dtype=float) - room)
    hi_track = np.asarray(w_r, dtype=float) - room
    ids = tuple(o.id for o, n in zip(opponents, near.any(axis=1), strict=True) if n)
    best: tuple[float, np.ndarray, str] | None = None
    # each opponent passed on its left (-1: smaller e) or right (+1); two opponents: the
    # four combinations
    J = len(opponents)
    for sides in np.ndindex(*(2,) * J):
        lo, hi = lo_track.copy(), hi_track.copy()
        for j, side in enumerate(sides):
            nj = beside[j]
            if side:  # right of it
                lo = np.where(nj, np.maximum(lo, e_o[j] + clear[j, 0]), lo)
            else:
                hi = np.where(nj, np.minimum(hi, e_o[j] - clear[j, 0]), hi)
        path = corridor_path(e_e_m, lo, hi, t, p)
        if path is None:
            continue
        side_sign = 1.0 if sum(sides) * 2 >= J else -1.0
        cost = float(np.mean(np.abs(path)))
        if abs(previous_offset_m) > 0.05 and np.sign(previous_offset_m) != side_sign:
            cost += p.change_weight
        if best is None or cost < best[0]:
            best = (cost, path, "pass")
    look = min(len(t) - 1, max(1, round(p.target_time_s / p.stage_s)))
    if best is not None:
        path = best[1]
        # move out early: aim at where the car must be when it comes beside (the lazy
        # path leaves the line at the last moment, and the real car lags the plan)
        first = np.nonzero(beside.any(axis=0))[0]
        k = max(look, int(first[0])) if first.size else look
        # ... but inside the track over the way there
        d = min(max(float(path[k]), float(lo_track[: k + 1].max())),
                float(hi_track[: k + 1].min()))
        cap = _cap_now(ds, e_o, e_e_m, width, length, opponents, p)
        mode = "pass" if np.max(np.abs(path)) > 0.02 else "line"
        return OvertakePlan(d, cap, _curve_factor(ref, s_e, path, p), mode, ids)
    # no safe pass: follow, back towards the line where the track allows, but staying on
    # its side of a car it overlaps now (never squeezed into it: the walls give way first)
    lo, hi = lo_track.copy(), hi_track.copy()
    for j in range(J):
        if abs(ds[j, 0]) < length[j, 0] + p.margin_longitudinal_m:
            if e_e_m >= e_o[j, 0]:
                lo = np.maximum(lo, e_o[j] + clear[j, 0])
            else:
                hi = np.minimum(hi, e_o[j] - clear[j, 0])
    path = corridor_path(e_e_m, lo, hi, t, p)
    if path is None:  # the walls give way first
        path = corridor_path(e_e_m, lo - 10.0 * (lo > lo_track), hi + 10.0 * (hi < hi_track),
                             t, p)
    if path is None:
        path = np.full(len(t), e_e_m)
    d = float(path[look])
    cap = math.inf
    for j, o in enumerate(opponents):
        hit = near[j] & (ds[j] > 0.0) & (np.abs(path - e_o[j]) < clear[j, 0])
        if hit.any():
            cap = min(cap, _follow_speed(float(ds[j, 0]), o.v_s_mps, float(length[j, 0]), p))
    cap = min(cap, _cap_now(ds, e_o, e_e_m, width, length, opponents, p))
    return OvertakePlan(d, cap, _curve_factor(ref, s_e, path, p), "follow", ids)


def _follow_speed(ds0: float, v_o: float, length: float, p: OvertakeParams) -> float:
    """Speed [m/s] that closes to the follow gap behind a car `ds0` [m] ahead at `v_o`."""
    gap = ds0 - length - p.gap_min_m - p.gap_time_s * max(v_o, 0.0)
    return max(0.0, v_o + p.gain_gap_per_s * gap)


def _cap_now(
    ds: np.ndarray,
    e_o: np.ndarray,
    e_e: float,
    width: np.ndarray,
    length: np.ndarray,
    opponents: list[OpponentPrediction],
    p: OvertakeParams,
) -> float:
    """The follow cap behind every opponent ahead in lateral conflict at stage 0."""
    cap = math.inf
    for j, o in enumerate(opponents):
        if ds[j, 0] > 0.0 and abs(e_e - e_o[j, 0]) < width[j, 0] + p.margin_lateral_m:
            cap = min(cap, _follow_speed(float(ds[j, 0]), o.v_s_mps, float(length[j, 0]), p))
    return cap


def _curve_factor(
    ref: ReferenceLap, s_e: np.ndarray, path: np.ndarray, p: OvertakeParams
) -> float:
    """Speed factor along the lateral `path` (K,) over the next ``curve_preview_s``
    (step 5)."""
    k = max(1, round(p.curve_preview_s / p.stage_s))
    d = path[:k]
    if np.max(np.abs(d)) < 1e-3:
        return 1.0
    kappa = np.asarray(ref.at("kappa", s_e[:k]), dtype=float)
    f = np.clip(1.0 + kappa * d, p.curve_factor_min**2, 1.0)
    return float(np.sqrt(f.min()))
