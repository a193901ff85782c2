"""The minimum-time lap as an artefact on disk: made offline by the tools, read by the planner.

A minimum-time lap (``services.planner.mintime.ocp.solve_min_time``: an IPOPT solve of
seconds to minutes) is an artefact keyed on everything it depends on (``cache_key``): the
track's points and widths, every vehicle parameter, the settings, ``CODE_VERSION`` and the
CasADi version. It lives in ``<cache>/mintime/<key>.npz`` with ``<cache>`` the compiled
solver cache's base folder (``services.planner.cache.default_cache_dir``:
``$RACESTACK_CACHE``, else ``$XDG_CACHE_HOME/racestack`` or ``~/.cache/racestack``); the
file holds the lap (the line, its speed profile, states and inputs) and its figures.

- ``load_min_time_lap`` (the planner core, the planner process): only reads; a missing
  artefact is ``MinTimeArtefactMissingError``, one line naming the command that makes it
  (``racestack mintime --for USE --track SPEC [--config FILE]``). It never starts IPOPT.
- ``make_min_time_lap`` (the tools): reads, or on a miss solves with IPOPT (a progress line
  first) and writes the artefact.
- ``ensure_artefacts(method, ...)`` (the tools, before they build planners): makes every
  lap planner `method` races on (``services.planner.mintime.requests``).

Files are written atomically; an unreadable or mismatched file counts as missing.
Infeasible problems are not cached.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import logging
import os
import shlex
import sys
import tempfile
from collections.abc import Callable
from pathlib import Path

import casadi as ca
import numpy as np

from services.planner.cache import default_cache_dir
from services.planner.mintime.model import servo_reach
from services.planner.mintime.ocp import (
    CODE_VERSION,
    MinTimeError,
    MinTimeLap,
    MinTimeSettings,
    solve_min_time,
)
from services.planner.mintime.requests import laps_of, request_for
from shared.commands import racestack_command
from shared.config.planner import PlannerSettings
from shared.config.vehicle import DynamicVehicleParams
from shared.track import Track

log = logging.getLogger(__name__)

#: Sub-folder of the cache base folder.
CACHE_SUBDIR = "mintime"
#: Stands for the configuration file in a command line when it is not known.
CONFIG_PLACEHOLDER = "[--config FILE]"
#: Settings added after laps were cached: at these values they stay out of the key, so the
#: laps stored before them keep their keys (the same problem, the same lap).
KEY_FREE_DEFAULTS: dict[str, object] = {"slip_fraction": 1.0, "ellipse_fraction": 1.0,
                                        "reserve_yaw_pole_per_s": None,
                                        "reserve_rear_fraction": None,
                                        "reserve_from_mps": None,
                                        "rear_ellipse_fraction": None}
#: The high-speed reserve's settings: in the key only when the reserve acts
#: (``MinTimeSettings.reserve_active``, a friction-limited tyre), so every lap whose top speed
#: is at or below its speed (the 4.18 m/s cap's) keeps its key.
RESERVE_FIELDS = ("reserve_speed_mps", "reserve_fraction", "reserve_width_mps",
                  "reserve_steering_weight_s", "reserve_margin_m", "reserve_yaw_pole_per_s",
                  "reserve_rear_fraction", "reserve_from_mps")


def cache_key(track: Track, vehicle: DynamicVehicleParams, settings: MinTimeSettings) -> str:
    """Hex digest of everything the minimum-time lap depends on (module docstring)."""
    h = hashlib.sha256()
    for arr in (track.xy, track.w_right_m, track.w_left_m):
        h.update(np.ascontiguousarray(arr, dtype=np.float64).tobytes())
    h.update(vehicle.model_dump_json().encode())
    fields = dataclasses.asdict(settings)
    if vehicle.tyre_model != "pacejka":  # the reserves act on Pacejka tyres only
        fields.update({n: KEY_FREE_DEFAULTS[n]
                       for n in ("slip_fraction", "ellipse_fraction", "rear_ellipse_fraction")})
    if not settings.reserve_active or vehicle.tyre_model == "linear":
        for name in RESERVE_FIELDS:  # no high-speed reserve: the problem (and key) of before
            del fields[name]
    for name, default in KEY_FREE_DEFAULTS.items():  # laps solved before these existed
        if name in fields and fields[name] == default:
            del fields[name]
    h.update(json.dumps(fields, sort_keys=True).encode())
    if servo_reach(vehicle) is not None:  # laps of a slow servo solved with its reach
        h.update(b"|servo-reach")
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


def print_progress(line: str) -> None:
    """Say `line` on stderr (the default progress of ``make_min_time_lap``)."""
    print(line, file=sys.stderr, flush=True)


def mintime_command(
    use: str | None,
    track_spec: str,
    config: str | None = CONFIG_PLACEHOLDER,
    settings: MinTimeSettings | None = None,
    cache_dir: str | Path | None = None,
) -> str:
    """The ``racestack mintime`` command line that makes the lap of `use` (one of
    ``requests.USES``) on `track_spec`.

    Args:
        use: the lap's use; None: the CLI's own lap with `settings`' top speed, grid and
            margin (``--v-max``, ``--ds``, ``--margin``).
        track_spec: what ``--track`` takes (a built-in name, folder or file).
        config: ``--config`` FILE; None: the built-in configuration (no ``--config``);
            ``CONFIG_PLACEHOLDER``: not known, written as ``[--config FILE]``.
        cache_dir: ``--cache`` DIR; None: the default cache (no ``--cache``).
    """
    words = [racestack_command(), "mintime"]  # runnable as printed (shared.commands)
    if use is not None:
        words += ["--for", use]
    words += ["--track", shlex.quote(track_spec)]
    if use is None and settings is not None:
        words += [
            "--v-max", f"{settings.v_max_mps:g}",
            "--ds", f"{settings.ds_m:g}",
            "--margin", f"{settings.margin_m:g}",
        ]
    if cache_dir is not None:
        words += ["--cache", shlex.quote(str(cache_dir))]
    if config == CONFIG_PLACEHOLDER:
        words.append(CONFIG_PLACEHOLDER)
    elif config is not None:
        words += ["--config", shlex.quote(config)]
    return " ".join(words)


class MinTimeArtefactMissingError(MinTimeError):
    """The minimum-time lap a planner races on is not on disk: one line naming the cache
    folder and the command that makes it (``command``). The planner never solves it itself.

    Attributes:
        track_name, track_spec: the track (its name; a spec ``--track`` takes).
        use: the lap's use (``requests.USES``), None for another lap.
        path: the artefact's file.
        command: the ``racestack mintime`` command line that makes it.
    """

    def __init__(
        self,
        track_name: str,
        track_spec: str,
        use: str | None,
        path: Path,
        *,
        config: str | None = CONFIG_PLACEHOLDER,
        settings: MinTimeSettings | None = None,
        cache_dir: str | Path | None = None,
    ) -> None:
        self.track_name = track_name
        self.track_spec = track_spec
        self.use = use
        self.path = path
        self._settings = settings
        self._cache_dir = cache_dir
        self.command = mintime_command(use, track_spec, config, settings, cache_dir)
        what = f" for {use}" if use is not None else ""
        super().__init__(
            track_spec,
            f"no minimum-time lap{what} of this car on {track_name} (cache {path.parent}): "
            f"make it with: {self.command}",
        )

    def __str__(self) -> str:
        return self.problem

    def for_config(
        self, config: str | None, track_spec: str | None = None
    ) -> MinTimeArtefactMissingError:
        """The same error with the command's ``--config`` set to `config` (None: the
        built-in configuration, no ``--config``) and, if given, its ``--track`` spec."""
        return MinTimeArtefactMissingError(
            self.track_name,
            track_spec or self.track_spec,
            self.use,
            self.path,
            config=config,
            settings=self._settings,
            cache_dir=self._cache_dir,
        )


def load_min_time_lap(
    track: Track,
    vehicle: DynamicVehicleParams,
    settings: MinTimeSettings | None = None,
    cache_dir: str | Path | None = None,
    *,
    use: str | None = None,
) -> MinTimeLap:
    """The minimum-time lap of `vehicle` on `track` with `settings` (None: the defaults)
    read from the cache (`cache_dir`, None: the default base folder); never solves.

    Args:
        use: the lap's use (``requests.USES``), for the error's command.

    Raises:
        MinTimeArtefactMissingError: no (readable) artefact for exactly this problem.
    """
    cfg = settings or MinTimeSettings()
    key = cache_key(track, vehicle, cfg)
    path = cache_file(key, cache_dir)
    lap = load_lap(path, key)
    if lap is None:
        raise MinTimeArtefactMissingError(
            track.name, track.source, use, path, settings=cfg, cache_dir=cache_dir
        )
    return lap


def make_min_time_lap(
    track: Track,
    vehicle: DynamicVehicleParams,
    settings: MinTimeSettings | None = None,
    cache_dir: str | Path | None = None,
    use_cache: bool = True,
    *,
    use: str | None = None,
    progress: Callable[[str], None] | None = print_progress,
) -> MinTimeLap:
    """The minimum-time lap from the cache, or solved with IPOPT and then cached (module
    docstring); `use_cache` False: solved, and not written.

    Args:
        use: the lap's use (``requests.USES``), named in the progress line.
        progress: called with one line before a solve (default: stderr; None: quiet).

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
    if progress is not None:
        what = f" for {use}" if use is not None else ""
        progress(
            f"solving the minimum-time lap{what} of this car on {track.name} with IPOPT "
            f"(once per track, car and settings; cache {path.parent}) ..."
        )
    lap = solve_min_time(track, vehicle, cfg)
    if use_cache:
        try:
            save_lap(path, lap, key)
        except OSError as exc:
            log.warning("could not cache the min-time lap in %s (%s)", path, exc)
    return lap


#: ``make_min_time_lap`` under the name the tools have used.
min_time_lap = make_min_time_lap


def ensure_artefacts(
    method: str | None,
    track: Track,
    settings: PlannerSettings,
    vehicle: DynamicVehicleParams | None = None,
    *,
    cache_dir: str | Path | None = None,
    progress: Callable[[str], None] | None = print_progress,
) -> list[MinTimeLap]:
    """Make every minimum-time lap planner `method` (None: ``settings.method``) races on
    with `settings` for `vehicle` (None: the F1TENTH gym's): nothing for ``cimpcc`` and
    ``mpcc``, the line for ``cimpcc-line``, the raceline's lap for ``raceline`` with
    ``line = "min_time"`` (``requests.laps_of``); each read from the cache or solved once.
    Returns those laps (in ``laps_of``'s order).

    Raises:
        MinTimeError: a lap has no feasible solution on `track`.
    """
    name = method or settings.method
    laps = []
    for use in laps_of(name, settings, vehicle):
        car, lap_settings = request_for(use, settings, vehicle)
        laps.append(
            make_min_time_lap(
                track, car, lap_settings, cache_dir, use=use, progress=progress
            )
        )
    return laps
