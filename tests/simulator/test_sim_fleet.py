"""Several cars in one simulator (issue #24), on the in-process bus: each car on its own keys
with its own commands, the second started its gap behind; a car driven into a stopped one
makes one incident (counted once, said on events/log, who hit whom), the cars never stay
inside each other and the striker loses its speed; each lidar sees the other car; one car
stays exactly the service it was."""

from __future__ import annotations

import math

import numpy as np
import pytest

from services.simulator.fleet import CarView
from services.simulator.service import START_OFFSET_M, SimulatorService
from shared.bus.fake import FakeBus
from shared.config import config_from_dict
from shared.messages import DriveCmd, LogEvent, Scan, SimTruth
from shared.track import load_track, occupancy_for
from shared.vehicle.contact import box_contact
from shared.vehicle.incidents import IncidentRecord, incident_line, parse_incident

H = 0.01


#: a straight of paperlike: from s = 1 m to 12 m
STRAIGHT_S_M = 5.0


@pytest.fixture(scope="module")
def track():
    return load_track("builtin:paperlike")


@pytest.fixture(scope="module")
def grid(track):
    return occupancy_for(track)


@pytest.fixture
def fleet(track, grid):
    def make(gap: float = 1.0, scale: float = 1.0, lead_s: float | None = None):
        lead = {} if lead_s is None else {"start_s_m": lead_s}
        cfg = config_from_dict({
            "cars": [{"name": "car0", **lead},
                     {"name": "car1", "speed_scale": scale, "start_gap_m": gap}],
        })
        bus = FakeBus()
        return SimulatorService.fleet(cfg, bus, track, wall_clock=lambda: 1000.0,
                                      grid=grid), bus
    return make


def _run(svc, steps: int, cmds: dict[str, tuple[float, float]]) -> None:
    cars = (svc, *svc.others)
    for _ in range(steps):
        for c in cars:
            if c.keys.car in cmds:
                v, d = cmds[c.keys.car]
                c.commands.put(DriveCmd(stamp_s=1.0, speed_mps=v, steering_rad=d))
            c.handle_inputs()
        results = svc.step_fleet(H)
        for c, r in zip(cars, results, strict=True):
            if r is not None:
                c.publish(r)


def test_two_cars_start_a_gap_apart_on_their_own_keys(track, fleet) -> None:
    svc, bus = fleet(gap=1.5)
    assert [c.keys.car for c in (svc, *svc.others)] == ["car0", "car1"]
    car1 = svc.others[0]
    s0 = svc.timer.s_m
    s1 = car1.timer.s_m
    assert s0 == pytest.approx(START_OFFSET_M, abs=0.01)
    assert (s0 - s1) % track.length_m == pytest.approx(1.5, abs=0.02)
    _run(svc, 100, {"car0": (2.0, 0.0), "car1": (1.0, 0.0)})
    t0 = bus.sent("racestack/car0/sim/truth", SimTruth)
    t1 = bus.sent("racestack/car1/sim/truth", SimTruth)
    assert t0 and t1
    assert t0[-1].speed_mps > t1[-1].speed_mps > 0.3  # each its own command
    assert bus.sent("racestack/car1/vehicle/scan", Scan)


def test_speed_scale_scales_the_commands(fleet) -> None:
    svc, _ = fleet(gap=3.0, scale=0.5, lead_s=STRAIGHT_S_M + 3.0)
    _run(svc, 300, {"car0": (2.0, 0.0), "car1": (2.0, 0.0)})
    v0, v1 = svc.sim.state.v_mps, svc.others[0].sim.state.v_mps
    assert v1 == pytest.approx(0.5 * v0, rel=0.05)


def test_a_car_driven_into_a_stopped_one_is_one_incident_and_never_a_free_pass(fleet) -> None:
    svc, bus = fleet(gap=1.2, lead_s=STRAIGHT_S_M)
    car1 = svc.others[0]
    peak = 0.0
    for _ in range(150):  # car1 drives into car0, which stands
        _run(svc, 1, {"car0": (0.0, 0.0), "car1": (3.0, 0.0)})
        a, b = svc.sim.state, car1.sim.state
        con = box_contact(np.array([a.x_m, a.y_m, a.yaw_rad]), np.array([b.x_m, b.y_m, b.yaw_rad]))
        peak = max(peak, float(con.depth_m[0]))
    assert peak <= 0.0  # after every step's response: never inside each other
    assert len(svc.contacts.incidents) >= 1
    assert svc.impacts >= 1
    lines = [m.text for m in bus.sent("racestack/car0/events/log", LogEvent)
             if m.text.startswith("contact ")]
    first = parse_incident(lines[0])
    assert first is not None and first.number == 1
    assert (first.striker, first.struck) == ("car1", "car0")
    assert first.closing_mps > 1.0
    assert len(lines) == len(svc.contacts.incidents)
    # the struck car was pushed forwards along the track, the striker is slowed by it
    assert svc.timer.s_m > STRAIGHT_S_M + 0.05
    assert car1.sim.state.v_mps < 2.0


def test_each_lidar_sees_the_other_car(fleet) -> None:
    svc, bus = fleet(gap=1.5, lead_s=STRAIGHT_S_M)
    _run(svc, 60, {"car0": (0.0, 0.0), "car1": (0.0, 0.0)})
    scans = bus.sent("racestack/car1/vehicle/scan", Scan)
    r = np.asarray(scans[-1].ranges_m)
    ahead = r[len(r) // 2 - 5: len(r) // 2 + 6]
    # car0's tail is about 1.5 - 0.58 / 2 m ahead of car1's CoG-mounted lidar
    assert float(np.median(ahead)) == pytest.approx(1.5 - 0.29, abs=0.08)


def test_one_car_has_no_fleet(track, grid) -> None:
    cfg = config_from_dict({})
    svc = SimulatorService(cfg, FakeBus(), track, grid=grid)
    assert svc.others == [] and svc.contacts is None and svc.speed_scale == 1.0
    assert svc.sensors.lidar is None or svc.sensors.lidar.boxes is None


def test_bus_car_must_be_in_the_list(track) -> None:
    cfg = config_from_dict({"cars": [{"name": "a"}, {"name": "b"}]})
    with pytest.raises(ValueError, match="not in"):
        SimulatorService.fleet(cfg, FakeBus(), track)


def test_incident_lines_round_trip() -> None:
    rec = IncidentRecord(3, "car1", "car0", 12.345, 0.021, 1.52)
    assert parse_incident(incident_line(rec)) == rec
    tie = IncidentRecord(4, "none", "car0+car1", 1.0, 0.01, 0.0)
    assert parse_incident(incident_line(tie)) == tie
    assert parse_incident("lap 1: 3.2 s") is None


def test_a_car_view_has_the_other_cars_keys() -> None:
    bus = FakeBus()
    v = CarView(bus, "car7")
    assert v.keys.drive_cmd == "racestack/car7/cmd/drive" and v.faults is bus.faults
    assert math.isfinite(1.0)
