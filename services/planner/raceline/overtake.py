"""Racing the line around opponents: a lateral corridor and a gap, planned over a horizon
(issue #24). Pure maths, no I/O; used by ``RacelinePlanner`` when it is given opponents.

Frame: the racing line (``Track``, ``e`` right +, its widths the distances to the boundaries).
The ego's CoG is at ``(s_e, e_e)``; each opponent is predicted keeping its share of the line's
speed profile and its offset (``services.planner.opponents.predict_on_line``) at the stages
``t_k = k dt_p``,
``k = 0 .. K-1`` (``OvertakeParams.stages``, ``stage_s``).

The plan of one tick is a lateral target ``d`` (right +) and a speed cap:

1. Ego progress: along the line's clock at the share ``c`` of its speeds the car is held
   to (the speed scale: a cautious out lap, a grip adaptation), but no further than from
   its speed now gaining ``ego_accel_mps2``: ``s_k = min(s_plan(t_plan(s_e) + c t_k), s_e
   + v_e t_k + a t_k^2 / 2)``.
2. Opponent j is *near* at stage k when ``-(L + m_lon) < s_jk - s_k < L + m_lon + T_gap
   v_p(s_k)`` and *beside* when ``|s_jk - s_k| < L + m_lon`` (L, W the means of the two
   cars' lengths and widths). Nobody near: the line, no cap.
3. A pass leaves each opponent on one side (two opponents: four combinations). Its
   corridor per stage is the track (``W_e / 2 + m_wall`` inside both boundaries, the
   narrowest half-way to the neighbouring stages) and, at the stages beside opponent j,
   ``e_k >= e_jk + W + m_lat`` (passing on its right) or ``e_k <= e_jk - (W + m_lat)``
   (its left): the lateral room at the opponent's predicted place over the whole horizon.
   A pass must be over within the horizon (nobody beside at its last stage: a pass that
   cannot end would be squeezed between the car and a wall where the line crosses the
   track). ``corridor_path`` finds the path nearest the line inside it that the car can
   follow (``lateral_rate_mps`` after ``lateral_lag_s``), or none. Cost, a proxy of the
   time lost: the mean ``|e_k|`` (plus ``change_weight`` for changing the side of a pass
   under way); the cheapest feasible pass wins, which chooses the side by what is faster
   and safe. The target ``d`` is the path where the car must be when it first comes beside
   (it moves out early: the real car lags the plan), with up to ``pass_extra_m`` more
   room from the car where the corridor has it, within the track over the way there.
   3b. The ego's progress along the line on a candidate path is its progress on the line
   times ``f / (1 + kappa e)`` per stage (``f`` of step 5; ``1 + kappa e`` the path's
   length per metre of line): the outside of a bend is longer, the inside shorter but
   slower. A candidate whose pass is not over within the horizon with that progress is
   dropped; one whose beside stages grow with it is re-planned with both. The beside
   stages are held ``pass_slack_s`` longer: a car slower than its plan (a pass begun below
   the line's speed) comes clear later, and where the track narrows there it was squeezed
   between the car and the wall.
4. No feasible pass: **follow** (``_follow``), ready to pass. Laterally: on its side of
   any car it overlaps now (never squeezed into it); else beside the line of the nearest
   car ahead (``W + m_lat`` off it) on the side with room for the longest, when that is at
   least ``ready_time_s`` (the slipstream position: when a pass becomes possible it needs
   no lateral move), else towards the line. The speed cap behind a car ahead in lateral
   conflict (now or along the path) keeps the follow gap::

       v_cap = max(0, v_s,j + k_gap (s_j0 - s_e - L - g_min - T_gap v_s,j))        [m/s]

   laterally clear of it, the same law holds the ego just behind side by side
   (``s_j0 - s_e -> L + m_lon + ready_gap``); side by side with it and more behind than
   ahead, the ego drops back (``v_s,j - drop_back``). The ego never aims into a predicted
   footprint and slows behind one it cannot pass: it never initiates contact.
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
        ready_time_s: following, the ego waits beside the line of the car ahead (the
            slipstream position) on a side with room for at least this long over the
            horizon (0: behind it, on the line) [s].
        ready_gap_m: ... and there keeps its centre this far behind side by side [m].
        drop_back_mps: side by side with a car it cannot pass, more behind than ahead, the
            ego drops back this much slower than it [m/s].
        pass_extra_m: passing, the target keeps up to this much more than ``W + m_lat``
            from the car beside where the corridor has the room [m].
        pass_slack_s: a pass keeps the room beside each car this much longer than the
            ego's predicted progress needs (step 3b) [s].
        ego_length_m, ego_width_m: the ego's footprint [m].
    """

    stages: int = 25
    stage_s: float = 0.2
    margin_lateral_m: float = 0.08
    margin_longitudinal_m: float = 0.1
    gap_time_s: float = 0.08
    gap_min_m: float = 0.2
    gain_gap_per_s: float = 1.5
    wall_margin_m: float = 0.06
    lateral_rate_mps: float = 0.7
    lateral_lag_s: float = 0.15
    change_weight: float = 0.5
    curve_factor_min: float = 0.6
    curve_preview_s: float = 1.0
    target_time_s: float = 0.5
    ego_accel_mps2: float = 3.0
    ready_time_s: float = 2.0
    ready_gap_m: float = 0.05
    drop_back_mps: float = 0.5
    pass_extra_m: float = 0.05
    pass_slack_s: float = 0.2
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
#: The ready position keeps this much more than ``W + m_lat`` from the car's line [m].
READY_EXTRA_M = 0.02
#: The ready position only where the ego's progress beside the line is at least this
#: share of its progress on it (``_progress_on``'s factor, the mean over the run) [1].
READY_MIN_PROGRESS = 0.97
#: The follow cap reads the opponent's speed this far ahead in its prediction [s].
SOON_S = 0.4


