"""The simulator's real-time loop on a machine too slow for real time.

A fake clock makes every simulation step cost more wall time than it simulates: the loop
must then skip ahead (re-anchor its clocks) so that what it publishes stays fresh for the
bridge and the planner, count it, say so, and keep integrating the car step by step. On
time it must not skip at all.
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

    def timed_publish(res):  # type: ignore[no-untyped-def]
        lags.append(machine.wall() - svc.stamp(svc.sim.t_s))
        return publish(res)

    svc.advance = slow_advance  # type: ignore[method-assign]
    svc.publish = timed_publish  # type: ignore[method-assign]
    svc.run(Waiter())  # type: ignore[arg-type]
    return svc, bus, lags


def test_on_time_it_never_skips() -> None:
    svc, _, lags = _run(cost_s=0.2 * H)
    assert svc.skips == 0 and svc.overruns == 0
    assert max(lags) <= 0.0 + 1e-9  # it publishes when the wall clock reaches the stamp


def test_too_slow_for_real_time_it_skips_ahead_and_its_stamps_stay_fresh() -> None:
    svc, bus, lags = _run(cost_s=3 * H)  # each 10 ms step takes 30 ms
    assert svc.skips > 0 and svc.skipped_s > 0.0
    # the simulation ran slower than real time, integrating every step
    assert svc.sim.t_s == pytest.approx(300 * H, abs=2 * H)
    # what it publishes lags the wall clock by at most the skip threshold plus one step
    # (without the skip: 300 steps x 20 ms = 6 s behind by the end)
    assert max(lags) <= MAX_LAG_S + 3 * H + 1e-9
    stamps = [p.stamp_s for p in bus.sent(bus.keys.pose, Pose)]
    assert len(stamps) > 10 and all(b > a for a, b in itertools.pairwise(stamps))


def test_it_says_so_when_it_skips(caplog: pytest.LogCaptureFixture) -> None:
    with caplog.at_level("WARNING", logger=service.__name__):
        svc, _, _ = _run(cost_s=3 * H)
    said = [r.getMessage() for r in caplog.records if "skips ahead" in r.getMessage()]
    assert said and len(said) < svc.skips  # the 1st, 10th, 100th time: not every time
