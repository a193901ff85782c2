"""Fixtures of the sysid tests: synthetic runs: the simulator's car driven open loop in-process
(speed steps, steering sweeps), recorded by its own odometry and IMU with noise, and
written as a telemetry recording."""

from __future__ import annotations

import math
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest

from services.simulator import ImuSensor, OdometrySensor, Simulator
from services.tools.sysid_drive import write_recording
from shared.config.simulator import SimulatorSettings
from shared.config.vehicle import DynamicVehicleParams

#: Command period [s] (the planner's 20 Hz).
CMD_DT_S = 0.05


def drive(vehicle: DynamicVehicleParams, duration_s: float = 60.0, seed: int = 0,
          steer_amp_rad: float = 0.3, speed_hi_mps: float = 4.5, speed_lo_mps: float = 1.8,
          **sim: float) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """The signals ``identify`` reads, from `duration_s` of open-loop driving: speed
    stepping between 1.8 m/s and `speed_hi_mps`, steering a sum of sines up to
    `steer_amp_rad` with steps."""
    settings = SimulatorSettings(vehicle=vehicle, **sim)
    s = Simulator(settings)
    s.reset((0.0, 0.0, 0.0), speed_mps=2.0)
    rng = np.random.default_rng(seed)
    imu = ImuSensor(settings.imu, np.random.default_rng(seed + 1))
    odo = OdometrySensor(settings.odometry, np.random.default_rng(seed + 2))
    out: dict[str, list[tuple[float, float]]] = {k: [] for k in (
        "cmd_speed_mps", "cmd_steering_rad", "speed_mps", "steering_rad", "yaw_rate_radps",
        "ax_mps2", "ay_mps2")}
    speed = 2.5
    phases = rng.uniform(0, 2 * math.pi, 3)
    n = int(duration_s / CMD_DT_S)
    for k in range(n):
        t = k * CMD_DT_S
        if k % 40 == 0:
            speed = float(rng.uniform(speed_lo_mps, speed_hi_mps))
        amp = steer_amp_rad * (0.35 + 0.65 * abs(math.sin(0.05 * t)))
        steer = amp * (0.6 * math.sin(1.3 * t + phases[0]) + 0.3 * math.sin(3.1 * t
                       + phases[1]) + 0.25 * np.sign(math.sin(0.7 * t + phases[2])))
        steer = float(np.clip(steer, -0.41, 0.41))
        out["cmd_speed_mps"].append((s.t_s, speed))
        out["cmd_steering_rad"].append((s.t_s, steer))
        for i in range(5):
            res = s.step((speed, steer) if i == 0 else None, CMD_DT_S / 5)
            for m in imu.update(res):
                out["yaw_rate_radps"].append((m.stamp_s, m.yaw_rate_radps))
                out["ax_mps2"].append((m.stamp_s, m.accel_long_mps2))
                out["ay_mps2"].append((m.stamp_s, m.accel_lat_mps2))
            for m in odo.update(res):
                out["speed_mps"].append((m.stamp_s, m.speed_mps))
                out["steering_rad"].append((m.stamp_s, m.steering_rad))
    return {k: (np.array([a for a, _ in v]), np.array([b for _, b in v]))
            for k, v in out.items()}


@pytest.fixture(scope="session")
def sysid_drive() -> Callable[..., dict[str, tuple[np.ndarray, np.ndarray]]]:
    """``drive``: a synthetic run of the simulator's car."""
    return drive


@pytest.fixture(scope="session")
def sysid_write_run() -> Callable[..., Path]:
    """``write_recording``: a synthetic run as a telemetry segment (as the telemetry
    service records it: the messages through the ``Recorder``)."""
    return write_recording
