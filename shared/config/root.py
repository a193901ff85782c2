"""The one racestack configuration: every section, loaded once at the edge from TOML.

``load_config(path)`` reads a TOML file (any subset of the sections; the rest default),
validates it into frozen typed objects and raises ``ConfigError`` naming the file, the
dotted key and the problem. Unknown keys anywhere are errors. Services receive the objects,
never the path.
"""

from __future__ import annotations

import tomllib
from pathlib import Path
from typing import Any

from pydantic import Field, ValidationError

from shared.config.base import ConfigError, Section
from shared.config.bus import BusSettings
from shared.config.lidar import LidarDriverSettings
from shared.config.localization import LocalizationSettings
from shared.config.planner import CurvatureSettings, PlannerSettings
from shared.config.ros2 import Ros2Settings
from shared.config.simulator import SimulatorSettings
from shared.config.telemetry import TelemetrySettings
from shared.config.vesc import VescSettings


class TrackSettings(Section):
    """Which track to race: a built-in name (``builtin:paperlike``), a folder or a file.

    Attributes:
        source: ``builtin:paperlike`` / ``builtin:gentle``, a folder holding a track, an
            F1TENTH centreline CSV, the centre file of a CiMPCC waypoint triple, or a ROS
            map_server ``MAP.yaml`` (its centreline and widths are extracted from the map,
            see ``racestack track --from-map``); relative paths are from the working folder.
    """

    source: str = Field("builtin:paperlike", min_length=1)


class RacestackConfig(Section):
    """The root of the configuration (one section per concern)."""

    track: TrackSettings = TrackSettings()
    curvature: CurvatureSettings = CurvatureSettings()
    planner: PlannerSettings = PlannerSettings()
    bus: BusSettings = BusSettings()
    simulator: SimulatorSettings = SimulatorSettings()
    localization: LocalizationSettings = LocalizationSettings()
    vesc: VescSettings = VescSettings()
    lidar_driver: LidarDriverSettings = LidarDriverSettings()
    telemetry: TelemetrySettings = TelemetrySettings()
    ros2: Ros2Settings = Ros2Settings()


def _format_errors(source: str, exc: ValidationError) -> str:
    lines = []
    for err in exc.errors():
        loc = ".".join(str(p) for p in err["loc"]) or "(root)"
        msg = err["msg"]
        if err["type"] == "extra_forbidden":
            msg = "unknown key"
        lines.append(f"{source}: {loc}: {msg}")
    return "\n".join(lines)


def config_from_dict(data: dict[str, Any], source: str = "<dict>") -> RacestackConfig:
    """Validate a nested dict into the configuration; ConfigError on any problem."""
    try:
        return RacestackConfig.model_validate(data)
    except ValidationError as exc:
        raise ConfigError(_format_errors(source, exc)) from None


def load_config(path: str | Path | None = None) -> RacestackConfig:
    """Load and validate a TOML configuration file (None: all defaults)."""
    if path is None:
        return RacestackConfig()
    p = Path(path)
    try:
        data = tomllib.loads(p.read_text(encoding="utf-8"))
    except OSError as exc:
        raise ConfigError(f"{p}: cannot read config ({exc.strerror or exc})") from None
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
        raise ConfigError(f"{p}: not valid TOML ({exc})") from None
    return config_from_dict(data, str(p))
