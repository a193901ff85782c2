"""The identification drive (``racestack sysid --drive``): its envelope on crafted responses,
its speed profile, and its phases on a short in-process run in the simulator."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from services.tools.sysid import main as sysid_main
from services.tools.sysid_drive import drive_main, run_drive, write_recording
from shared.config import config_from_dict
from shared.config.vehicle import vehicle_preset
from shared.track import load_track
from shared.vehicle.sysid_drive import (
    PHASES,
    DriveSettings,
    Envelope,
    envelope_lost_line,
    envelope_raise,
    envelope_update,
    speed_profile,
)

L = 0.33  # wheelbase [m]
K = 0.01  # the crafted car's understeer gradient [rad/(m/s^2)]


def corner(env: Envelope, st: DriveSettings, response: object, ay_peak: float,
           v: float = 3.0) -> Envelope:
    """One crafted bend: a_y rising to `ay_peak` and back over 2 s at 100 Hz, the
    steering `response(ay)` the car needs for it; then the envelope raised."""
    for ay in ay_peak * np.sin(np.linspace(0.0, math.pi, 200)):
        r = ay / v  # the yaw rate of a steady turn at a_y
        env = envelope_update(env, L, v, response(ay), r, ay, 0.01, st)  # type: ignore[operator]
    return envelope_raise(env, st)


def drive_bends(st: DriveSettings, response: object, grip: float, bends: int = 60
                ) -> tuple[Envelope, list[float]]:
    """Bends at the envelope's target (the car gives at most `grip`); the targets."""
    env = Envelope(st.ay_first_mps2)
    targets = []
    for _ in range(bends):
        targets.append(env.ay_target_mps2)
        env = corner(env, st, response, min(env.ay_target_mps2, grip))
    return env, targets


def linear(ay: float) -> float:
    """The steering of a linear car at a_y [rad], at 3 m/s (``L kappa + K a_y``)."""
    return L * ay / 9.0 + K * ay


def saturating(ay: float) -> float:
    """Linear up to 4.5 m/s^2, then ever more steering (the front tyres saturating)."""
    return linear(ay) + 0.08 * max(abs(ay) - 4.5, 0.0) ** 1.5 * math.copysign(1.0, ay)


def test_envelope_keeps_rising_on_a_linear_car() -> None:
    st = DriveSettings()
    env, targets = drive_bends(st, linear, grip=20.0, bends=30)
    assert not env.saturated
    assert env.understeer_rad_per_mps2 == pytest.approx(K, rel=0.02)
    assert np.all(np.diff(targets) == pytest.approx(st.ay_step_mps2))
    assert env.ay_target_mps2 == pytest.approx(st.ay_first_mps2 + 30 * st.ay_step_mps2)


def oversteering(ay: float) -> float:
    """Linear up to 4.5 m/s^2, then ever less steering (the rear tyres saturating)."""
    return linear(ay) - 0.08 * max(abs(ay) - 4.5, 0.0) ** 1.5 * math.copysign(1.0, ay)


def test_envelope_stops_rising_at_saturation() -> None:
    st = DriveSettings(front_departure=True)
    env, targets = drive_bends(st, saturating, grip=20.0)
    assert env.saturated and env.reason == "steering response"
    # the departure passes saturation_rad (0.05 rad) a little above 4.5 m/s^2
    assert 4.5 < env.ay_saturation_mps2 < 6.0
    assert env.ay_target_mps2 == pytest.approx(st.margin * env.ay_saturation_mps2)
    stop = int(np.argmax(np.diff(targets) <= 0)) + 1
    assert max(targets) < 6.5 and np.all(np.diff(targets[stop:]) <= 0)
    assert envelope_raise(env, st) == env  # it no longer rises


def test_envelope_stops_rising_at_the_rears_saturation() -> None:
    st = DriveSettings()  # by default only the rear's departure (oversteer) counts
    env, targets = drive_bends(st, oversteering, grip=20.0)
    assert env.saturated and env.reason == "steering response"
    assert 4.5 < env.ay_saturation_mps2 < 6.0
    assert env.ay_target_mps2 == pytest.approx(st.margin * env.ay_saturation_mps2)
    assert max(targets) < 6.5
    assert envelope_raise(env, st) == env


