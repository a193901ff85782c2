"""Track geometry: loading, arc length, projection, boundaries, occupancy maps."""

from shared.track.errors import TrackError
from shared.track.geometry import Track
from shared.track.io import BUILTIN_TRACKS, DEFAULT_TRACK, load_track
from shared.track.occupancy import OccupancyGrid, load_ros_map, rasterize_track

__all__ = [
    "BUILTIN_TRACKS",
    "DEFAULT_TRACK",
    "OccupancyGrid",
    "Track",
    "TrackError",
    "load_ros_map",
    "load_track",
    "rasterize_track",
]
