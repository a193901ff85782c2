"""The one typed, validated configuration of racestack (see ``root.RacestackConfig``)."""

from shared.config.base import ConfigError, Section
from shared.config.bus import BusSettings
from shared.config.root import (
    VEHICLE_MOVED,
    RacestackConfig,
    TrackSettings,
    config_from_dict,
    load_config,
)

__all__ = [
    "VEHICLE_MOVED",
    "BusSettings",
    "ConfigError",
    "RacestackConfig",
    "Section",
    "TrackSettings",
    "config_from_dict",
    "load_config",
]
