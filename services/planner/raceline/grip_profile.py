"""A line's speed profile re-planned for the grip the car turned out to have. Pure maths.

The raceline planner's grip adaptation (``RacelinePlanner._adapt_grip``) learns that the
car has less grip than its line was planned for as one number, the speed scale ``c`` in
(0, 1]: the car could not hold the line at its speeds, it held it at ``c`` times them.
Driving the whole line at ``c v(s)`` slows the straights (at the cap) and the gentle bends
as much as the bends at the grip. Read instead as grip, ``c`` says the car holds
``G = c^2 A`` of lateral acceleration, with ``A`` what the line asks in its bends at the
grip (``line_grip_mps2``: the 99th percentile of ``v^2 |kappa|``). The re-planned profile
(``grip_speed_profile``) is the line's own, never faster, and within ``G`` on the friction
ellipse::

    v_g(s)   <= min(v(s), sqrt(G / |kappa(s)|))
    a_x(s)   <= share G sqrt(1 - (v_g^2 |kappa| / G)^2)       (forward: drive, backward:
                                                               brake; around the loop)

with ``share`` (``[planner.raceline] grip_profile_long_share``) the part of the ellipse the
profile spends along the track (the speed loop's lag and the servo's overshoot need some).
At ``c = 1`` it is the line's own profile. The plan the tracker follows along it
(``grip_raceline``) is the line's path at the node-wise share ``v_g / v`` of its speeds
(``ReferenceLap.slower``: the steady-state steering and slip there, the line's dynamic part
faded in by the share's fourth power).

The re-plan is work for a tick's spare time, not for one tick: its passes are a Python loop
over the line's nodes (2-12 ms on 700-4200 nodes here) and its plans ``from_path`` over all
of them (0.5-1.5 ms each; six of them with the slower plans the tracker steers a car held
below the line by). Done in the tick that found the grip, it took 2.5-19 ms against the
planner's 2 ms budget. ``GripReplan`` does the same work a slice at a time (``raceline.
jobs``: the passes ``PASS_CHUNK`` nodes a slice, the plans' steady-state steering
``PLAN_CHUNK``), at most ``[planner.raceline] grip_replan_work_per_tick`` node steps per
tick, and hands over the line, the plan along it and its slower plans when all is done; the
car drives the line it has at the scale it has meanwhile (``RacelinePlanner.
_replan_for_grip``).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, replace
from typing import TYPE_CHECKING

import numpy as np

from services.planner.raceline.jobs import Job, SlicedJob, run_job
from services.planner.raceline.tracker import ReferenceLap
from shared.config.vehicle import DynamicVehicleParams

if TYPE_CHECKING:  # the planner module imports this one
    from services.planner.raceline.planner import Raceline

#: The percentile of the line's lateral acceleration read as the grip it was planned on.
LINE_GRIP_PERCENTILE = 99.0
#: The passes go twice around, so that the closed loop's profile closes.
PASSES = 2
#: Node steps of the passes between two looks at the tick's work budget.
PASS_CHUNK = 64
#: Nodes of a plan's steady-state steering (``ReferenceLap.from_path_job``) per slice.
PLAN_CHUNK = 256


def line_grip_mps2(v_mps: np.ndarray, kappa_1pm: np.ndarray) -> float:
    """The lateral acceleration [m/s^2] a line asks in its bends at the grip: the
    ``LINE_GRIP_PERCENTILE`` percentile of ``v^2 |kappa|`` over its nodes ((n,) arrays
    [m/s], [1/m]); positive."""
    a_y = np.asarray(v_mps, dtype=float) ** 2 * np.abs(np.asarray(kappa_1pm, dtype=float))
    return max(float(np.percentile(a_y, LINE_GRIP_PERCENTILE)), 1e-6)


def grip_speed_profile(
    v_mps: np.ndarray,
    kappa_1pm: np.ndarray,
    seg_m: np.ndarray,
    grip_mps2: float,
    long_share: float,
) -> np.ndarray:
    """The closed line's speeds [m/s] (n,) within `grip_mps2` (module docstring).

    Args:
        v_mps: (n,) the line's own speeds [m/s], positive (an upper bound everywhere).
        kappa_1pm: (n,) the path's curvature at the nodes [1/m].
        seg_m: (n,) length of the segment from node i to node i+1 (the last: back to 0) [m].
        grip_mps2: ``G``, the lateral acceleration the car holds [m/s^2], positive.
        long_share: share of ``G`` the profile spends along the track, in (0, 1].
    """
    return run_job(_profile_passes(v_mps, kappa_1pm, seg_m, grip_mps2, long_share))


def _profile_passes(
    v_mps: np.ndarray,
    kappa_1pm: np.ndarray,
    seg_m: np.ndarray,
    grip_mps2: float,
    long_share: float,
) -> Job[np.ndarray]:
    """``grip_speed_profile`` as a job (``run_job``): each slice a chunk of at most
    ``PASS_CHUNK`` node steps of its passes; returns the speeds (arguments as there)."""
    if not grip_mps2 > 0.0 or not 0.0 < long_share <= 1.0:
        raise ValueError("the grip must be positive and the longitudinal share in (0, 1]")
    v_line = np.asarray(v_mps, dtype=float)
    kappa = np.abs(np.asarray(kappa_1pm, dtype=float))
    v = np.minimum(v_line, np.sqrt(grip_mps2 / np.maximum(kappa, 1e-12)))
    seg = [float(x) for x in seg_m]
    k = [float(x) for x in kappa]
    w = [float(x) for x in v]
    n = len(w)
    g_x = long_share * grip_mps2
    sqrt = math.sqrt

    def along(i: int) -> float:  # the ellipse's longitudinal room at node i [m/s^2]
        u = w[i] * w[i] * k[i] / grip_mps2
        return g_x * sqrt(max(0.0, 1.0 - u * u))

    for _ in range(PASSES):
        for start in range(0, n, PASS_CHUNK):  # forward: drive out of the bends
            stop = min(start + PASS_CHUNK, n)
            yield stop - start
            for i in range(start, stop):
                j = (i + 1) % n
                w[j] = min(w[j], sqrt(w[i] * w[i] + 2.0 * along(i) * seg[i]))
        for end in range(n, 0, -PASS_CHUNK):  # backward: brake into them
            stop = max(end - PASS_CHUNK, 0)
            yield end - stop
            for i in range(end - 1, stop - 1, -1):
                j = (i + 1) % n
                w[i] = min(w[i], sqrt(w[j] * w[j] + 2.0 * along(j) * seg[i]))
    return np.maximum(np.asarray(w), 1e-3)


@dataclass(frozen=True)
class GripLine:
    """A line re-planned for the grip found, ready to drive.

    Attributes:
        raceline: the line with its profile within the grip and the plan along it.
        scale: the grip adaptation's speed scale it was re-planned for, in (0, 1].
        slow_plans: its plan at each of the slower shares asked (``ReferenceLap.slower``:
            the steering of a car held below the line's speeds), in their order.
    """

    raceline: Raceline
    scale: float
    slow_plans: tuple[ReferenceLap, ...]


def grip_raceline(
    raceline: Raceline,
    scale: float,
    vehicle: DynamicVehicleParams,
    long_share: float,
    line_grip: float | None = None,
) -> Raceline:
    """`raceline` re-planned for a car that held it at `scale` (0, 1] of its speeds (module
    docstring): its path, the profile within ``G = scale^2 A``, and the plan along it.

    Args:
        raceline: the line as built (its ``reference``'s nodes are its points).
        scale: the grip adaptation's speed scale ``c``; 1 returns `raceline`.
        vehicle: the car the plan's steady-state steering is for.
        long_share: ``[planner.raceline] grip_profile_long_share``.
        line_grip: ``A`` [m/s^2] (None: ``line_grip_mps2`` of the line).
    """
    if scale == 1.0:
        return raceline
    return run_job(_grip_job(raceline, scale, vehicle, long_share, line_grip, (), None,
                             None)).raceline


class GripReplan(SlicedJob[GripLine]):
    """``grip_raceline`` with the slower plans, done a slice at a time (module docstring,
    ``raceline.jobs.SlicedJob``): ``advance(work)`` once per tick until it returns True,
    then ``result`` is the ``GripLine``.

    Args:
        raceline, scale, vehicle, long_share, line_grip: as ``grip_raceline``.
        slow_shares: the shares (each in (0, 1)) of the re-planned line's speeds to make
            its slower plans at (the planner's ``FEED_FORWARD_SCALES`` but the last).
        line_steady: `raceline`'s path at its own speeds (``ReferenceLap.from_path``), when
            the caller keeps it (None: made in the job).
    """

    def __init__(
        self,
        raceline: Raceline,
        scale: float,
        vehicle: DynamicVehicleParams,
        long_share: float,
        line_grip: float | None,
        slow_shares: Sequence[float] = (),
        line_steady: ReferenceLap | None = None,
    ) -> None:
        super().__init__(_grip_job(raceline, scale, vehicle, long_share, line_grip,
                                   tuple(slow_shares), line_steady, PLAN_CHUNK))
        self.scale = float(scale)


def _grip_job(
    raceline: Raceline,
    scale: float,
    vehicle: DynamicVehicleParams,
    long_share: float,
    line_grip: float | None,
    slow_shares: tuple[float, ...],
    line_steady: ReferenceLap | None,
    chunk: int | None,
) -> Job[GripLine]:
    """The re-plan as a job (``raceline.jobs``; arguments as ``GripReplan``): the passes,
    then the plans (``ReferenceLap.from_path_job``'s slices of `chunk` nodes, None: all at
    once)."""
    if not 0.0 < scale <= 1.0:
        raise ValueError(f"speed scale must be in (0, 1], got {scale}")
    ref = raceline.reference
    a_line = line_grip if line_grip is not None else line_grip_mps2(ref.v_mps, ref.kappa_1pm)
    seg = np.diff(np.append(ref.s_m, ref.length_m))
    v_g = yield from _profile_passes(ref.v_mps, ref.kappa_1pm, seg, scale * scale * a_line,
                                     long_share)
    share = np.clip(v_g / ref.v_mps, 1e-3, 1.0)
    plan = yield from ref.slower_job(share, vehicle, line_steady, chunk)
    slow_plans: list[ReferenceLap] = []
    if slow_shares:
        steady = yield from ReferenceLap.from_path_job(plan.line, plan.kappa_1pm, plan.v_mps,
                                                       vehicle, chunk)
        for k in slow_shares:
            slow_plans.append((yield from plan.slower_job(k, vehicle, steady, chunk)))
    line = replace(raceline, speed_mps=np.asarray(plan.v_mps), reference=plan)
    return GripLine(line, float(scale), tuple(slow_plans))
