"""racestack sysid: the car identified from synthetic runs of the simulator's own car
(known parameters, sensor noise and delays), and the one-line errors of bad recordings."""

from __future__ import annotations

import json
import math
import tomllib
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest

from services.tools import sysid
from shared.config import load_config
from shared.config.vehicle import F1TENTH_GYM, REAL_CAR_IDENTIFIED, vehicle_preset
from shared.keys import DRIVE_CMD, ODOM
from shared.vehicle.identification import SysidError, identify

Drive = Callable[..., dict]
Write = Callable[..., Path]
Cap = pytest.CaptureFixture[str]
#: The simulator's defaults: actuation 10 ms, + 20 ms on the steering.
SPEED_DELAY_S, STEERING_DELAY_S = 0.01, 0.03


def _rel(est: float, true: float) -> float:
    return abs(est - true) / abs(true)


@pytest.fixture(scope="module")
def gym_run(sysid_drive: Drive) -> dict:
    return sysid_drive(F1TENTH_GYM, 60.0, seed=3)


def test_the_gym_car_with_saturated_linear_tyres(gym_run: dict) -> None:
    res = identify(gym_run, F1TENTH_GYM, "linear_saturated")
    e = res.estimates
    assert abs(e["steering_delay_s"].value - STEERING_DELAY_S) <= 0.01
    assert abs(e["speed_delay_s"].value - SPEED_DELAY_S) <= 0.015
    assert _rel(e["steering_rate_max_radps"].value, 3.2) < 0.05
    assert e["steering_time_constant_s"].value < 0.03  # the gym's servo: rate-limited
    assert _rel(e["speed_gain_accel_per_s"].value, 4.755) < 0.15
    assert _rel(e["speed_gain_brake_per_s"].value, 19.02) < 0.15
    assert _rel(e["accel_max_mps2"].value, 9.51) < 0.10
    assert _rel(e["cornering_stiffness_front_per_rad"].value, 4.718) < 0.10
    assert _rel(e["cornering_stiffness_rear_per_rad"].value, 5.4562) < 0.10
    assert _rel(e["mu"].value, 1.0489) < 0.05
    assert abs(e["steering_offset_rad"].value) < 0.005
    for name in ("mu", "cornering_stiffness_front_per_rad", "steering_delay_s"):
        assert e[name].identifiable and math.isfinite(e[name].sigma), name


def test_a_changed_car_and_a_base_that_is_wrong(gym_run: dict, sysid_drive: Drive) -> None:
    """Parameters 20-40 % off the base the fit starts from."""
    true = vehicle_preset("f1tenth_gym", mu=0.75, cornering_stiffness_front_per_rad=6.2,
                          cornering_stiffness_rear_per_rad=4.0, speed_gain_accel_per_s=3.5)
    run = sysid_drive(true, 60.0, seed=5, steer_amp_rad=0.25)
    e = identify(run, F1TENTH_GYM, "linear_saturated").estimates
    assert _rel(e["mu"].value, 0.75) < 0.05
    assert _rel(e["cornering_stiffness_front_per_rad"].value, 6.2) < 0.10
    assert _rel(e["cornering_stiffness_rear_per_rad"].value, 4.0) < 0.10
    assert _rel(e["speed_gain_accel_per_s"].value, 3.5) < 0.15


def test_the_identified_car_with_pacejka_tyres(sysid_drive: Drive) -> None:
    run = sysid_drive(REAL_CAR_IDENTIFIED, 60.0, seed=4, steer_amp_rad=0.2, speed_hi_mps=4.0)
    e = identify(run, F1TENTH_GYM.model_copy(update={"tyre_model": "pacejka"}),
                 "pacejka").estimates
    assert _rel(e["pacejka_front_D"].value, 0.650) < 0.05
    assert _rel(e["pacejka_rear_D"].value, 0.618) < 0.05
    assert _rel(e["steering_time_constant_s"].value, 0.158) < 0.10
    assert abs(e["steering_delay_s"].value - STEERING_DELAY_S) <= 0.01
    # a servo this slow never reaches its 3.2 rad/s: the run cannot tell the limit
    assert not e["steering_rate_max_radps"].identifiable
    assert "never reached" in e["steering_rate_max_radps"].note


def test_linear_tyres_fit_the_products(gym_run: dict) -> None:
    res = identify(gym_run, F1TENTH_GYM, "linear")
    overlay = res.vehicle_overlay(F1TENTH_GYM)
    assert overlay["tyre_model"] == "linear" and "mu" not in overlay
    k = res.estimates["mu_cornering_stiffness_front_per_rad"]
    assert np.isfinite(k.value) and k.value > 0


