"""Fixtures of the bus and message tests: sample records, loopback Zenoh sessions, a watchdog."""

from __future__ import annotations

import faulthandler
import sys
from collections.abc import Callable, Iterator

import numpy as np
import pytest

from shared.messages import (
    DriveCmd,
    Imu,
    LapEvent,
    LogEvent,
    Message,
    Odom,
    Opponents,
    OpponentTrack,
    Plan,
    Pose,
    Scan,
    SimControl,
    SimTruth,
    State,
    Teleport,
    VescState,
)
from shared.net import free_loopback_port

#: Hard limit of one bus test [s]: past it the stacks are dumped and the run is ended,
#: so a hung Zenoh session can never hang the suite.
TEST_DEADLINE_S = 20.0


@pytest.fixture(autouse=True)
def _watchdog() -> Iterator[None]:
    """Kill the test process with a traceback dump if one test runs past the deadline."""
    faulthandler.dump_traceback_later(TEST_DEADLINE_S, exit=True, file=sys.stderr)
    try:
        yield
    finally:
        faulthandler.cancel_dump_traceback_later()


def _plan(n: int = 5) -> Plan:
    horizon = np.zeros((n + 1, 4))
    horizon[:, 0] = np.linspace(0.0, 1.0, n + 1)
    horizon[:, 3] = np.linspace(10.0, 11.0, n + 1)
    inputs = np.tile([3.0, 0.1, 3.0], (n, 1))
    return Plan(
        stamp_s=12.5,
        horizon=horizon,
        inputs=inputs,
        beta=np.linspace(0.2, 0.8, n),
        status="solved",
        solver_status="Solve_Succeeded",
        iterations=7,
        solve_time_ms=4.5,
        method="cimpcc",
        s_m=10.0,
        e_con_m=-0.05,
        source_stamp_s=12.45,
        consecutive_failures=0,
    )


#: One valid instance of every message type (with every optional field set where possible).
SAMPLE_FACTORIES: dict[type[Message], Callable[[], Message]] = {
    Pose: lambda: Pose(
        stamp_s=1.0, x_m=1.5, y_m=-2.0, yaw_rad=0.3, cov=np.diag([0.01, 0.02, 0.003])
    ),
    Imu: lambda: Imu(stamp_s=1.0, yaw_rate_radps=0.5, ax_mps2=1.2, ay_mps2=-0.4),
    Odom: lambda: Odom(stamp_s=1.0, speed_mps=3.1, steering_rad=-0.2, yaw_rate_radps=0.7),
    Scan: lambda: Scan(
        stamp_s=1.0,
        angle_min_rad=-2.35,
        angle_increment_rad=0.0043,
        ranges_m=np.array([1.0, 2.5, np.inf, 0.3], dtype=np.float32),
    ),
    State: lambda: State(
        stamp_s=2.0,
        x_m=1.0,
        y_m=2.0,
        yaw_rad=-3.0,
        speed_mps=2.2,
        yaw_rate_radps=0.1,
        steering_rad=0.05,
        source_stamp_s=1.99,
        valid=True,
    ),
    DriveCmd: lambda: DriveCmd(stamp_s=2.0, speed_mps=3.3, steering_rad=0.21),
    Plan: _plan,
    LapEvent: lambda: LapEvent(
        stamp_s=30.0,
        kind="lap",
        lap=1,
        lap_time_s=9.87,
        mean_speed_mps=3.4,
        off_track_events=0,
        max_abs_e_con_m=0.12,
    ),
    VescState: lambda: VescState(
        stamp_s=3.0,
        status="ok",
        temp_fet_c=35.0,
        temp_motor_c=40.0,
        avg_motor_current_a=3.2,
        avg_input_current_a=1.1,
        duty=0.2,
        erpm=12000.0,
        v_in_v=11.8,
        amp_hours=0.05,
        tachometer=-1234,
        tachometer_abs=5678,
        fault_code=0,
    ),
    SimTruth: lambda: SimTruth(
        stamp_s=4.0,
        x_m=1.0,
        y_m=1.0,
        yaw_rad=0.0,
        speed_mps=3.0,
        yaw_rate_radps=0.2,
        slip_rad=0.01,
        steering_rad=0.1,
        s_m=42.0,
        e_con_m=0.1,
        off_track=False,
        lap=2,
    ),
    LogEvent: lambda: LogEvent(stamp_s=5.0, level="warning", source="planner", text="slow solve"),
    SimControl: lambda: SimControl(stamp_s=6.0, action="reset"),
    Teleport: lambda: Teleport(stamp_s=7.0, x_m=-0.3, y_m=1.2, yaw_rad=0.1, speed_mps=0.5),
    Opponents: lambda: Opponents(
        stamp_s=8.0,
        source_stamp_s=7.95,
        tracks=[
            OpponentTrack(id=3, x_m=4.0, y_m=-1.5, vx_mps=2.5, vy_mps=0.3, yaw_rad=0.12,
                          length_m=0.58, width_m=0.31, cov_xx_m2=4e-4, cov_xy_m2=1e-5,
                          cov_yy_m2=3e-4, speed_var_m2ps2=0.02, age_s=1.25, hits=14)
        ],
    ),
}


@pytest.fixture
def sample() -> Callable[[type[Message]], Message]:
    """A function returning a fresh valid instance of a message class."""
    return lambda cls: SAMPLE_FACTORIES[cls]()


@pytest.fixture
def free_port() -> int:
    """A free TCP port on 127.0.0.1 (picked by binding port 0)."""
    return free_loopback_port()
