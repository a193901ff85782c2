"""The one racestack configuration: every section, loaded once at the edge from TOML.

``load_config(path)`` reads a TOML file (any subset of the sections; the rest default),
validates it into frozen typed objects and raises ``ConfigError`` naming the file, the
dotted key and the problem. Unknown keys anywhere are errors. Services receive the objects,
never the path.

The car is given once, as ``[vehicle]``: every planner, the minimum-time lap and the
simulator assume it. ``[simulator.vehicle]`` is an optional override for model-mismatch
experiments: absent, the simulator races ``[vehicle]``; present, the simulator races that
car while the planners keep ``[vehicle]``. Its keys change ``[vehicle]``'s; a ``preset``
given there starts from that preset instead. ``cfg.simulator.vehicle`` is always the car
the simulator races (resolved when the configuration is validated), ``cfg.vehicle`` the car
the planners believe. A changed configuration is made by validating changed tables
(``config_from_dict``); ``model_copy(update={"vehicle": ...})`` skips validation and would
leave the simulator's car as it was.

A file with ``[simulator.vehicle]`` and no ``[vehicle]`` (written when the simulator's car was
the one car of the stack) is an error of one line, ``VEHICLE_MOVED``: its car is not silently
taken as a mismatch.
"""

from __future__ import annotations

import difflib
import tomllib
import typing
from pathlib import Path
from typing import Any

from pydantic import BaseModel, Field, ValidationError, model_validator
from pydantic_core import PydanticCustomError

from shared.config.base import ConfigError, Section
from shared.config.bus import BusSettings
from shared.config.cars import CarEntry, check_cars
from shared.config.lidar import LidarDriverSettings
from shared.config.localization import LocalizationSettings
from shared.config.planner import CurvatureSettings, PlannerSettings
from shared.config.processes import ProcessSettings
from shared.config.ros2 import Ros2Settings
from shared.config.simulator import SimulatorSettings
from shared.config.telemetry import TelemetrySettings
from shared.config.vehicle import DynamicVehicleParams
from shared.config.vesc import VescSettings

