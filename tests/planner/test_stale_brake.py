"""The planner's stale-state brake is a deadline: the brake goes out ``stale_state_s`` (100 ms)
after the last state, not up to a check period later (issue 15: it was 101-152 ms).

Two tests over 20 trials each, on the real ``PlannerShell`` with a stub planner (no solver)
on ``shared.bus.fake.FakeBus``:

* deterministic: a fake clock, advanced by the shell's own deadline waits; states arrive at
  random gaps shorter than the limit, then stop. Proves the logic: no brake while states
  come, the brake exactly ``stale_state_s`` after the last one, repeated every period.
* real time: the shell's two workers on real threads and clocks; the delay is taken from the
  planner's OWN timestamps (its wall time at the last state's arrival and the brake
  command's stamp), so the test's own scheduling does not enter it. Prints median / max and
  asserts the brake is never early and its median within 110 ms. The max is printed, not
  asserted: on this shared 2-core machine (load average above 10 while other suites run) a
  thread's wake-up is sometimes late by more than 10 ms, which no code can prevent; the
  deadline itself is proven by the first test. Alone it gave median 100.4 ms, max 102.3 ms.
"""

from __future__ import annotations

import random
import statistics
import threading
import time

import numpy as np

from services.planner.interface import DriveCommand, SolveResult
from services.planner.service import BrakeDeadline, PlannerShell
from shared.bus.fake import FakeBus
from shared.config.planner import PlannerSettings
from shared.messages import DriveCmd, PlanStatusName, State

TRIALS = 20
#: The acceptance: brake at most this long after the last state [s] (limit 100 ms + jitter).
BRAKE_BOUND_S = 0.110
N = 3


class StubPlanner:
    """A PlannerLike without a solver: commands 2 m/s at once."""

    def __init__(self, settings: PlannerSettings) -> None:
        self.settings = settings
        self.resets = 0
        self.steps = 0

    def step(self, x_m: float, y_m: float, yaw_rad: float, on_command=None) -> SolveResult:
        self.steps += 1
        cmd = DriveCommand(speed_mps=2.0, steering_rad=0.1)
        if on_command is not None:
            on_command(cmd)
        return SolveResult(
            command=cmd, states=np.zeros((N + 1, 4)), inputs=np.zeros((N, 3)),
            status=PlanStatusName.SOLVED, solver_status="ok", iterations=1, solve_time_s=1e-3,
            beta=np.zeros(N), s_m=0.0, e_con_m=0.0, consecutive_failures=0, method="cimpcc",
        )

    def prepare(self) -> None:
        pass

    def reset(self) -> None:
        self.resets += 1


class FakeClock:
    """A settable clock [s]."""

    def __init__(self, t: float) -> None:
        self.t = t

    def __call__(self) -> float:
        return self.t


def _state(stamp_s: float) -> State:
    return State(stamp_s=stamp_s, x_m=0.0, y_m=0.0, yaw_rad=0.0, speed_mps=1.0,
                 yaw_rate_radps=0.0, steering_rad=0.0, source_stamp_s=stamp_s, valid=True)


def _brakes(bus: FakeBus) -> list[DriveCmd]:
    return [c for c in bus.sent(bus.keys.drive_cmd, DriveCmd) if c.speed_mps == 0.0]


def test_brake_deadline_core() -> None:
    d = BrakeDeadline(stale_s=0.1, repeat_s=0.05, now=10.0)
    assert abs(d.remaining(10.0) - 0.1) < 1e-12 and not d.fire(10.099)
    d.arm(10.05)
    assert abs(d.remaining(10.1) - 0.05) < 1e-12 and not d.fire(10.149)
    assert d.fire(10.15) and abs(d.remaining(10.15) - 0.05) < 1e-12  # repeated every 50 ms
    assert not d.fire(10.19) and d.fire(10.2001)


