"""Joining the racing line from a standing start anywhere on the track (``raceline.join``,
issue #21): the blended path's maths, and the closed loop from starts where the raceline
used to steer straight for its line and run over the wall."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from services.planner.raceline.join import (
    LENGTH_SHARES,
    MAX_SLOPE,
    MIN_LENGTH_M,
    ON_LINE_M,
    STEEPEST,
    LineJoin,
    smootherstep_weight,
)

LENGTH = 20.0
S = np.linspace(0.0, LENGTH, 201)[:-1]
#: a line swinging from side to side of a straight track (right +) [m]
Q = 0.3 * np.sin(2.0 * math.pi * S / 10.0)


def _straight(s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """A straight line along x: points and right normals."""
    s = np.atleast_1d(s)
    return np.column_stack([s, np.zeros_like(s)]), np.tile([0.0, -1.0], (len(s), 1))


def test_the_weight_is_flat_at_both_ends() -> None:
    assert smootherstep_weight(0.0) == 1.0 and smootherstep_weight(1.0) == 0.0
    assert smootherstep_weight(-1.0) == 1.0 and smootherstep_weight(2.0) == 0.0
    h = 1e-4
    for u in (0.0, 1.0):
        assert abs(smootherstep_weight(u + h) - smootherstep_weight(u - h)) < 1e-9
    steepest = max(abs(smootherstep_weight(u + h) - smootherstep_weight(u - h)) / (2 * h)
                   for u in np.linspace(0.0, 1.0, 101))
    assert steepest == pytest.approx(STEEPEST, rel=1e-3)


def test_a_car_on_its_line_needs_no_join_where_the_line_runs_along_the_track() -> None:
    """On the line where it runs along the track (the crest of its swing): no blend; on
    the line where it crosses the track (the car put down along the track stands across
    the line): a blend that leaves along the track."""
    crest = 2.5  # Q's maximum: the line parallel to the track
    e0 = float(np.interp(crest, S, Q)) + 0.5 * ON_LINE_M
    assert LineJoin.start(crest, e0, S, Q, LENGTH) is None
    across = 5.0  # Q crosses the centreline at its steepest, 0.19 m/m
    e0 = float(np.interp(across, S, Q))
    join = LineJoin.start(across, e0, S, Q, LENGTH)
    assert join is not None
    assert abs(join.slope(across + 1e-3) + float(np.gradient(Q, S)[50])) < 0.02  # along


def test_the_blend_starts_at_the_car_ends_on_the_line_and_stays_between_them() -> None:
    e0 = -0.25  # the car stands 0.25 m left of the centreline
    join = LineJoin.start(1.0, e0, S, Q, LENGTH)
    assert join is not None
    q0 = float(join.line_e(1.0))
    assert join.offset(1.0) == pytest.approx(e0 - q0)  # the car's own position
    # behind the start it stays there; past its end it is the line
    assert join.offset(0.9) == pytest.approx(e0 - float(join.line_e(0.9)))
    end = 1.0 + join.length_m
    assert join.done(end) and join.offset(end + 0.01) == 0.0
    for s in np.linspace(1.0, end, 50):
        p = join.offset(s) + float(join.line_e(s))  # the path's lateral position
        q = float(join.line_e(s))
        assert min(e0, q) - 1e-9 <= p <= max(e0, q) + 1e-9
    # its length keeps the blend's slope within MAX_SLOPE for the largest gap on the way
    gaps = np.abs(e0 - join.line_e(np.linspace(1.0, end, 40)))
    assert STEEPEST * float(np.max(gaps)) / join.length_m <= MAX_SLOPE * 1.05


def test_on_a_straight_the_path_leaves_parallel_and_meets_the_line_tangentially() -> None:
    q = np.full_like(S, 0.3)  # the line 0.3 m right of the centreline all along
    join = LineJoin.start(2.0, 0.0, S, q, LENGTH, line_xy=_straight)
    assert join is not None
    assert abs(join.slope(2.0 + 1e-3)) < 1e-3
    assert abs(join.slope(2.0 + join.length_m - 1e-3)) < 1e-3
    assert join.path_curvature(2.0, _straight) == pytest.approx(0.0, abs=0.02)
    mid = 2.0 + 0.5 * join.length_m
    assert join.slope(mid) == pytest.approx(STEEPEST * 0.3 / join.length_m, rel=0.02)


def _arc(s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """A circle of radius 5 m (left turn): points and right normals."""
    s = np.atleast_1d(s)
    h = s / 5.0
    pts = np.column_stack([5.0 * np.sin(h), 5.0 * (1.0 - np.cos(h))])
    return pts, np.column_stack([np.sin(h), -np.cos(h)])


def test_the_offsets_and_curvatures_at_once_are_the_station_by_station_ones() -> None:
    """``offsets`` and ``path_curvatures`` (one call for many stations, as the tick's feed
    uses them) equal ``offset`` and the three-point circle station by station, behind the
    start, along the blend and past its end, across the lap's wrap."""
    join = LineJoin.start(17.0, -0.25, S, Q, LENGTH)
    assert join is not None
    laps = np.linspace(-30.0, 50.0, 801)  # the line's table: np.interp's periodic one
    assert np.array_equal(join.line_e(laps), np.interp(laps, S, Q, period=LENGTH))
    s = np.linspace(15.0, 17.0 + join.length_m + 2.0, 97)
    assert np.allclose(join.offsets(s), [join.offset(float(x)) for x in s], atol=1e-12)
    for xy in (_straight, _arc):
        at_once = join.path_curvatures(s, xy)
        for x, k in zip(s, at_once, strict=True):
            pts, normals = xy(np.array([x - 0.3, x, x + 0.3]))
            d = np.array([join.offset(x + h) for h in (-0.3, 0.0, 0.3)])
            a, b, c = pts + d[:, None] * normals
            ab, bc, ca = b - a, c - b, a - c
            cross = ab[0] * bc[1] - ab[1] * bc[0]
            den = math.sqrt(float(ab @ ab) * float(bc @ bc) * float(ca @ ca))
            assert k == pytest.approx(2.0 * cross / den, abs=1e-9)
            assert join.path_curvature(float(x), xy) == pytest.approx(k, abs=1e-12)
    past = 17.0 + join.length_m + 1.0  # on the line: the arc's own curvature
    assert join.path_curvatures(np.array([past]), _arc)[0] == pytest.approx(0.2, rel=1e-6)