def ego_progress(
    ref: ReferenceLap,
    s0_m: float,
    times_s: np.ndarray,
    v0_mps: float | None = None,
    accel_mps2: float = 3.0,
    speed_scale: float = 1.0,
) -> np.ndarray:
    """(K,) ego arc length [m] at `times_s` from `s0_m`: along the line's clock (its speed
    profile; at `speed_scale` of its speeds the clock runs that much slower), or no
    further than from the speed `v0_mps` gaining `accel_mps2` (a car held behind another
    does not jump back to the line's speed)."""
    t = np.asarray(times_s, dtype=float)
    t0 = float(ref.at("t", s0_m))
    on_plan = (s0_m + np.asarray(ref.s_at_time(t0 + speed_scale * t), dtype=float)
               - float(ref.s_at_time(t0)))
    if v0_mps is None:
        return on_plan
    return np.minimum(on_plan, s0_m + v0_mps * t + 0.5 * accel_mps2 * t**2)


def corridor_path(
    e0: float, lo: np.ndarray, hi: np.ndarray, t: np.ndarray, p: OvertakeParams
) -> np.ndarray | None:
    """The lateral path (K,) [m] nearest the line within the corridor ``lo <= e_k <= hi``
    that the car can follow from `e0`: moving at most ``lateral_rate_mps`` after
    ``lateral_lag_s``; None when no such path exists.

    The bounds are first tightened backwards (``lo_k >= lo_j - r (t_j - t_k)`` for every
    later stage j, ``hi_k <= hi_j + r (t_j - t_k)``: what a later stage needs must be
    reachable from stage k; a reversed running max / min), then the path is built forwards,
    each stage the point of its tightened interval nearest the line reachable from the
    last: exact for a one-dimensional rate-limited corridor.
    """
    r = p.lateral_rate_mps
    rt = r * t
    lo = (np.maximum.accumulate((lo - rt)[::-1])[::-1] + rt).tolist()
    hi = (np.minimum.accumulate((hi + rt)[::-1])[::-1] - rt).tolist()
    tt = t.tolist()
    lag = p.lateral_lag_s
    path = [0.0] * len(tt)
    e = e0
    prev_t = tt[0]
    for k, tk in enumerate(tt):
        a, b = lo[k], hi[k]
        if a > b + 1e-9:
            return None
        reach = r * (tk - lag) if tk > lag else 0.0
        a, b = max(a, e0 - reach), min(b, e0 + reach)
        if k > 0:
            step = r * (tk - prev_t)
            a, b = max(a, e - step), min(b, e + step)
        if a > b + 1e-9:
            return None
        e = min(max(0.0, a), b)
        path[k] = e
        prev_t = tk
    return np.array(path)


