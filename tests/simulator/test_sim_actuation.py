"""Actuation of the simulated car: delays, NaN commands, the command timeout, step sizes."""

from __future__ import annotations

import math
import subprocess
import sys
from pathlib import Path

import pytest

from services.simulator.actuators import CommandDelayLine, speed_control, steering_control
from services.simulator.state import Command, Pose2D
from services.simulator.vehicle import Simulator
from shared.config.simulator import SimulatorSettings


def test_p_controllers() -> None:
    assert speed_control(3.0, 1.0, 4.0, 20.0) == 8.0  # speeding up
    assert speed_control(1.0, 3.0, 4.0, 20.0) == -40.0  # braking
    assert speed_control(-2.0, 0.0, 4.0, 20.0) == -8.0  # reversing away from standstill
    assert speed_control(0.0, -2.0, 4.0, 20.0) == 40.0  # braking from reverse
    assert steering_control(0.2, 0.1, 0.01) == pytest.approx(10.0)


def test_delay_line_orders_channels_and_clips() -> None:
    line = CommandDelayLine(0.01, 0.03, 0.1, (-5.0, 20.0), (-0.4, 0.4))
    line.clear(hold_steering_rad=0.05)
    line.push(2.0, 1.0, 0.0)  # steering clipped to 0.4
    assert line.targets(0.0) == (0.0, 0.05, True)  # nothing acts yet
    assert line.targets(0.01) == (2.0, 0.05, False)  # speed after 10 ms
    assert line.targets(0.03) == (2.0, 0.4, False)  # steering after 30 ms
    line.push(3.0, 0.1, 0.02)
    assert line.targets(0.04) == (3.0, 0.4, False)
    assert line.targets(0.05) == (3.0, 0.1, False)
    with pytest.raises(ValueError, match="backwards"):
        line.push(1.0, 0.0, 0.01)


@pytest.mark.parametrize(
    "bad", [(math.nan, 0.1), (2.0, math.nan), (math.inf, 0.0), (1.0, -math.inf), (None, 0.0)]
)
def test_non_finite_command_brakes_and_never_reaches_the_state(bad: tuple) -> None:
    sim = Simulator()
    sim.reset(Pose2D(0.0, 0.0, 0.0), speed_mps=3.0)
    for _ in range(20):
        sim.step(Command(3.0, 0.1), 0.01)
    for _ in range(200):
        res = sim.step(bad, 0.01)  # type: ignore[arg-type]
        assert all(math.isfinite(v) for v in res.state.as_tuple())
        assert math.isfinite(res.accel_long_mps2) and math.isfinite(res.accel_lat_mps2)
    assert res.speed_target_mps == 0.0
    assert res.steering_target_rad == pytest.approx(0.1)  # servo holds the last valid value
    assert abs(res.state.v_mps) < 0.01
    assert sim.rejected_commands == 200
    assert sim.set_command(math.nan, 0.0, sim.t_s) is False


def test_commands_stopped_brakes_after_the_timeout() -> None:
    s = SimulatorSettings()
    sim = Simulator(s)
    sim.reset(Pose2D(0.0, 0.0, 0.0), speed_mps=3.0)
    for _ in range(50):
        sim.step(Command(3.0, 0.0), 0.01)
    t_last = sim.t_s - 0.01  # the last command was received at the start of the last step
    results = [sim.step(None, 0.01) for _ in range(100)]
    for r in results:
        age = r.t_s - 0.01 - s.actuation_delay_s - t_last  # age at the last sub-step
        if age < s.command_timeout_s - 1e-6:
            assert not r.command_timed_out and r.speed_target_mps == 3.0
        elif age > s.command_timeout_s + 1e-6:
            assert r.command_timed_out and r.speed_target_mps == 0.0
    assert results[-1].state.v_mps < 0.1
    # a fresh command ends the timeout
    sim.set_command(2.0, 0.0, sim.t_s)
    r = [sim.step(None, 0.01) for _ in range(2)][-1]
    assert not r.command_timed_out and r.speed_target_mps == 2.0


def test_set_command_and_step_none_equals_step_with_command() -> None:
    a, b = Simulator(), Simulator()
    for sim in (a, b):
        sim.reset(Pose2D(1.0, 2.0, 0.5), speed_mps=1.0)
    for k in range(100):
        cmd = Command(2.0 + 0.01 * k, 0.2 * math.sin(0.05 * k))
        ra = a.step(cmd, 0.01)
        b.set_command(cmd.speed_mps, cmd.steering_rad, b.t_s)
        rb = b.step(None, 0.01)
    assert ra == rb


def test_step_sizes() -> None:
    sim = Simulator()
    sim.reset(Pose2D(0.0, 0.0, 0.0), speed_mps=2.0, t_s=5.0)
    r = sim.step(Command(2.0, 0.0), 0.025)
    assert r.t_s == pytest.approx(5.025) and r.substeps == 3
    r = sim.step(Command(2.0, 0.0), 0.004)
    assert r.t_s == pytest.approx(5.029) and r.substeps == 1
    for bad in (0.0, -0.01, math.nan, math.inf):
        with pytest.raises(ValueError):
            sim.step(Command(2.0, 0.0), bad)
    with pytest.raises(ValueError):
        sim.reset(Pose2D(math.nan, 0.0, 0.0))


def test_simulator_does_not_import_the_vesc_driver_service() -> None:
    """The fake-VESC actuation uses ``shared.vesc`` only: no service imports another."""
    code = (
        "import sys\n"
        "import services.simulator.service, services.simulator.vesc_actuation\n"
        "bad = sorted(m for m in sys.modules if m.startswith('services.vesc_driver'))\n"
        "print(','.join(bad))\n"
    )
    root = Path(__file__).resolve().parents[2]
    out = subprocess.run(
        [sys.executable, "-c", code], cwd=root, capture_output=True, text=True, timeout=60
    )
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == ""