# --------------------------------------------------------------------------- the command
def test_the_command_writes_a_loadable_car(gym_run: dict, tmp_path: Path, capsys: Cap,
                                           sysid_write_run: Write) -> None:
    run = tmp_path / "run"
    sysid_write_run(run / "telemetry.0000.rrd", gym_run)
    out = tmp_path / "car.toml"
    code = sysid.main([str(run), "--out", str(out)])
    text = capsys.readouterr()
    assert code == 0, text.err
    cfg = load_config(out)
    assert cfg.vehicle.tyre_model == "linear_saturated"
    assert _rel(cfg.vehicle.mu, 1.0489) < 0.05
    raw = out.read_text(encoding="utf-8")
    assert "+-" in raw and raw.startswith("# racestack sysid")
    assert set(tomllib.loads(raw)) == {"vehicle"}
    doc = json.loads(out.with_suffix(".sysid.json").read_text(encoding="utf-8"))
    assert doc["estimates"]["steering_delay_s"]["identifiable"] is True
    # a rate limit the run does not tell: its bound in the JSON, and the car planned no
    # faster than that bound (nor than the base's 3.2 rad/s)
    rate = doc["estimates"]["steering_rate_max_radps"]
    if rate["identifiable"]:
        assert rate["lower_bound"] is None
    elif rate["lower_bound"] is None:  # told nothing, not even a bound: the base's
        assert cfg.vehicle.steering_rate_max_radps == 3.2
    else:
        assert cfg.vehicle.steering_rate_max_radps == pytest.approx(
            min(3.2, rate["lower_bound"]), rel=1e-3)
    pytest.importorskip("matplotlib")
    assert out.with_suffix(".png").stat().st_size > 10_000


def _one_line_error(code: int, err: str, *words: str) -> None:
    lines = [ln for ln in err.strip().splitlines() if "error" in ln]
    assert code == 2 and len(lines) == 1, err
    assert "Traceback" not in err
    for w in words:
        assert w in lines[0], lines[0]


def test_a_short_run_is_one_line(tmp_path: Path, capsys: Cap, sysid_drive: Drive,
                                 sysid_write_run: Write) -> None:
    sysid_write_run(tmp_path / "short" / "telemetry.0000.rrd", sysid_drive(F1TENTH_GYM, 8.0))
    code = sysid.main([str(tmp_path / "short"), "--out", str(tmp_path / "c.toml"),
                       "--no-figure"])
    _one_line_error(code, capsys.readouterr().err, "too short")
    assert not (tmp_path / "c.toml").exists()


def test_a_run_without_cornering_is_one_line(tmp_path: Path, capsys: Cap, sysid_drive: Drive,
                                             sysid_write_run: Write) -> None:
    sysid_write_run(tmp_path / "straight.rrd", sysid_drive(F1TENTH_GYM, 25.0, steer_amp_rad=0.0))
    code = sysid.main([str(tmp_path / "straight.rrd"), "--out", str(tmp_path / "c.toml"),
                       "--no-figure"])
    _one_line_error(code, capsys.readouterr().err, "no cornering")


def test_missing_keys_are_named(tmp_path: Path, capsys: Cap, sysid_drive: Drive,
                                sysid_write_run: Write) -> None:
    sysid_write_run(tmp_path / "noimu.rrd", sysid_drive(F1TENTH_GYM, 25.0), keys=(ODOM, DRIVE_CMD))
    code = sysid.main([str(tmp_path / "noimu.rrd"), "--out", str(tmp_path / "c.toml"),
                       "--no-figure"])
    _one_line_error(code, capsys.readouterr().err, "missing vehicle/imu", "imu/ay_mps2")


def test_a_killed_runs_open_segment(tmp_path: Path, capsys: Cap, sysid_drive: Drive,
                                    sysid_write_run: Write) -> None:
    """The last segment cut inside a message (SIGKILL): read up to there, said once; with
    too little left, the one line says so."""
    run = tmp_path / "killed"
    seg = sysid_write_run(run / "telemetry.0000.rrd", sysid_drive(F1TENTH_GYM, 32.0, seed=7))
    data = seg.read_bytes()
    seg.write_bytes(data[: int(0.8 * len(data))])  # no footer, cut mid-message
    code = sysid.main([str(run), "--out", str(tmp_path / "c.toml"), "--no-figure"])
    err = capsys.readouterr().err
    assert "Traceback" not in err
    assert "no footer" in err
    assert code == 0, err  # ~25 s of driving before the cut: enough
    short = tmp_path / "short-killed"
    seg = sysid_write_run(short / "telemetry.0000.rrd", sysid_drive(F1TENTH_GYM, 12.0))
    seg.write_bytes(seg.read_bytes()[:-200])
    code = sysid.main([str(short), "--out", str(tmp_path / "d.toml"), "--no-figure"])
    _one_line_error(code, capsys.readouterr().err)


def test_not_a_recording_is_one_line(tmp_path: Path, capsys: Cap) -> None:
    junk = tmp_path / "junk.rrd"
    junk.write_bytes(b"not a recording at all" * 10)
    code = sysid.main([str(junk), "--out", str(tmp_path / "c.toml"), "--no-figure"])
    _one_line_error(code, capsys.readouterr().err, "junk.rrd")
    code = sysid.main([str(tmp_path / "nothing"), "--out", str(tmp_path / "c.toml"),
                       "--no-figure"])
    _one_line_error(code, capsys.readouterr().err, "nothing")


def test_the_core_names_missing_signals(sysid_drive: Drive) -> None:
    with pytest.raises(SysidError, match="missing signals: ay_mps2"):
        identify({k: v for k, v in sysid_drive(F1TENTH_GYM, 1.0).items() if k != "ay_mps2"},
                 F1TENTH_GYM)
