"""config/car.toml, the commented real-car example, loads with the real configuration model
(an unknown or misspelt key, or a value out of range, fails here)."""

from __future__ import annotations

import re
import tomllib
from pathlib import Path

from shared.config import config_from_dict, load_config

CAR_TOML = Path(__file__).resolve().parents[2] / "config" / "car.toml"


def test_the_car_example_loads_and_says_what_the_car_uses() -> None:
    cfg = load_config(CAR_TOML)
    assert cfg.vesc.port == "/dev/sensors/vesc" and cfg.vesc.poll_imu_rate_hz > 0
    assert cfg.lidar_driver.port == "/dev/sensors/hokuyo"
    assert cfg.localization.pose_source == "lidar"
    assert cfg.bus.security == "mtls" and cfg.bus.certs_dir == "certs"
    assert cfg.planner.method == "cimpcc"
    assert cfg.track.source.endswith(".yaml")  # the team's map, extracted at start-up


def test_the_commented_alternatives_are_valid_too() -> None:
    """Each ``# key = value`` line of the file, uncommented in its section, still loads."""
    text = CAR_TOML.read_text(encoding="utf-8")
    base = tomllib.loads(text)
    section = None
    tried = 0
    for line in text.splitlines():
        header = re.fullmatch(r"#?\s*\[([\w.]+)\]\s*", line.split("  #")[0].strip())
        if header and not line.lstrip("# ").startswith("[simulator]"):
            section = header.group(1)
            continue
        m = re.fullmatch(r"#\s*(\w+)\s*=\s*(\"[^\"]*\"|\[[^\]]*\]|[-\w.]+)\s*(#.*)?", line)
        if not (m and section) or m.group(2) == "...":
            continue
        data = tomllib.loads(text)
        node = data
        for part in section.split("."):
            node = node.setdefault(part, {})
        node[m.group(1)] = tomllib.loads(f"v = {m.group(2)}")["v"]
        config_from_dict(data, f"{CAR_TOML} with {line.strip()}")
        tried += 1
    assert tried >= 2 and base  # the Ethernet lidar port and the laptop listen endpoint


def test_the_cimpcc_line_light_overlay_is_the_slip_model_with_cimpccs_progress_reward() -> None:
    """config/cimpcc-line-light.toml: the light model README's "Laps at the limit" measures."""
    from shared.config.planner import CIMPCC_LINE_LIGHT_WEIGHTS

    line = load_config(CAR_TOML.parent / "cimpcc-line-light.toml").planner.cimpcc_line
    assert line.model == "kinematic_slip" and line.lead_pose_s == 0.04
    assert line.integrator == "rk4" and line.horizon_steps == 10 and line.lifted
    assert line.weights == CIMPCC_LINE_LIGHT_WEIGHTS
