"""One definition each: the status vocabularies, the car's geometry, the bridge's tuning."""

from __future__ import annotations

import inspect
import textwrap
from pathlib import Path

import pytest

from services.localization_bridge.fusion import StateAssembler
from services.simulator import LapTimer
from shared.car import CAR
from shared.config import load_config
from shared.config.localization import LocalizationSettings
from shared.config.telemetry import TelemetrySettings
from shared.config.vehicle import DynamicVehicleParams
from shared.config.vesc import VescSettings
from shared.messages import LapEvent, LapKindName, LogEvent, LogLevelName, decode
from shared.messages.vocab import VOCABULARIES


@pytest.mark.parametrize(("enum", "values"), VOCABULARIES, ids=lambda v: getattr(v, "__name__", ""))
def test_each_status_enum_is_its_literal(enum: type, values: tuple[str, ...]) -> None:
    assert tuple(m.value for m in enum) == values
    assert all(m == m.value for m in enum)  # a member is its wire string


def test_records_take_enum_members_and_send_the_plain_strings() -> None:
    a = LapEvent(stamp_s=1.0, kind=LapKindName.START, lap=0, off_track_events=0)
    b = LapEvent(stamp_s=1.0, kind="start", lap=0, off_track_events=0)
    assert a.encode() == b.encode() and type(a.kind) is str
    log = decode(LogEvent(stamp_s=1.0, level=LogLevelName.WARNING, source="t", text="x").encode(),
                 LogEvent)
    assert log.level == LogLevelName.WARNING == "warning"


def test_the_car_geometry_is_every_setting_s_default() -> None:
    assert (CAR.length_m, CAR.width_m, CAR.wheelbase_m) == (0.58, 0.31, 0.324)
    veh = DynamicVehicleParams()
    assert (veh.length_m, veh.width_m) == (CAR.length_m, CAR.width_m)
    tele = TelemetrySettings()
    assert (tele.car_length_m, tele.car_width_m) == (CAR.length_m, CAR.width_m)
    assert VescSettings().wheelbase_m == CAR.wheelbase_m
    assert load_config(None).planner.wheelbase_m == CAR.wheelbase_m
    footprint = inspect.signature(LapTimer).parameters
    assert footprint["length_m"].default == CAR.length_m
    assert footprint["width_m"].default == CAR.width_m


def test_localization_section_defaults_are_the_bridge_s_and_load_from_toml(
    tmp_path: Path,
) -> None:
    core = StateAssembler()
    defaults = load_config(None).localization
    assert (core.max_input_age_s, core.max_prediction_s) == (0.25, 0.1)
    assert (defaults.max_input_age_s, defaults.max_prediction_s) == (0.25, 0.1)
    assert (defaults.pose_queue, defaults.check_period_s) == (4, 0.2)
    toml = tmp_path / "c.toml"
    toml.write_text(textwrap.dedent("""
        [localization]
        max_input_age_s = 0.5
        max_prediction_s = 0.0
    """), encoding="utf-8")
    tuned = StateAssembler.from_settings(load_config(toml).localization)
    assert (tuned.max_input_age_s, tuned.max_prediction_s) == (0.5, 0.0)
    with pytest.raises(ValueError):
        LocalizationSettings(max_prediction_s=-1.0)
