"""Opponents as the planner core sees them, and their prediction along the track (issue #24).

Pure maths, no I/O. ``OpponentEstimate`` carries exactly the fields of the ``Opponents``
message's tracks (id, x_m, y_m, vx_mps, vy_mps, yaw_rad, length_m, width_m, covariance), so a
service can fill it from the message; the bench fills it from the simulator's truth or from
the lidar tracker (``services.localization_bridge.opponents``).

Prediction (``predict_on_line``): an opponent keeps its **progress speed** along a line (the
velocity's component along the line's tangent at its projection, ``v_s = v . t``) and its
lateral offset from it (constant velocity along the track's progress, not in the map frame:
a car going round a bend stays in the bend). Stage k at ``t_k = k dt``::

    s_k = s_0 + v_s t_k,        e_k = e_0                         [m]

with ``(s_0, e_0)`` the projection of its centre on the line (``e`` right +, the ``Track``
convention). Given the line's speed profile ``v_p(s)`` (``profile_mps``), the opponent keeps
instead its **share of that profile**, ``rho = v_s / v_p(s_0)`` (clipped to [0,
``MAX_PROFILE_SHARE``]): ``ds/dt = rho v_p(s)`` -- it brakes for the bends the
line brakes for (a car held at constant speed would drive through a hairpin at its straight
speed in the prediction). A stopped car stays stopped either way.

From the bus (``estimates_from_record``): the planner service turns each ``opponents`` record
(``shared.messages.Opponents``, its tracks at the scan's stamp) into estimates moved to "now"
at their own velocity, ``x = x_scan + v (t_now - t_scan)``; a record older than the stale
limit gives none, a track with a value that is not a finite number (or a non-positive size)
is dropped; both are counted (``RecordCounts``), never raised.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

from shared.car import CAR
from shared.track import Track

if TYPE_CHECKING:
    from services.planner.raceline.tracker import ReferenceLap

#: The largest share of the line's speed profile an opponent is predicted to keep [1].
MAX_PROFILE_SHARE = 1.2


@dataclass(frozen=True)
class OpponentEstimate:
    """One other car, in the map frame.

    Attributes:
        id: track id (stable while the same car is tracked).
        x_m, y_m: centre of its footprint [m].
        vx_mps, vy_mps: velocity [m/s].
        yaw_rad: heading [rad].
        length_m, width_m: footprint [m].
        covariance: row-major covariance of (x, y, vx, vy) [m^2, m^2/s, m^2/s^2] (16
            values; empty when unknown, e.g. the simulator's truth).
    """

    id: int
    x_m: float
    y_m: float
    vx_mps: float
    vy_mps: float
    yaw_rad: float
    length_m: float = CAR.length_m
    width_m: float = CAR.width_m
    covariance: tuple[float, ...] = field(default=())


@dataclass
class RecordCounts:
    """What ``estimates_from_record`` made of the records it was given (running totals).

    Attributes:
        records: records converted; stale: of them, dropped whole for their age.
        tracks: tracks handed on as estimates; bad_tracks: tracks dropped as malformed.
    """

    records: int = 0
    stale: int = 0
    tracks: int = 0
    bad_tracks: int = 0


def _estimate(track: object, age_s: float) -> OpponentEstimate | None:
    """One record track as an estimate `age_s` [s] after its scan (None: malformed)."""
    try:
        x, y = float(track.x_m), float(track.y_m)  # type: ignore[attr-defined]
        vx, vy = float(track.vx_mps), float(track.vy_mps)  # type: ignore[attr-defined]
        yaw = float(track.yaw_rad)  # type: ignore[attr-defined]
        length, width = float(track.length_m), float(track.width_m)  # type: ignore[attr-defined]
        cxx, cxy = float(track.cov_xx_m2), float(track.cov_xy_m2)  # type: ignore[attr-defined]
        cyy = float(track.cov_yy_m2)  # type: ignore[attr-defined]
        sv = float(track.speed_var_m2ps2)  # type: ignore[attr-defined]
        tid = int(track.id)  # type: ignore[attr-defined]
    except (AttributeError, TypeError, ValueError, OverflowError):
        return None
    values = (x, y, vx, vy, yaw, length, width, cxx, cxy, cyy, sv)
    if not all(np.isfinite(values)) or length <= 0.0 or width <= 0.0:
        return None
    # covariance of (x, y, vx, vy): the position block, the speed variance on both velocity
    # axes, grown over the age by the velocity's (row-major, 16 values)
    a2 = age_s * age_s
    cov = (
        cxx + a2 * sv, cxy, age_s * sv, 0.0,
        cxy, cyy + a2 * sv, 0.0, age_s * sv,
        age_s * sv, 0.0, sv, 0.0,
        0.0, age_s * sv, 0.0, sv,
    )
    return OpponentEstimate(tid, x + vx * age_s, y + vy * age_s, vx, vy, yaw, length, width, cov)


def estimates_from_record(
    record: object, now_s: float, stale_s: float, counts: RecordCounts | None = None
) -> list[OpponentEstimate]:
    """The estimates of one ``opponents`` record at wall time `now_s` [s] (module
    docstring).

    Args:
        record: an ``Opponents`` record (``source_stamp_s`` [s], ``tracks``).
        now_s: the time to move the tracks to [s] (the record's clock: wall time).
        stale_s: a record whose scan is older than this [s] gives no estimates.
        counts: running totals to add to (``RecordCounts``).

    Returns:
        the estimates (empty for a stale or malformed record); never raises for the record's
        contents.
    """
    counts = counts if counts is not None else RecordCounts()
    counts.records += 1
    try:
        age = float(now_s) - float(record.source_stamp_s)  # type: ignore[attr-defined]
        tracks = list(record.tracks)  # type: ignore[attr-defined]
    except (AttributeError, TypeError, ValueError, OverflowError):
        counts.stale += 1  # no usable stamp: as good as stale
        return []
    if not np.isfinite(age) or age > stale_s:
        counts.stale += 1
        return []
    age = max(age, 0.0)  # a clock a little ahead of ours: the scan is "now"
    out: list[OpponentEstimate] = []
    for tr in tracks:
        est = _estimate(tr, age)
        if est is None:
            counts.bad_tracks += 1
        else:
            out.append(est)
    counts.tracks += len(out)
    return out


@dataclass(frozen=True)
class OpponentPrediction:
    """One opponent predicted over a horizon along a line.

    Attributes:
        id: the estimate's id.
        s_m: (K,) arc length of its centre on the line at each stage, unwrapped from the
            projection (may exceed the line's length) [m].
        e_m: (K,) lateral offset from the line (right +) [m].
        v_s_mps: its progress speed along the line [m/s].
        length_m, width_m: footprint [m].
    """

    id: int
    s_m: np.ndarray
    e_m: np.ndarray
    v_s_mps: float
    length_m: float
    width_m: float


def progress_speed(line: Track, s_m: float, vx_mps: float, vy_mps: float) -> float:
    """Velocity (vx, vy) [m/s] projected on the tangent of `line` at arc length `s_m` [m]."""
    h = float(line.heading_at(s_m))
    return vx_mps * float(np.cos(h)) + vy_mps * float(np.sin(h))


def predict_on_line(
    line: Track,
    opponent: OpponentEstimate,
    t_s: np.ndarray,
    s_hint_m: float | None = None,
    profile: ReferenceLap | None = None,
) -> OpponentPrediction:
    """`opponent` at the times `t_s` (K,) [s] from now (increasing), at constant progress
    speed along `line` (or its share of `profile_mps`) and constant offset from it
    (module docstring).

    Args:
        s_hint_m: arc length near which to project (None: the whole line).
        profile: the line's plan (its speed profile and clock; None: constant progress
            speed). Keeping the share ``rho`` of its speed is moving along its clock
            ``rho`` times as fast: ``s_k = s_plan(t_plan(s_0) + rho t_k)``.
    """
    if s_hint_m is None:
        s0, e0 = line.project(np.array([opponent.x_m, opponent.y_m]))
    else:
        s0, e0 = line.project(np.array([opponent.x_m, opponent.y_m]), s_hint_m, 10.0)
    s0, e0 = float(s0), float(e0)
    v_s = progress_speed(line, s0, opponent.vx_mps, opponent.vy_mps)
    t = np.asarray(t_s, dtype=float)
    if profile is None:
        s_k = s0 + v_s * t
    else:
        share = min(max(v_s / max(float(profile.at("v", s0)), 0.1), 0.0), MAX_PROFILE_SHARE)
        t0 = float(profile.at("t", s0))
        s_plan0 = float(profile.s_at_time(t0))  # s0 as the clock's inverse gives it
        s_k = s0 + (np.asarray(profile.s_at_time(t0 + share * t), dtype=float) - s_plan0)
    return OpponentPrediction(
        id=opponent.id,
        s_m=s_k,
        e_m=np.full(t.shape, e0),
        v_s_mps=v_s,
        length_m=opponent.length_m,
        width_m=opponent.width_m,
    )
