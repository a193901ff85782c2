"""The planner service hands the opponents to a method that plans with them (issue #24).

On the real ``PlannerShell`` over ``shared.bus.fake.FakeBus`` with a stub planner (no
solver): the shell subscribes to its car's ``opponents`` only when the registry says the
method plans with opponents; before each solve the planner gets the newest record's tracks,
moved to now at their velocity; a stale record gives none and malformed tracks are dropped,
both counted, never a crash.
"""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from services.planner.interface import DriveCommand, SolveResult
from services.planner.opponents import RecordCounts, estimates_from_record
from services.planner.service import PlannerShell
from shared.bus.fake import FakeBus
from shared.config.methods import CIMPCC, METHODS, RACELINE, plans_with_opponents
from shared.config.planner import PlannerSettings
from shared.messages import DriveCmd, Opponents, OpponentTrack, PlanStatusName, State

N = 3


class StubPlanner:
    """A PlannerLike that takes opponents and records what it was given before each step."""

    def __init__(self, settings: PlannerSettings) -> None:
        self.settings = settings
        self.given: list[list] = []
        self.current: list = []

    def set_opponents(self, opponents) -> None:
        self.current = list(opponents)

    def step(self, x_m: float, y_m: float, yaw_rad: float, on_command=None) -> SolveResult:
        self.given.append(self.current)
        cmd = DriveCommand(speed_mps=2.0, steering_rad=0.0)
        if on_command is not None:
            on_command(cmd)
        return SolveResult(
            command=cmd, states=np.zeros((N + 1, 4)), inputs=np.zeros((N, 3)),
            status=PlanStatusName.SOLVED, solver_status="ok", iterations=1, solve_time_s=1e-3,
            beta=np.zeros(N), s_m=0.0, e_con_m=0.0, consecutive_failures=0,
            method=settings_method(self.settings),
        )

    def prepare(self) -> None:
        pass

    def reset(self) -> None:
        pass


def settings_method(settings: PlannerSettings) -> str:
    return settings.method


class Clock:
    def __init__(self, t: float) -> None:
        self.t = t

    def __call__(self) -> float:
        return self.t


def _track(tid: int, x: float, vx: float = 2.0, **kw) -> OpponentTrack:
    fields = dict(id=tid, x_m=x, y_m=1.0, vx_mps=vx, vy_mps=0.0, yaw_rad=0.0, length_m=0.58,
                  width_m=0.31, cov_xx_m2=1e-4, cov_xy_m2=0.0, cov_yy_m2=1e-4,
                  speed_var_m2ps2=0.01, age_s=1.0, hits=10)
    fields.update(kw)
    return OpponentTrack(**fields)


def _state(stamp_s: float) -> State:
    return State(stamp_s=stamp_s, x_m=0.0, y_m=0.0, yaw_rad=0.0, speed_mps=1.0,
                 yaw_rate_radps=0.0, steering_rad=0.0, source_stamp_s=stamp_s, valid=True)


def _shell(method: str, car: str = "car1"):
    settings = PlannerSettings(method=method, command_yield_s=0.0)
    bus = FakeBus(car)
    wall = Clock(1000.0)
    mono = Clock(50.0)
    planner = StubPlanner(settings)
    shell = PlannerShell(planner, bus, clock=mono, wall_clock=wall)
    return shell, planner, bus, wall, mono


def _solve(shell: PlannerShell, bus: FakeBus, wall: Clock, mono: Clock) -> None:
    mono.t += 1.0
    shell.on_state(_state(wall.t))


def test_the_registry_says_which_methods_plan_with_opponents() -> None:
    assert plans_with_opponents(RACELINE) and not plans_with_opponents(CIMPCC)
    assert [n for n, s in METHODS.items() if s.opponents] == [RACELINE]


def test_a_method_without_opponents_does_not_subscribe() -> None:
    shell, planner, bus, wall, mono = _shell(CIMPCC)
    assert shell.opponent_sub is None and bus.keys.opponents not in bus.subs
    _solve(shell, bus, wall, mono)
    assert planner.given == [[]]  # never handed any


