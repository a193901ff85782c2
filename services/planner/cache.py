"""Where the planner's built artefacts live: compiled problems (``mpc/solver.py``) and the
minimum-time laps (``mintime/store.py``), below one cache folder."""

from __future__ import annotations

import os
from pathlib import Path


def default_cache_dir() -> Path:
    """``$RACESTACK_CACHE`` or ``$XDG_CACHE_HOME/racestack`` or ``~/.cache/racestack``."""
    env = os.environ.get("RACESTACK_CACHE")
    if env:
        return Path(env)
    xdg = os.environ.get("XDG_CACHE_HOME")
    return Path(xdg) / "racestack" if xdg else Path.home() / ".cache" / "racestack"
