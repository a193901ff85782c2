"""The simulator's real-time loop on a machine too slow for real time.

A fake clock makes every simulation step cost more wall time than it simulates: the loop
must then slow the world (re-anchor its clocks by the lag beyond ``MAX_LAG_S``) so that what
it publishes stays fresh for the bridge and the planner, count it, say so, and keep
integrating the car step by step. On time it must not slow at all. The sensor readings
(the lidar scan) are computed before the loop waits for a step's instant.
"""

from __future__ import annotations

import itertools
import threading

import pytest

from services.simulator import service
from services.simulator.service import MAX_LAG_S, SimulatorService
from shared.bus.fake import FakeBus
from shared.config import RacestackConfig
from shared.messages import Pose
from shared.track import OccupancyGrid, load_track

H = 0.01  # the default integration step [s]
WALL0 = 1_000_000.0  # the fake wall clock at monotonic 0 [s]


@pytest.fixture(scope="module")
def grid() -> OccupancyGrid:
    return service.occupancy_for(load_track(RacestackConfig().track.source))  # once


@pytest.fixture(autouse=True)
def _one_grid(monkeypatch: pytest.MonkeyPatch, grid: OccupancyGrid) -> None:
    monkeypatch.setattr(service, "occupancy_for", lambda _track: grid)


class SlowMachine:
    """A monotonic clock (and its wall clock) that moves `cost_s` per simulation step, and
    moves `wait`'s time at once instead of sleeping; stops the loop after `steps` steps."""

    def __init__(self, cost_s: float, steps: int) -> None:
        self.t = 0.0
        self.cost_s = cost_s
        self.steps = steps
        self.stop = threading.Event()

    def clock(self) -> float:
        return self.t

    def wall(self) -> float:
        return WALL0 + self.t


def _run(cost_s: float, steps: int = 300) -> tuple[SimulatorService, FakeBus, list[float]]:
    """Run the loop for `steps` steps of `cost_s` each; returns the service, its bus and how
    far behind the wall clock the simulation's present was at each publication [s]."""
    cfg = RacestackConfig()
    machine = SlowMachine(cost_s, steps)
    bus = FakeBus()
    svc = SimulatorService(
        cfg, bus, load_track(cfg.track.source), clock=machine.clock, wall_clock=machine.wall
    )  # type: ignore[arg-type]
    advance = svc.advance
    count = 0

    def slow_advance(h: float):  # type: ignore[no-untyped-def]
        nonlocal count
        machine.t += machine.cost_s  # the step's compute time
        count += 1
        if count >= machine.steps:
            machine.stop.set()
        return advance(h)

    class Waiter:  # stop.wait(delay): the fake time passes at once
        def is_set(self) -> bool:
            return machine.stop.is_set()

        def wait(self, delay: float) -> bool:
            machine.t += max(delay, 0.0)
            return machine.stop.is_set()

    lags: list[float] = []
    publish = svc.publish

    def timed_publish(res, readings=None):  # type: ignore[no-untyped-def]
        lags.append(machine.wall() - svc.stamp(svc.sim.t_s))
        return publish(res, readings)

    svc.advance = slow_advance  # type: ignore[method-assign]
    svc.publish = timed_publish  # type: ignore[method-assign]
    svc.run(Waiter())  # type: ignore[arg-type]
    return svc, bus, lags


def test_on_time_it_never_slows() -> None:
    svc, _, lags = _run(cost_s=0.2 * H)
    assert svc.slowdowns == 0 and svc.overruns == 0
    assert max(lags) <= 0.0 + 1e-9  # it publishes when the wall clock reaches the stamp


