"""Fixtures of the localisation tests: the built-in track rasterised once per session."""

from __future__ import annotations

import pytest

from shared.track import OccupancyGrid, Track, load_track, rasterize_track


@pytest.fixture(scope="session")
def paperlike() -> tuple[OccupancyGrid, Track]:
    """The built-in ``paperlike`` track and its 5 cm occupancy grid (needs no shared data)."""
    track = load_track("paperlike")
    return rasterize_track(track, resolution_m=0.05), track