def test_stale_brake_deadline_with_a_fake_clock() -> None:
    """20 trials: states at random gaps < 100 ms, then silence; the brake comes exactly
    100 ms after the last state (never before), then every planner period."""
    rng = random.Random(15)
    settings = PlannerSettings()
    mono, wall = FakeClock(100.0), FakeClock(1_800_000_000.0)
    bus = FakeBus()
    shell = PlannerShell(StubPlanner(settings), bus, clock=mono, wall_clock=wall)
    stale, period = settings.stale_state_s, settings.dt_s
    assert stale == 0.1
    delays, waits = [], []

    def advance(dt: float) -> None:
        mono.t += dt
        wall.t += dt

    for _trial in range(TRIALS):
        gaps = [0.0] + [rng.uniform(0.005, 0.095) for _ in range(rng.randint(3, 12))]
        arrivals = [float(a) for a in np.cumsum(gaps) + mono.t]  # the first one at once
        before = len(_brakes(bus))
        last_wall = None
        while True:
            if arrivals and mono.t >= arrivals[0] - 1e-12:
                arrivals.pop(0)
                last_wall = wall.t
                shell.on_state(_state(wall.t))
                continue

            def wait(left: float, pending: list[float] = arrivals) -> None:
                waits.append(left)
                advance(min(left, pending[0] - mono.t) if pending else left)

            if shell.deadline_step(wait):
                break
        brakes = _brakes(bus)
        assert len(brakes) == before + 1, "no brake while the states came"
        assert last_wall is not None
        delays.append(brakes[-1].stamp_s - last_wall)
        # silent on: the brake is repeated every planner period
        assert not shell.deadline_step(lambda left: advance(left))
        assert shell.deadline_step(lambda left: None)
        assert abs(_brakes(bus)[-1].stamp_s - brakes[-1].stamp_s - period) < 1e-6
    assert all(abs(d - stale) < 1e-6 for d in delays), delays
    assert max(delays) <= BRAKE_BOUND_S
    assert min(waits) >= 0.0


def test_stale_brake_real_time_delays() -> None:
    """20 trials on real threads: the brake's delay after the last state, from the planner's
    own timestamps: never early, median at most 110 ms (printed: median and max)."""
    settings = PlannerSettings()
    bus = FakeBus()
    shell = PlannerShell(StubPlanner(settings), bus)
    stop = threading.Event()
    server = threading.Thread(target=shell.serve, args=(stop,), daemon=True)
    server.start()
    delays = []
    try:
        for _trial in range(TRIALS):
            n_before = len(shell.deadline_brakes)
            for _ in range(4):  # 20 Hz states, as the bridge gives them
                bus.deliver(bus.keys.state, _state(time.time()))
                time.sleep(0.05)
            deadline = time.monotonic() + 2.0
            while len(shell.deadline_brakes) == n_before and time.monotonic() < deadline:
                time.sleep(0.01)
            assert len(shell.deadline_brakes) > n_before, "no brake after the states stopped"
            last_wall, stamp = shell.deadline_brakes[n_before]
            delays.append(stamp - last_wall)
            time.sleep(0.03)
    finally:
        stop.set()
        bus.close()
        server.join(5.0)
        shell.close()
        shell.join_workers()
    assert not server.is_alive()
    ms = [d * 1e3 for d in delays]
    print(f"\nstale-state brake after the last state over {TRIALS} trials: "
          f"median {statistics.median(ms):.1f} ms, max {max(ms):.1f} ms "
          f"(limit {settings.stale_state_s * 1e3:.0f} ms)")
    assert min(delays) >= settings.stale_state_s - 1e-3, ms  # never early
    assert statistics.median(delays) <= BRAKE_BOUND_S, ms
    late = [d for d in ms if d > BRAKE_BOUND_S * 1e3]
    if late:
        print(f"  {len(late)} of {TRIALS} wake-ups late on this loaded machine: {late}")


def test_a_solve_is_triggered_by_the_first_state_of_a_new_pose_once_per_period() -> None:
    """Issue 25: the planner solves on the state of a new pose (the bridge publishes one per
    fused pose), at most once per period; a repeat of the same pose (the bridge's fallback
    prediction) only once 1.5 periods have passed without a new pose."""
    settings = PlannerSettings()
    dt = settings.dt_s
    mono, wall = FakeClock(100.0), FakeClock(1000.0)
    planner = StubPlanner(settings)
    shell = PlannerShell(planner, FakeBus(), clock=mono, wall_clock=wall)

    def state(pose_stamp: float) -> None:
        shell.on_state(State(stamp_s=wall.t, x_m=0.0, y_m=0.0, yaw_rad=0.0, speed_mps=1.0,
                             yaw_rate_radps=0.0, steering_rad=0.0,
                             source_stamp_s=pose_stamp, valid=True))

    def at(t: float) -> None:  # both clocks to `t` after the start
        mono.t, wall.t = 100.0 + t, 1000.0 + t

    at(0.0)
    state(1000.0)
    assert planner.steps == 1  # the first state is solved at once
    at(0.025)
    state(1000.025)  # a new pose, but within the period: skipped
    at(0.05)
    state(1000.05)  # the next pose, a period later: solved
    assert planner.steps == 2
    at(0.0625)
    state(1000.05)  # the same pose again (a prediction): not solved
    at(0.05 + 1.4 * dt)
    state(1000.05)
    assert planner.steps == 2
    at(0.05 + 1.5 * dt)
    state(1000.05)  # no new pose for 1.5 periods: the prediction keeps the control going
    assert planner.steps == 3
    at(0.05 + 1.5 * dt + 0.8 * dt)
    state(1000.0 + 0.05 + 2.3 * dt)  # a new pose 0.8 periods later: solved
    assert planner.steps == 4
