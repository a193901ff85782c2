"""Simulator + lap timer in a loop with a pure-pursuit driver: the simulation caveat.

With the gym's linear tyres a car can take the paper-like track's 0.8-1 m turns at 4 m/s
(16-20 m/s^2); with the friction limit it cannot and slides off. At 2 m/s both stay on.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from services.simulator.laps import LapTimer, centreline_pose
from services.simulator.state import Command
from services.simulator.vehicle import Simulator
from shared.config.simulator import SimulatorSettings
from shared.config.vehicle import DynamicVehicleParams
from shared.track import load_track


def _one_lap(track_name: str, tyre_model: str, speed: float):
    track = load_track(track_name)
    settings = SimulatorSettings(vehicle=DynamicVehicleParams(tyre_model=tyre_model))
    sim = Simulator(settings)
    s_hint = track.length_m - 0.5
    sim.reset(centreline_pose(track, s_hint), speed_mps=speed)
    timer = LapTimer(track, settings.vehicle.width_m, settings.vehicle.length_m)
    lookahead, wb = 0.8, settings.vehicle.wheelbase_m
    events = []
    for _ in range(round(1.15 * track.length_m / speed / 0.01)):
        st = sim.state
        s, _ = track.project(np.array([st.x_m, st.y_m]), s_hint=s_hint)
        s_hint = float(s)
        tx, ty = track.point_at(s_hint + lookahead)
        alpha = math.atan2(ty - st.y_m, tx - st.x_m) - st.yaw_rad
        steer = math.atan2(2.0 * wb * math.sin(alpha), lookahead)
        res = sim.step(Command(speed, steer), 0.01)
        st = res.state
        events += timer.update(res.t_s, st.x_m, st.y_m, st.yaw_rad, st.v_mps)
    return events


@pytest.mark.parametrize("tyre_model", ["linear", "linear_saturated"])
def test_slow_lap_is_clean_for_both_tyre_models(tyre_model: str) -> None:
    events = _one_lap("paperlike", tyre_model, 2.0)
    assert [e.kind for e in events] == ["start", "lap"]
    assert events[1].max_abs_e_con_m < 0.3
    assert events[1].mean_speed_mps == pytest.approx(2.0, abs=0.1)


def test_fast_lap_needs_grip_the_friction_limit_does_not_give() -> None:
    ideal = _one_lap("paperlike", "linear", 4.0)
    assert [e.kind for e in ideal] == ["start", "lap"]
    assert ideal[1].off_track_events == 0
    real = _one_lap("paperlike", "linear_saturated", 4.0)
    assert any(e.kind == "off_track" for e in real)
