"""A slower car in ``racestack up`` (``[[cars]] pace``, issue #24): its planner races that
share of its line's speeds (``[planner.raceline] speed_share``), the per-car configuration
says so, and a pace for a method that races no planned line is one clear error."""

from __future__ import annotations

import tomllib
from pathlib import Path

import pytest

from services.tools.launcher.multicar import car_label, write_car_configs
from shared.config import ConfigError, config_from_dict


def _two(pace: float, method: str = "raceline") -> dict:
    return {"planner": {"method": "cimpcc"},
            "cars": [{"name": "car0", "method": method, "pace": pace},
                     {"name": "car1", "method": "raceline", "start_gap_m": 3.0}]}


def test_a_pace_goes_into_that_cars_planner_configuration(tmp_path: Path) -> None:
    data = _two(0.85)
    cfg = config_from_dict(data)
    _base, per_car = write_car_configs(data, cfg, tmp_path)
    own = tomllib.loads(per_car["car0"].read_text(encoding="utf-8"))
    other = tomllib.loads(per_car["car1"].read_text(encoding="utf-8"))
    assert own["planner"]["method"] == "raceline"
    assert own["planner"]["raceline"]["speed_share"] == 0.85
    assert "raceline" not in other["planner"]  # the other car races its line's own speeds
    assert config_from_dict(own).planner.raceline.speed_share == 0.85
    assert car_label(cfg.cars[0], "raceline") == "car0 (raceline pace 0.85)"
    assert car_label(cfg.cars[1], "raceline") == "car1 (raceline)"


def test_a_pace_needs_a_method_that_races_a_planned_line() -> None:
    with pytest.raises(ConfigError, match=r"pace 0\.85 needs a method that races a planned line"):
        config_from_dict(_two(0.85, method="cimpcc"))
    bad = {"planner": {"method": "mpcc"}, "cars": [{"name": "car0", "pace": 0.9}]}
    with pytest.raises(ConfigError, match="not mpcc"):
        config_from_dict(bad)
    with pytest.raises(ConfigError):
        config_from_dict(_two(1.2))