def test_envelope_goes_on_past_the_fronts_softness_but_not_past_what_it_sees() -> None:
    st = DriveSettings()  # the front's extra steering (understeer) is not a stop...
    env, targets = drive_bends(st, saturating, grip=20.0, bends=30)
    assert not env.saturated
    # ...and a car that gives at most 5 m/s^2 (its grip or its lock) is not asked for
    # more: a target the lead above it is saturation, then short of what it gave
    env, targets = drive_bends(st, linear, grip=5.0, bends=40)
    assert env.saturated and env.reason == "target not reached"
    assert max(targets) <= 5.0 + st.ay_lead_mps2 + st.ay_step_mps2 + 1e-9
    assert env.ay_saturation_mps2 == pytest.approx(5.0, abs=0.01)
    assert env.ay_target_mps2 == pytest.approx(st.margin * 5.0, abs=0.01)
    assert envelope_raise(env, st) == env


def test_envelope_stops_when_the_line_is_lost() -> None:
    st = DriveSettings()
    env = corner(Envelope(4.0), st, linear, 4.0)
    lost = envelope_lost_line(env, st)
    assert lost.saturated and lost.reason == "lost the line"
    assert lost.ay_target_mps2 == pytest.approx(st.margin * env.ay_seen_mps2)


def test_speed_profile_caps_the_bends_and_brakes_before_them() -> None:
    kappa = np.zeros(400)
    kappa[200:240] = 1.0  # a 1 m-radius bend on a 40 m loop of 0.1 m steps
    v = speed_profile(kappa, 0.1, 4.0, 5.0, 2.0)
    assert np.all(v[200:240] == pytest.approx(2.0))  # sqrt(4 / 1)
    assert v[100] == pytest.approx(5.0)
    # braking at 2 m/s^2 into the bend: v^2 = 4 + 2 * 2 * distance
    assert v[190] == pytest.approx(math.sqrt(4.0 + 4.0 * 1.0))
    # it never asks for more braking than that (the rise out of a bend is the command's
    # ramp, not the profile's)
    assert np.all(np.diff(v ** 2) >= -2 * 2.0 * 0.1 - 1e-9)
    assert v[240] == pytest.approx(5.0)


@pytest.fixture(scope="module")
def short_drive() -> tuple[dict, object]:
    """A 42 s drive of the identified car (a Pacejka car) on paperlike, the cornering
    phase started at 4 m/s^2 so that it meets the tyres' limit (~6.4 m/s^2)."""
    car = vehicle_preset("real_car_identified")
    cfg = config_from_dict({"vehicle": {"preset": car.preset}})
    st = DriveSettings(speed_steps_s=8.0, steering_steps_s=6.0, cornering_s=28.0,
                       ay_first_mps2=4.0, ay_step_mps2=0.4)
    return run_drive(load_track("builtin:paperlike"), cfg.simulator, cfg.planner.dt_s, st)


def test_the_drive_runs_its_phases_on_the_track(short_drive: tuple) -> None:
    signals, summ = short_drive
    phases = [row[1] for row in summ.trace]
    firsts = [phases.index(p) for p in PHASES[:3]]
    assert firsts == sorted(firsts) and firsts[0] == 0  # in order, each present
    assert summ.off_track == 0 and summ.max_abs_e_m < 0.45
    speeds = np.array([row[2] for row in summ.trace if row[1] == "speed_steps"])
    assert len(np.unique(np.round(speeds, 3))) > 3  # stepped
    assert summ.sim_s == pytest.approx(42.0, abs=0.2)
    assert all(len(signals[k][0]) > 100 for k in signals)


def test_the_cornering_targets_rise_and_stop_at_the_envelope(short_drive: tuple) -> None:
    _, summ = short_drive
    targets = np.array([row[3] for row in summ.trace if row[1] == "cornering"])
    assert summ.saturated, "the short drive should reach the tyres' limit"
    peak = int(np.argmax(targets))
    assert targets[peak] > targets[0]  # rose
    assert np.all(np.diff(targets[:peak + 1]) >= 0)
    assert np.all(np.diff(targets[peak:]) <= 0)  # and stopped
    assert targets[-1] <= summ.ay_saturation_mps2
    assert summ.ay_seen_mps2 < 6.4 * 1.05  # short of the front tyres' peak (mu g D)


def test_the_drive_recording_is_what_sysid_reads(short_drive: tuple, tmp_path: Path) -> None:
    signals, _ = short_drive
    run = tmp_path / "drive"
    write_recording(run / "telemetry.0000.rrd", signals)
    out = tmp_path / "car.toml"
    assert sysid_main([str(run), "--out", str(out), "--no-figure"]) == 0
    assert out.exists()


def test_drive_and_fit_arguments(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert sysid_main(["--out", str(tmp_path / "x.toml")]) == 2
    assert "give a RECORDING" in capsys.readouterr().err
    assert drive_main(str(tmp_path / "run"), "no-such-track", None) == 2
    assert "error" in capsys.readouterr().err