def test_a_blend_too_tight_for_the_car_is_shortened_or_dropped() -> None:
    """A blend bending tighter than the join may is replaced by a shorter one (the first
    of ``LENGTH_SHARES`` within the limit, else the least tight of them); none at all
    when even that one is tighter than the car can turn."""
    full = LineJoin.start(2.0, -0.25, S, Q, LENGTH, line_xy=_straight)
    assert full is not None
    shares = [replace(full, length_m=max(k * full.length_m, MIN_LENGTH_M))
              for k in LENGTH_SHARES]
    bends = [j.tightest_curvature(_straight) for j in shares]
    # within the limit: the longest blend that is (here the limit admits only the loosest)
    loosest = int(np.argmin(bends))
    got = LineJoin.start(2.0, -0.25, S, Q, LENGTH, line_xy=_straight,
                         max_curvature_1pm=bends[loosest] * 1.0001, turn_curvature_1pm=10.0)
    assert got is not None and got.length_m == pytest.approx(shares[loosest].length_m)
    # no blend within the limit, but within the turning circle: the least tight one
    got = LineJoin.start(2.0, -0.25, S, Q, LENGTH, line_xy=_straight,
                         max_curvature_1pm=1e-3, turn_curvature_1pm=10.0)
    assert got is not None and got.length_m == pytest.approx(shares[loosest].length_m)
    # even that one tighter than the car turns: the tracker joins directly
    assert LineJoin.start(2.0, -0.25, S, Q, LENGTH, line_xy=_straight,
                          max_curvature_1pm=1e-3, turn_curvature_1pm=1e-3) is None


