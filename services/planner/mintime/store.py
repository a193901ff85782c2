"""The minimum-time lap with a disk cache: solve once per track, car and settings (I/O shell).

``min_time_lap(track, vehicle, settings)`` returns the cached ``MinTimeLap`` when one exists
for exactly this problem, else solves it (``services.planner.mintime.ocp.solve_min_time``) and
stores it. The key hashes everything the result depends on: the track's points and widths,
every vehicle parameter, the settings, ``CODE_VERSION`` and the CasADi version. The cache
lives in ``<cache>/mintime/<key>.npz`` with ``<cache>`` the compiled-solver cache's base
folder (``services.planner.mpc.solver.default_cache_dir``: ``$RACESTACK_CACHE``, else
``$XDG_CACHE_HOME/racestack`` or ``~/.cache/racestack``). Files are written atomically; an
unreadable or mismatched file counts as a miss. Infeasible problems are not cached.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import logging
import os
import tempfile
from pathlib import Path

import casadi as ca
import numpy as np

from services.planner.mintime.ocp import CODE_VERSION, MinTimeLap, MinTimeSettings, solve_min_time
from services.planner.mpc.solver import default_cache_dir
from shared.config.vehicle import DynamicVehicleParams
from shared.track import Track

log = logging.getLogger(__name__)

#: Sub-folder of the cache base folder.
CACHE_SUBDIR = "mintime"


def cache_key(track: Track, vehicle: DynamicVehicleParams, settings: MinTimeSettings) -> str:
    """Hex digest of everything the minimum-time lap depends on (module docstring)."""
    h = hashlib.sha256()
    for arr in (track.xy, track.w_right_m, track.w_left_m):
        h.update(np.ascontiguousarray(arr, dtype=np.float64).tobytes())
    h.update(vehicle.model_dump_json().encode())
    h.update(json.dumps(dataclasses.asdict(settings), sort_keys=True).encode())
    h.update(f"{CODE_VERSION}|casadi-{ca.__version__}".encode())
    return h.hexdigest()[:32]


def cache_file(key: str, cache_dir: str | Path | None = None) -> Path:
    """Path of the cache entry of `key` (``cache_dir`` None: the default base folder)."""
    base = Path(cache_dir) if cache_dir is not None else default_cache_dir()
    return base / CACHE_SUBDIR / f"{key}.npz"


def save_lap(path: Path, lap: MinTimeLap, key: str) -> None:
    """Store `lap` at `path` (atomic: a temporary file in the same folder, then a rename)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    values = {
        f.name: getattr(lap, f.name) for f in dataclasses.fields(lap) if f.name != "cache_hit"
    }
    arrays = {k: v for k, v in values.items() if isinstance(v, np.ndarray)}
    scalars = {k: v for k, v in values.items() if k not in arrays}
    meta = {"key": key, "arrays": sorted(arrays), "scalars": scalars}
    fd, tmp = tempfile.mkstemp(dir=path.parent, suffix=".npz.tmp")
    try:
        with os.fdopen(fd, "wb") as fh:
            np.savez(fh, meta=np.array(json.dumps(meta)), **arrays)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def load_lap(path: Path, key: str) -> MinTimeLap | None:
    """The lap stored at `path` for `key`, or None (missing, unreadable or another key)."""
    if not path.exists():
        return None
    try:
        with np.load(path, allow_pickle=False) as data:
            meta = json.loads(str(data["meta"]))
            if meta.get("key") != key:
                return None
            arrays = {name: np.array(data[name]) for name in meta["arrays"]}
        return MinTimeLap(**meta["scalars"], **arrays, cache_hit=True)
    except (OSError, KeyError, ValueError, TypeError) as exc:  # TypeError: fields changed
        log.warning("ignoring unreadable min-time cache entry %s (%s)", path, exc)
        return None


def min_time_lap(
    track: Track,
    vehicle: DynamicVehicleParams,
    settings: MinTimeSettings | None = None,
    cache_dir: str | Path | None = None,
    use_cache: bool = True,
) -> MinTimeLap:
    """The minimum-time lap from the cache, or solved and then cached (module docstring).

    Raises:
        MinTimeError: no feasible lap (see ``solve_min_time``).
    """
    cfg = settings or MinTimeSettings()
    key = cache_key(track, vehicle, cfg)
    path = cache_file(key, cache_dir)
    if use_cache:
        lap = load_lap(path, key)
        if lap is not None:
            return lap
    lap = solve_min_time(track, vehicle, cfg)
    if use_cache:
        try:
            save_lap(path, lap, key)
        except OSError as exc:
            log.warning("could not cache the min-time lap in %s (%s)", path, exc)
    return lap