#: The error of a configuration that gives the car only as ``[simulator.vehicle]``.
VEHICLE_MOVED = (
    "[simulator.vehicle] moved to [vehicle] (the car the planner, the minimum-time lap and the "
    "simulator assume); keep [simulator.vehicle] next to a [vehicle] section only to simulate "
    "a different car than the planner believes"
)
#: Error type of ``VEHICLE_MOVED`` (reported as the message alone, without a key).
_MOVED_TYPE = "section_moved"


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
    """The root of the configuration (one section per concern).

    ``vehicle`` is the car the planners and the minimum-time lap assume; ``simulator.vehicle``
    the car the simulator races: ``vehicle`` unless ``[simulator.vehicle]`` overrides it (see
    the module docstring). ``simulates_another_car`` says whether the two differ.
    """

    track: TrackSettings = TrackSettings()
    vehicle: DynamicVehicleParams = Field(
        DynamicVehicleParams(),
        description="The car: geometry, mass, tyres and limits of the dynamic single-track "
        "model. Every planner (its minimum-time lines, tyre-slip models, tracker and recovery "
        "ramp), the minimum-time lap and the simulator assume it; the simulator races another "
        "car only when [simulator.vehicle] is given. Presets: f1tenth_gym (the F1TENTH gym's "
        "values) and real_car_identified (a real car's identified mass, inertia, axles, "
        "steering and Pacejka tyres; shared/config/vehicle.py); a key next to the preset "
        "overrides it",
    )
    curvature: CurvatureSettings = CurvatureSettings()
    planner: PlannerSettings = PlannerSettings()
    bus: BusSettings = BusSettings()
    simulator: SimulatorSettings = SimulatorSettings()
    localization: LocalizationSettings = LocalizationSettings()
    vesc: VescSettings = VescSettings()
    lidar_driver: LidarDriverSettings = LidarDriverSettings()
    telemetry: TelemetrySettings = TelemetrySettings()
    ros2: Ros2Settings = Ros2Settings()
    processes: ProcessSettings = ProcessSettings()
    cars: tuple[CarEntry, ...] = Field(
        (),
        description="Several cars on one track ([[cars]]: name, method, speed_scale, pace, "
        "start_gap_m, start_s_m; shared/config/cars.py): one simulator integrates them all, "
        "racestack up starts a bridge and a planner per car; empty: the one car of [bus] car",
    )

    @model_validator(mode="after")
    def _cars_distinct(self) -> RacestackConfig:
        check_cars(self.cars, self.planner.method)
        return self

    def car(self, name: str) -> CarEntry | None:
        """The ``[[cars]]`` entry named `name` (None: not in the list)."""
        return next((c for c in self.cars if c.name == name), None)

    @model_validator(mode="before")
    @classmethod
    def _simulated_car_tables(cls, data: Any) -> Any:
        """Tables (TOML, dicts): ``[simulator.vehicle]`` without ``[vehicle]`` is the
        ``VEHICLE_MOVED`` error; an override without a ``preset`` changes ``[vehicle]``'s
        keys (merged here, so its preset and values are the base)."""
        if not isinstance(data, dict):
            return data
        sim = data.get("simulator")
        if not isinstance(sim, dict) or "vehicle" not in sim:
            return data
        if "vehicle" not in data:
            raise PydanticCustomError(_MOVED_TYPE, VEHICLE_MOVED)
        override = sim["vehicle"]
        base = _vehicle_table(data["vehicle"])
        if not isinstance(override, dict) or "preset" in override or base is None:
            return data
        return {**data, "simulator": {**sim, "vehicle": {**base, **override}}}

    @model_validator(mode="after")
    def _simulated_car_defaults_to_vehicle(self) -> RacestackConfig:
        """Without ``[simulator.vehicle]`` the simulator races ``[vehicle]``: the resolved
        ``simulator.vehicle`` keeps the car out of the simulator's set fields (so it still
        reads as not given)."""
        sim = self.simulator
        if "vehicle" not in sim.model_fields_set and sim.vehicle != self.vehicle:
            values = {**dict(sim), "vehicle": self.vehicle}  # every value already validated
            resolved = SimulatorSettings.model_construct(set(sim.model_fields_set), **values)
            object.__setattr__(self, "simulator", resolved)  # frozen: set once, here
        return self

    @model_validator(mode="after")
    def _distinct_serial_ports(self) -> RacestackConfig:
        """``[vesc] port`` and ``[lidar_driver] port`` name two devices: one path for both
        would have one driver talk SCIP to the VESC or VESC frames to the lidar."""
        if self.vesc.port == self.lidar_driver.port:
            raise ValueError(
                f"[vesc] port and [lidar_driver] port are both {self.vesc.port!r}: each "
                "device has its own (e.g. /dev/sensors/vesc and /dev/sensors/hokuyo)"
            )
        return self

    @property
    def simulates_another_car(self) -> bool:
        """True when the simulator races another car than the planners believe (a
        ``[simulator.vehicle]`` that differs from ``[vehicle]``)."""
        return self.simulator.vehicle != self.vehicle


def _vehicle_table(value: Any) -> dict[str, Any] | None:
    """``[vehicle]`` as a table to merge an override onto, or None when it is no valid car
    (its own errors are reported at ``vehicle``, not a second time at the override)."""
    if isinstance(value, DynamicVehicleParams):
        return value.model_dump()
    if not isinstance(value, dict):
        return None
    try:
        DynamicVehicleParams.model_validate(value)
    except ValidationError:
        return None
    return dict(value)


def _format_errors(source: str, exc: ValidationError) -> str:
    lines = []
    for err in exc.errors():
        loc = ".".join(str(p) for p in err["loc"]) or "(root)"
        msg = err["msg"]
        if err["type"] == _MOVED_TYPE:
            lines.append(f"{source}: {msg}")
            continue
        if err["type"] == "extra_forbidden":
            msg = "unknown key" + _did_you_mean(err["loc"])
        lines.append(f"{source}: {loc}: {msg}")
    return "\n".join(lines)


def _section_at(path: tuple[Any, ...]) -> type[BaseModel] | None:
    """The section class at dotted `path` from the root (None: not a section)."""
    model: type[BaseModel] = RacestackConfig
    for part in path:
        field = model.model_fields.get(str(part))
        if field is None:
            return None
        candidates = [field.annotation, *typing.get_args(field.annotation)]
        nxt = next((c for c in candidates
                    if isinstance(c, type) and issubclass(c, BaseModel)), None)
        if nxt is None:
            return None
        model = nxt
    return model


def _did_you_mean(loc: tuple[Any, ...]) -> str:
    """``; did you mean 'x'?`` for an unknown key close to a key of its section, else ''."""
    section = _section_at(tuple(loc[:-1]))
    if section is None:
        return ""
    close = difflib.get_close_matches(str(loc[-1]), list(section.model_fields), n=1)
    return f"; did you mean {close[0]!r}?" if close else ""


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