@pytest.mark.slow
def test_standing_starts_where_the_line_is_far_join_it_without_leaving_the_track() -> None:
    """From rest on the centreline of paperlike at stations where, before the join, the
    raceline steered for its line at full lock and full throttle and left the track (3 of
    them: 11.71, 15.69, 39.48 m; measured with the old planner), it now stays on the track
    and under the cap for 6 s."""
    from services.planner.mintime.store import ensure_artefacts
    from services.planner.raceline.planner import RacelinePlanner
    from services.simulator import Command
    from services.tools.bench.head_to_head import SimCar
    from shared.config import load_config
    from shared.track import load_track

    track = load_track("paperlike")
    cfg = load_config(None)
    ensure_artefacts("raceline", track, cfg.planner, cfg.vehicle, progress=None)
    planner = RacelinePlanner(track, cfg.planner, cfg.curvature, vehicle=cfg.vehicle)
    period, step = planner.settings.dt_s, cfg.simulator.integration_step_s
    for s0 in (11.71, 15.69, 39.48):
        car = SimCar(track, cfg.simulator, s0)
        planner.reset()
        top = 0.0
        for _ in range(int(6.0 / period)):
            res = planner.step(*car.rear_pose())
            new = Command(res.command.speed_mps, res.command.steering_rad)
            car.step(car.cmd, 0.002)  # the compute delay, then the command
            n = max(1, math.ceil((period - 0.002) / step - 1e-9))
            for _ in range(n):
                car.step(new, (period - 0.002) / n)
            car.cmd = new
            top = max(top, car.sim.state.v_mps)
        assert car.off == 0, f"left the track from s = {s0} m"
        assert top <= 4.18 * 1.01, f"{top:.3f} m/s from s = {s0} m"


def test_a_linear_car_joins_at_its_line_s_speeds_into_a_bend_tighter_than_its_lock() -> None:
    """gen-1004 with the gym's unbounded ``linear`` tyres, from rest at s = 4.03 m (a
    tuning track of the standing starts): the join ends in a bend the line drifts through,
    tighter than the lock turns the car. Capped by the line's own curvature as if the tyres
    saturated, the car came into it at 2.1 m/s against the plan's 3-4 and left the track
    (0.46 m wide). Capped only by what the blend bends beyond the line, it stays on."""
    from benchmarks.standing_starts import race_from
    from services.planner.mintime.store import ensure_artefacts
    from services.planner.raceline.planner import RacelinePlanner
    from shared.config import config_from_dict
    from shared.config.methods import RACELINE
    from shared.track import load_track

    track = load_track("gen:1004")
    cfg = config_from_dict({"vehicle": {"tyre_model": "linear"}})
    ensure_artefacts(RACELINE, track, cfg.planner, cfg.vehicle, progress=None)
    planner = RacelinePlanner(track, cfg.planner, cfg.curvature, vehicle=cfg.vehicle)
    assert not planner.drivable_slower
    off, top, _ = race_from(planner, track, cfg, 4.03, 3.0)
    assert off == 0
    assert top <= 4.18 * 1.01


def test_a_standing_start_at_ten_metres_per_second_joins_without_a_slide() -> None:
    """gen-1006 at ``--v-max 10`` (a tuning track), from rest 0.3 m past the start line:
    the line crosses the track there at 0.2 rad and the car accelerates to 6-7 m/s within
    the join. With the feedback scheduled on the plan's 6-8 m/s (a tenth of its gain) and
    the join at full speed, the car ran 0.5 m past the blend, the grip adaptation took that
    for a slide and cut the race to 0.7 of the line. Now the join is driven at the speed
    of the tracker's full feedback, the feedback at the car's own speed: no cut in the out
    lap and the first flying lap, and no off-track event."""
    from benchmarks.robustness import config_for
    from benchmarks.standing_starts import race_from
    from services.planner.mintime.store import ensure_artefacts
    from services.planner.raceline.planner import RacelinePlanner
    from shared.config.methods import RACELINE
    from shared.track import load_track

    track = load_track("gen:1006")
    cfg = config_for("default", 10.0)
    assert cfg.planner.raceline.v_max_mps == pytest.approx(10.0, abs=0.5)
    ensure_artefacts(RACELINE, track, cfg.planner, cfg.vehicle, progress=None)
    planner = RacelinePlanner(track, cfg.planner, cfg.curvature, vehicle=cfg.vehicle)
    cuts = []
    adapt = planner._adapt_grip

    def watched(e_line_m: float) -> None:
        before = planner.speed_scale
        adapt(e_line_m)
        if planner.speed_scale < before:
            cuts.append((planner._s_line, e_line_m))

    planner._adapt_grip = watched
    off, top, _ = race_from(planner, track, cfg, 0.3, 16.0)
    assert cuts == []
    assert off == 0
    assert top > 7.0  # it raced at speed, not crept