def _track_room(line, s_e: np.ndarray, room: float) -> tuple[np.ndarray, np.ndarray]:
    """(lo, hi) (K,) [m]: where the ego's CoG may be across the line at its predicted arc
    lengths `s_e`, `room` [m] inside both boundaries, the narrowest over each stage's
    neighbourhood (half-way to the stages beside it: the track may narrow between them)."""
    mid = 0.5 * (s_e[1:] + s_e[:-1])
    w_r, w_l = line.interp_width(np.concatenate([s_e, mid]))
    K = len(s_e)
    wr, wl = np.asarray(w_r, dtype=float), np.asarray(w_l, dtype=float)
    r_k, r_m = wr[:K].copy(), wr[K:]
    l_k, l_m = wl[:K].copy(), wl[K:]
    r_k[1:] = np.minimum(r_k[1:], r_m)
    r_k[:-1] = np.minimum(r_k[:-1], r_m)
    l_k[1:] = np.minimum(l_k[1:], l_m)
    l_k[:-1] = np.minimum(l_k[:-1], l_m)
    return -(l_k - room), r_k - room


def plan_around(
    ref: ReferenceLap,
    s_e_m: float,
    e_e_m: float,
    opponents: list[OpponentPrediction],
    previous_offset_m: float,
    params: OvertakeParams,
    v_e_mps: float | None = None,
    speed_scale: float = 1.0,
) -> OvertakePlan:
    """The plan of one tick (module docstring).

    Args:
        ref: the line and its speed profile (``ref.line`` widths: to the boundaries).
        s_e_m, e_e_m: the ego's CoG on the line (arc length, offset right +) [m].
        opponents: predictions on the same line at ``params.times()``.
        previous_offset_m: the last tick's target [m] (its sign: the side of a pass).
        v_e_mps: the ego's speed now [m/s] (None: on the profile; ``ego_progress``).
        speed_scale: the share of the profile's speeds the ego is held to (0, 1]: a pass
            is planned with the speeds the car will drive (a cautious out lap at 0.8
            planned passes at the line's speeds and ended squeezed beside the car it
            could not pass, Oschersleben seeds 610-637).
    """
    if not opponents:
        return FREE
    p = params
    line = ref.line
    L_line = line.length_m
    t = p.times()
    s_e = ego_progress(ref, s_e_m, t, v_e_mps, p.ego_accel_mps2, speed_scale)  # (K,)
    v_e = speed_scale * np.asarray(ref.at("v", s_e), dtype=float)
    ds = np.stack([o.s_m for o in opponents]) - s_e[None, :]  # (J, K) ahead of the ego
    ds = (ds + 0.5 * L_line) % L_line - 0.5 * L_line
    e_o = np.stack([o.e_m for o in opponents])
    length = 0.5 * (p.ego_length_m + np.array([o.length_m for o in opponents]))[:, None]
    width = 0.5 * (p.ego_width_m + np.array([o.width_m for o in opponents]))[:, None]
    clear = width + p.margin_lateral_m  # (J, 1)
    beside_m = length + p.margin_longitudinal_m  # (J, 1): closer than this is side by side
    near = (ds > -beside_m) & (ds < beside_m + p.gap_time_s * v_e[None, :])  # (J, K)
    if not near.any():
        return FREE
    beside = np.abs(ds) < beside_m  # (J, K): side by side
    lo_track, hi_track = _track_room(line, s_e, 0.5 * p.ego_width_m + p.wall_margin_m)
    ids = tuple(o.id for o, n in zip(opponents, near.any(axis=1), strict=True) if n)
    J = len(opponents)
    look = min(len(t) - 1, max(1, round(p.target_time_s / p.stage_s)))
    best: tuple[float, np.ndarray, np.ndarray, np.ndarray] | None = None
    # a pass must be over within the horizon (no car still beside at its end): one that
    # is not could end squeezed between a car and a wall
    if not beside[:, -1].any():
        # each opponent passed on its left (-1: smaller e) or right (+1); two opponents:
        # the four combinations
        # where the ego is now is allowed while it cannot move yet: a bound it misses now
        # (tracking errors) it must leave at its lateral rate
        away = p.lateral_rate_mps * np.maximum(t - p.lateral_lag_s, 0.0)
        lo_reach, hi_reach = e_e_m - away, e_e_m + away
        if e_e_m < lo_track[0]:
            lo_track = np.minimum(lo_track, hi_reach)
        if e_e_m > hi_track[0]:
            hi_track = np.maximum(hi_track, lo_reach)
        kappa = np.asarray(ref.at("kappa", s_e), dtype=float)
        slack = max(0, round(p.pass_slack_s / p.stage_s))

        def bounds(sides: tuple[int, ...], by: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
            lo, hi = lo_track.copy(), hi_track.copy()
            for j, side in enumerate(sides):
                nj = by[j]
                if not nj.any():
                    continue
                if side:  # right of it
                    need = e_o[j] + clear[j, 0]
                    if e_e_m > e_o[j, 0]:  # on that side already
                        need = np.minimum(need, hi_reach)
                    lo = np.where(nj, np.maximum(lo, need), lo)
                else:
                    need = e_o[j] - clear[j, 0]
                    if e_e_m < e_o[j, 0]:
                        need = np.maximum(need, lo_reach)
                    hi = np.where(nj, np.minimum(hi, need), hi)
            return lo, hi

        for sides in np.ndindex(*(2,) * J):
            lo, hi = bounds(sides, beside)
            path = corridor_path(e_e_m, lo, hi, t, p)
            if path is None:
                continue
            # the ego's progress along the line on that path (step 3b): the pass must be
            # over within the horizon with it too
            s_p = _progress_on(s_e, kappa, path, p)
            ds_p = (np.stack([o.s_m for o in opponents]) - s_p[None, :] + 0.5 * L_line) % (
                L_line) - 0.5 * L_line
            # ... and the room beside them held ``pass_slack_s`` longer (the ego comes
            # clear later than predicted when it is slower than its plan)
            beside_p = _hold(np.abs(ds_p) < beside_m, slack) | beside
            if beside_p[:, -1].any():
                continue
            if (beside_p & ~beside).any():
                lo, hi = bounds(sides, beside_p)
                path = corridor_path(e_e_m, lo, hi, t, p)
                if path is None:
                    continue
            side_sign = 1.0 if sum(sides) * 2 >= J else -1.0
            cost = float(np.mean(np.abs(path)))
            if abs(previous_offset_m) > 0.05 and np.sign(previous_offset_m) != side_sign:
                cost += p.change_weight
            if best is None or cost < best[0]:
                best = (cost, path, lo, hi)
    if best is not None:
        path = best[1]
        # move out early: aim at where the car must be when it comes beside (the lazy
        # path leaves the line at the last moment, and the real car lags the plan)
        first = np.nonzero(beside.any(axis=0))[0]
        k = max(look, int(first[0])) if first.size else look
        # with room to spare beside them where the corridor has it (the lazy path runs
        # on its edge, and tracking errors would eat the margin)
        lo, hi = best[2], best[3]
        if first.size:
            win = slice(int(first[0]), int(np.nonzero(beside.any(axis=0))[0][-1]) + 1)
            if path[k] > 0.0:
                d_k = float(path[k]) + min(p.pass_extra_m, max(0.0, float(hi[win].min()
                                                                    - path[k])))
            else:
                d_k = float(path[k]) - min(p.pass_extra_m, max(0.0, float(path[k]
                                                                    - lo[win].max())))
        else:
            d_k = float(path[k])
        # ... but inside the track over the way there
        d = min(max(d_k, float(lo_track[: k + 1].max())), float(hi_track[: k + 1].min()))
        cap = _cap_now(ds, e_o, e_e_m, width, length, opponents, p)
        mode = "pass" if np.max(np.abs(path)) > 0.02 else "line"
        if mode == "line":  # no move needed: no extra room either (it biased the line
            d = 0.0  # to one side by pass_extra_m, flickering with the plans around it)
        return OvertakePlan(d, cap, _curve_factor(ref, s_e, path, p), mode, ids)
    return _follow(ref, s_e, e_e_m, ds, e_o, clear, beside_m, near, length, width,
                   lo_track, hi_track, t, look, opponents, ids, p)


def _hold(mask: np.ndarray, n: int) -> np.ndarray:
    """(J, K) bool: `mask` (J, K) held `n` stages longer (stage k is set when any of the
    stages k - n .. k is)."""
    out = mask.copy()
    for i in range(1, n + 1):
        out[:, i:] |= mask[:, :-i]
    return out


def _progress_on(
    s_e: np.ndarray, kappa: np.ndarray, path: np.ndarray, p: OvertakeParams
) -> np.ndarray:
    """(K,) the ego's arc length along the line [m] when it drives the lateral `path` (K,)
    [m] instead of the line (step 3b of the module docstring): each stage's advance of
    `s_e` (K,) times ``f / (1 + kappa e)``, the bend's speed factor ``f`` (step 5) over
    the path's length per metre of line (`kappa` (K,) the line's curvature at `s_e`): the
    outside of a bend is longer at the same speed, the inside shorter but slower."""
    q = np.maximum(1.0 + kappa[:-1] * 0.5 * (path[:-1] + path[1:]), 0.3)
    f = np.sqrt(np.clip(q, p.curve_factor_min**2, 1.0))
    steps = np.diff(s_e) * f / q
    out = np.empty_like(s_e)
    out[0] = s_e[0]
    out[1:] = s_e[0] + np.cumsum(steps)
    return out


def _follow(
    ref: ReferenceLap,
    s_e: np.ndarray,
    e_e: float,
    ds: np.ndarray,
    e_o: np.ndarray,
    clear: np.ndarray,
    beside_m: np.ndarray,
    near: np.ndarray,
    length: np.ndarray,
    width: np.ndarray,
    lo_track: np.ndarray,
    hi_track: np.ndarray,
    t: np.ndarray,
    look: int,
    opponents: list[OpponentPrediction],
    ids: tuple[int, ...],
    p: OvertakeParams,
) -> OvertakePlan:
    """No safe pass: follow (step 4 of the module docstring), ready to pass.

    Lateral: on its side of a car it overlaps now (never squeezed into it: the walls give
    way first); else, behind the nearest car ahead, beside its line (``clear`` off it) on
    the side with room for the longest over the horizon when that is at least
    ``ready_time_s`` (the slipstream position: a pass that becomes possible starts with no
    lateral move), else towards the line. Speed: behind a car in lateral conflict the
    follow gap; laterally clear of it, no closer than just behind side by side
    (``ready_gap_m``); beside a car with the ego's centre behind its, dropping back.
    """
    J = len(opponents)
    lo, hi = lo_track.copy(), hi_track.copy()
    overlapping = False
    # a clearance the ego misses now it must regain at its lateral rate (as a pass does)
    away = p.lateral_rate_mps * np.maximum(t - p.lateral_lag_s, 0.0)
    for j in range(J):
        if abs(ds[j, 0]) < beside_m[j, 0]:
            overlapping = True
            if e_e >= e_o[j, 0]:
                lo = np.maximum(lo, np.minimum(e_o[j] + clear[j, 0], e_e + away))
            else:
                hi = np.minimum(hi, np.maximum(e_o[j] - clear[j, 0], e_e - away))
    target = 0.0
    ahead = [j for j in range(J) if near[j].any() and ds[j, 0] > 0.0]
    if not overlapping and ahead and p.ready_time_s > 0.0:
        j = min(ahead, key=lambda i: ds[i, 0])
        rooms = (hi_track - (e_o[j] + clear[j, 0]), (e_o[j] - clear[j, 0]) - lo_track)
        runs = []
        for room in rooms:
            bad = np.nonzero(room < 0.0)[0]
            runs.append(t[bad[0]] if bad.size else t[-1] + p.stage_s)
        side = int(np.argmax(runs))
        off = clear[j, 0] + READY_EXTRA_M
        e_ready = e_o[j] + (off if side == 0 else -off)
        # ... and not where that side is the outside of a bend: waiting there the ego
        # loses ground instead of closing in
        n = max(1, int(np.searchsorted(t, runs[side])))
        k_n = np.asarray(ref.at("kappa", s_e[:n]), dtype=float)
        q = np.maximum(1.0 + k_n * e_ready[:n], 0.3)
        gain = float(np.mean(np.sqrt(np.clip(q, p.curve_factor_min**2, 1.0)) / q))
        if runs[side] >= p.ready_time_s and gain >= READY_MIN_PROGRESS:
            target = float(e_ready[0])
    lo_t, hi_t = lo - target, hi - target
    path = corridor_path(e_e - target, lo_t, hi_t, t, p)
    if path is None:  # the walls give way first: the bounds the cars did not tighten
        path = corridor_path(e_e - target, lo_t - 10.0 * (lo <= lo_track),
                             hi_t + 10.0 * (hi >= hi_track), t, p)
    path = np.full(len(t), e_e) if path is None else path + target
    d = float(path[look])
    cap = math.inf
    for j, o in enumerate(opponents):
        if not near[j].any():
            continue
        ds0 = float(ds[j, 0])
        if abs(ds0) < beside_m[j, 0]:  # side by side now
            if ds0 > 0.0:  # its centre ahead of the ego's: drop back
                cap = min(cap, max(0.0, o.v_s_mps - p.drop_back_mps))
            continue
        if ds0 <= 0.0:
            continue
        tight = clear[j, 0] - READY_EXTRA_M  # the ready position is not a conflict
        conflict = near[j] & (ds[j] > 0.0) & (np.abs(path - e_o[j]) < tight)
        close = ds0 < float(length[j, 0]) + p.gap_min_m + p.gap_time_s * o.v_s_mps
        if conflict.any() or (close and abs(e_e - e_o[j, 0]) < tight):
            cap = min(cap, _follow_speed(ds0, _speed_soon(o, p), float(length[j, 0]), p))
        else:  # the ready position: just behind side by side
            gap = ds0 - float(beside_m[j, 0]) - p.ready_gap_m
            cap = min(cap, max(0.0, o.v_s_mps + p.gain_gap_per_s * gap))
    return OvertakePlan(d, cap, _curve_factor(ref, s_e, path, p), "follow", ids)


def _speed_soon(o: OpponentPrediction, p: OvertakeParams) -> float:
    """The opponent's progress speed [m/s]: its speed now, or the mean of its predicted
    next ``SOON_S`` when lower (it brakes for a bend: the follower slows with it, not
    after it)."""
    k = min(len(o.s_m) - 1, max(1, round(SOON_S / p.stage_s)))
    return min(o.v_s_mps, float(o.s_m[k] - o.s_m[0]) / (k * p.stage_s))


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
    """The follow cap behind every opponent ahead in lateral conflict at stage 0 (not one
    side by side already: braking there only lets it run into the ego)."""
    cap = math.inf
    for j, o in enumerate(opponents):
        if ds[j, 0] > length[j, 0] and abs(e_e - e_o[j, 0]) < width[j, 0] + p.margin_lateral_m:
            cap = min(cap, _follow_speed(float(ds[j, 0]), _speed_soon(o, p),
                                         float(length[j, 0]), p))
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