def test_the_planner_gets_the_newest_record_moved_to_now_before_each_solve() -> None:
    shell, planner, bus, wall, mono = _shell(RACELINE, car="car1")
    assert shell.opponent_sub is not None
    assert bus.keys.opponents == "racestack/car1/opponents"  # its own car's key
    assert bus.keys.opponents in bus.subs
    _solve(shell, bus, wall, mono)
    assert planner.given[-1] == []  # nothing seen yet: alone
    bus.deliver(bus.keys.opponents, Opponents(stamp_s=wall.t, source_stamp_s=wall.t - 0.2,
                                              tracks=[_track(1, 5.0)]))
    bus.deliver(bus.keys.opponents, Opponents(stamp_s=wall.t, source_stamp_s=wall.t - 0.05,
                                              tracks=[_track(1, 6.0), _track(2, 9.0, vx=0.0)]))
    _solve(shell, bus, wall, mono)
    got = planner.given[-1]
    assert [o.id for o in got] == [1, 2]
    assert got[0].x_m == pytest.approx(6.0 + 2.0 * 0.05)  # moved to now at its velocity
    assert got[1].x_m == pytest.approx(9.0) and got[0].y_m == pytest.approx(1.0)
    assert len(got[0].covariance) == 16 and got[0].covariance[0] > 1e-4
    assert bus.sent(bus.keys.drive_cmd, DriveCmd)[-1].speed_mps == 2.0
    # no newer record: the same tracks until they go stale, then none (counted once)
    wall.t += 0.1
    _solve(shell, bus, wall, mono)
    assert [o.id for o in planner.given[-1]] == [1, 2]
    wall.t += 0.2
    _solve(shell, bus, wall, mono)
    _solve(shell, bus, wall, mono)
    assert planner.given[-1] == [] and planner.given[-2] == []
    assert shell.opponent_counts.stale == 1 and shell.opponent_counts.records == 1


def test_stale_records_and_malformed_tracks_are_counted_and_dropped_never_a_crash() -> None:
    shell, planner, bus, wall, mono = _shell(RACELINE)
    bus.deliver(bus.keys.opponents, Opponents(stamp_s=wall.t, source_stamp_s=wall.t - 1.0,
                                              tracks=[_track(1, 5.0)]))
    _solve(shell, bus, wall, mono)
    assert planner.given[-1] == [] and shell.opponent_counts.stale == 1
    # a record the validation would refuse, as a shell might still see it in memory
    def like(tid: int) -> SimpleNamespace:
        base = _track(tid, 1.0)
        return SimpleNamespace(**{f: getattr(base, f) for f in OpponentTrack.__struct_fields__})

    bad = SimpleNamespace(seq=7, source_stamp_s=wall.t, tracks=[
        _track(3, 4.0),
        SimpleNamespace(**{**vars(like(4)), "x_m": float("nan")}),
        SimpleNamespace(id=5),  # fields missing
        SimpleNamespace(**{**vars(like(6)), "length_m": 0.0}),
    ])
    bus.deliver(bus.keys.opponents, bad)
    _solve(shell, bus, wall, mono)
    assert [o.id for o in planner.given[-1]] == [3]
    assert shell.opponent_counts.bad_tracks == 3
    bus.deliver(bus.keys.opponents, SimpleNamespace(seq=8, tracks=[]))  # no stamp at all
    _solve(shell, bus, wall, mono)
    assert planner.given[-1] == [] and shell.opponent_counts.stale == 2
    assert bus.sent(bus.keys.drive_cmd, DriveCmd)[-1].speed_mps == 2.0  # still driving


def test_a_planner_that_refuses_them_races_on() -> None:
    shell, planner, bus, wall, mono = _shell(RACELINE)

    def refuse(_):
        raise RuntimeError("no")

    planner.set_opponents = refuse
    bus.deliver(bus.keys.opponents, Opponents(stamp_s=wall.t, source_stamp_s=wall.t,
                                              tracks=[_track(1, 5.0)]))
    _solve(shell, bus, wall, mono)
    assert len(planner.given) == 1
    assert sum(bus.faults.snapshot().values()) == 1


def test_estimates_from_record_without_a_shell() -> None:
    counts = RecordCounts()
    rec = Opponents(stamp_s=10.0, source_stamp_s=10.0, tracks=[_track(1, 0.0, vx=-1.0)])
    (e,) = estimates_from_record(rec, 10.1, 0.25, counts)
    assert e.x_m == pytest.approx(-0.1) and e.vx_mps == -1.0 and e.length_m == 0.58
    assert estimates_from_record(rec, 9.9, 0.25, counts)[0].x_m == 0.0  # a clock behind
    assert estimates_from_record(rec, 10.3, 0.25, counts) == []
    assert (counts.records, counts.stale, counts.tracks) == (3, 1, 2)
