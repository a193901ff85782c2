"""Fixtures shared by the whole suite."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
SHARED = ROOT.parent / "shared"
TRACKS = SHARED / "tracks"


@pytest.fixture(scope="session")
def shared_tracks() -> Path:
    """The real track data in ../shared/tracks (skips when the folder is missing)."""
    if not (TRACKS / "map416").is_dir():
        pytest.skip(f"needs the shared track data at {TRACKS} (not present beside this checkout)")
    return TRACKS


@pytest.fixture(scope="session", autouse=True)
def _solver_cache(tmp_path_factory: pytest.TempPathFactory) -> None:
    """Compile planner problems once per test session into a private cache."""
    if "RACESTACK_CACHE" not in os.environ:
        os.environ["RACESTACK_CACHE"] = str(tmp_path_factory.mktemp("solver-cache"))