def test_too_slow_for_real_time_the_world_slows_and_its_stamps_stay_fresh() -> None:
    svc, bus, lags = _run(cost_s=3 * H)  # each 10 ms step takes 30 ms
    assert svc.slowdowns > 0 and svc.slowed_s > 0.0
    assert svc.longest_slowdown_s <= svc.slowed_s
    # the simulation ran slower than real time, integrating every step
    assert svc.sim.t_s == pytest.approx(300 * H, abs=2 * H)
    # what it publishes lags the wall clock by at most the threshold (without the slowdown:
    # 300 steps x 20 ms = 6 s behind by the end)
    assert max(lags) <= MAX_LAG_S + 1e-9
    stamps = [p.stamp_s for p in bus.sent(bus.keys.pose, Pose)]
    assert len(stamps) > 10 and all(b > a for a, b in itertools.pairwise(stamps))


def test_it_says_so_when_the_world_slows(caplog: pytest.LogCaptureFixture) -> None:
    with caplog.at_level("WARNING", logger=service.__name__):
        svc, _, _ = _run(cost_s=3 * H)
    said = [r.getMessage() for r in caplog.records if "the world slows" in r.getMessage()]
    assert said and len(said) < svc.slowdowns  # the 1st, 10th, 100th time: not every time


def test_one_long_stall_slows_the_world_once_by_its_excess() -> None:
    """A step that waited 100 ms for a core: one slowdown of 100 - MAX_LAG_S ms (the rest is
    caught up), the stamps still rising, every step integrated."""
    cfg = RacestackConfig()
    machine = SlowMachine(0.0, 200)
    bus = FakeBus()
    svc = SimulatorService(
        cfg, bus, load_track(cfg.track.source), clock=machine.clock, wall_clock=machine.wall
    )  # type: ignore[arg-type]
    advance = svc.advance
    count = 0

    def stalling_advance(h: float):  # type: ignore[no-untyped-def]
        nonlocal count
        count += 1
        machine.t += 0.1 if count == 100 else 0.001
        if count >= machine.steps:
            machine.stop.set()
        return advance(h)

    class Waiter:
        def is_set(self) -> bool:
            return machine.stop.is_set()

        def wait(self, delay: float) -> bool:
            machine.t += max(delay, 0.0)
            return machine.stop.is_set()

    svc.advance = stalling_advance  # type: ignore[method-assign]
    svc.run(Waiter())  # type: ignore[arg-type]
    assert svc.slowdowns == 1
    assert svc.slowed_s == pytest.approx(0.1 - MAX_LAG_S, abs=H + 1e-6)
    stamps = [p.stamp_s for p in bus.sent(bus.keys.pose, Pose)]
    assert all(b > a for a, b in itertools.pairwise(stamps))


def test_the_lidar_scan_is_computed_before_the_wait_for_its_instant() -> None:
    """The step's sensor readings come before the loop waits for the step's wall instant,
    so a scan's cost is spent in the step's slack, not between that instant and the pose."""
    cfg = RacestackConfig()
    machine = SlowMachine(0.0, 50)
    svc = SimulatorService(
        cfg, FakeBus(), load_track(cfg.track.source), clock=machine.clock,
        wall_clock=machine.wall,
    )  # type: ignore[arg-type]
    events: list[str] = []
    update, advance = svc.sensors.update, svc.advance
    count = 0

    def counted_advance(h: float):  # type: ignore[no-untyped-def]
        nonlocal count
        count += 1
        events.append("step")
        if count >= machine.steps:
            machine.stop.set()
        return advance(h)

    def traced_update(res):  # type: ignore[no-untyped-def]
        events.append("sensors")
        return update(res)

    class Waiter:
        def is_set(self) -> bool:
            return machine.stop.is_set()

        def wait(self, delay: float) -> bool:
            events.append("wait")
            machine.t += max(delay, 0.0)
            return machine.stop.is_set()

    svc.advance = counted_advance  # type: ignore[method-assign]
    svc.sensors.update = traced_update  # type: ignore[method-assign]
    svc.run(Waiter())  # type: ignore[arg-type]
    assert events[:6] == ["step", "sensors", "wait"] * 2
