"""Track geometry: loading, arc length, projection, boundaries, occupancy maps."""

from shared.track.errors import TrackError
from shared.track.geometry import Track
from shared.track.io import (
    BUILTIN_TRACKS,
    DEFAULT_TRACK,
    TRACK_SPEC_HELP,
    RacelineTable,
    load_f1tenth_raceline,
    load_map_track,
    load_track,
    write_f1tenth_centerline,
    write_f1tenth_raceline,
)
from shared.track.occupancy import OccupancyGrid, load_ros_map, occupancy_for, rasterize_track

__all__ = [
    "BUILTIN_TRACKS",
    "DEFAULT_TRACK",
    "TRACK_SPEC_HELP",
    "OccupancyGrid",
    "RacelineTable",
    "Track",
    "TrackError",
    "load_f1tenth_raceline",
    "load_map_track",
    "load_ros_map",
    "load_track",
    "occupancy_for",
    "rasterize_track",
    "write_f1tenth_centerline",
    "write_f1tenth_raceline",
]
