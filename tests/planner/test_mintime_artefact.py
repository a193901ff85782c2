"""The minimum-time lap as an artefact: the tools make it, the planner only reads it.

The loader's one-line error names the command that makes the lap; that command, run as
named, makes exactly the artefact the planner then reads; the planner process fails fast
(exit code 2, one line, no IPOPT) without it; the request functions give the laps the
planners, the bench and the CLI solved before (the same cache keys, so caches still hit).
"""

from __future__ import annotations

import dataclasses
import os
import shlex
import signal
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import pytest

import services.planner.mintime.store as store
import services.tools.mintime as mintime_cli
from services.planner import (
    MIN_TIME_USES,
    MinTimeArtefactMissingError,
    MinTimeError,
    ensure_artefacts,
    for_stack,
    laps_of,
    limit_request,
    line_request,
    load_min_time_lap,
    make_planner,
    raceline_request,
    request_for,
)
from services.planner.mintime.ocp import MinTimeSettings
from services.planner.mintime.requests import LIMIT, planning_vehicle
from services.planner.service import main as planner_main
from services.tools.cli import main as racestack_main
from shared.commands import racestack_command
from shared.config import config_from_dict, load_config
from shared.config.methods import CIMPCC_LINE as LINE
from shared.config.methods import RACELINE
from shared.config.planner import PlannerSettings
from shared.config.vehicle import F1TENTH_GYM, REAL_CAR_IDENTIFIED, DynamicVehicleParams
from shared.track import Track, TrackError, load_track

#: The built-in track whose laps solve fastest (paperlike: 43 m, a few seconds each).
TRACK = "paperlike"
ROOT = Path(__file__).resolve().parents[2]
#: How the commands the errors name start here (``shared.commands``: runnable as printed).
RACESTACK = racestack_command()


@pytest.fixture
def keep_signal_handlers() -> Iterator[None]:
    """A service shell run in this process installs its Ctrl-C handler: put pytest's back."""
    saved = {sig: signal.getsignal(sig) for sig in (signal.SIGINT, signal.SIGTERM)}
    try:
        yield
    finally:
        for sig, handler in saved.items():
            signal.signal(sig, handler)


@pytest.fixture
def no_ipopt(monkeypatch: pytest.MonkeyPatch) -> None:
    """Any minimum-time solve fails the test (the planner must only read)."""

    def refuse(*_args, **_kwargs):
        raise AssertionError("the planner started IPOPT")

    monkeypatch.setattr(store, "solve_min_time", refuse)


@pytest.fixture
def empty_cache(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    """A fresh, empty default cache (``$RACESTACK_CACHE``) for this test."""
    cache = tmp_path / "cache"
    monkeypatch.setenv("RACESTACK_CACHE", str(cache))
    return cache


def line_config(tmp_path: Path, method: str = LINE) -> Path:
    """A configuration racing `method` on ``TRACK``, solver uncompiled (builds fast)."""
    path = tmp_path / "line.toml"
    path.write_text(
        f'[track]\nsource = "builtin:{TRACK}"\n\n[planner]\nmethod = "{method}"\n\n'
        "[planner.solver]\ncompile = false\n"
    )
    return path


# ---------------------------------------------------------------------------- the loader
@pytest.mark.parametrize("use", MIN_TIME_USES)
def test_the_loader_only_reads_and_its_error_is_one_line_naming_the_command(
    tmp_path: Path, no_ipopt: None, use: str
) -> None:
    track = load_track(TRACK)
    car, settings = request_for(use, PlannerSettings(), F1TENTH_GYM)
    with pytest.raises(MinTimeArtefactMissingError) as info:
        load_min_time_lap(track, car, settings, cache_dir=tmp_path, use=use)
    err = info.value
    assert isinstance(err, MinTimeError) and isinstance(err, TrackError)  # every shell's path
    text = str(err)
    assert "\n" not in text
    assert text.startswith(f"no minimum-time lap for {use} of this car on {TRACK} (cache ")
    assert str(tmp_path / "mintime") in text
    assert text.endswith(
        f"make it with: {RACESTACK} mintime --for {use} --track builtin:{TRACK} "
        f"--cache {tmp_path} [--config FILE]"
    )
    assert err.command in text and err.path.parent == tmp_path / "mintime"
    assert not (tmp_path / "mintime").exists()  # nothing written either
    # the service's form: its own configuration (or none: the built-in one)
    assert err.for_config("my.toml").command.endswith("--config my.toml")
    assert "--config" not in err.for_config(None).command


def test_a_lap_of_other_settings_names_them(tmp_path: Path, no_ipopt: None) -> None:
    with pytest.raises(MinTimeArtefactMissingError) as info:
        load_min_time_lap(load_track(TRACK), F1TENTH_GYM, MinTimeSettings(5.0, ds_m=0.2),
                          cache_dir=tmp_path)
    assert "no minimum-time lap of this car" in str(info.value)
    assert f"{RACESTACK} mintime --track builtin:paperlike --v-max 5 --ds 0.2 --margin 0.02" in (
        info.value.command
    )


# --------------------------------------------------------------------- the planner process
@pytest.mark.parametrize("method", [LINE, RACELINE])
def test_the_planner_process_fails_fast_without_its_lap(
    tmp_path: Path, empty_cache: Path, no_ipopt: None, keep_signal_handlers: None, capsys,
    method: str,
) -> None:
    """``python -m services.planner`` (in process): exit code 2 with the one line naming
    the command with this configuration, before any solve, compile or bus."""
    config = line_config(tmp_path, method)
    assert planner_main(["--config", str(config)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "Traceback" not in err, err
    assert err.startswith(f"planner: error: no minimum-time lap for {method} of this car on ")
    assert err.rstrip().endswith(
        f"make it with: {RACESTACK} mintime --for {method} --track builtin:{TRACK} "
        f"--config {config}"
    )
    assert str(empty_cache / "mintime") in err
    assert not list(empty_cache.rglob("*.so"))  # failed before compiling anything


def test_the_planner_process_exits_at_once_without_its_lap(tmp_path: Path) -> None:
    """The real process (``python -m services.planner``), an empty cache: exit code 2 with
    the one error line, no solve started (no progress line, nothing written)."""
    config = line_config(tmp_path)
    env = {**os.environ, "RACESTACK_CACHE": str(tmp_path / "cache"), "PYTHONPATH": str(ROOT)}
    done = subprocess.run(
        [sys.executable, "-m", "services.planner", "--config", str(config)],
        cwd=ROOT, env=env, capture_output=True, text=True, timeout=60,
        stdin=subprocess.DEVNULL,
    )
    assert done.returncode == 2, done.stderr
    # the service's INFO log lines, then the one error line
    lines = [ln for ln in done.stderr.splitlines() if ln.strip() and " INFO " not in ln]
    assert len(lines) == 1 and "Traceback" not in done.stderr, done.stderr
    assert lines[0].startswith("planner: error: no minimum-time lap for cimpcc-line")
    assert f"make it with: {RACESTACK} mintime --for cimpcc-line" in lines[0]
    assert "solving" not in done.stdout + done.stderr
    assert not (tmp_path / "cache" / "mintime").exists()


def test_racestack_up_makes_the_lap_before_it_starts_the_planner(
    tmp_path: Path, monkeypatch, capsys
) -> None:
    import services.tools.launcher.up as up
    from shared.bus import BusOpenError

    made: list = []

    def fake_ensure(method, track, settings, vehicle=None, **kwargs):
        made.append((method, track.name, settings, vehicle))
        kwargs["progress"]("solving ...")
        return []

    def no_bus(_settings):
        assert made, "the bus opened before the planner's lap was made"
        raise BusOpenError("test: no bus")

    monkeypatch.setattr(up, "ensure_artefacts", fake_ensure)
    monkeypatch.setattr(up.Launcher, "open_bus", staticmethod(no_bus))
    cfg = load_config(str(line_config(tmp_path)))
    opts = up.UpOptions(config_path=None, run_dir=tmp_path / "run")
    assert up.run_up(cfg, opts) == 2
    # the planner's settings as the stack's planner builds them (``for_stack``: the raceline's
    # margin widened for the configured pose source)
    stack = for_stack(cfg.planner, cfg.localization.pose_source)
    assert made == [(LINE, TRACK, stack, cfg.vehicle)]
    assert "racestack up: solving ..." in capsys.readouterr().out
    # a lap that cannot exist: one line, nothing started

    def infeasible(*_args, **_kwargs):
        raise MinTimeError("builtin:paperlike", "no feasible lap: too narrow")

    monkeypatch.setattr(up, "ensure_artefacts", infeasible)
    assert up.run_up(cfg, up.UpOptions(config_path=None, run_dir=tmp_path / "run2")) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "no feasible lap" in err, err
    assert not (tmp_path / "run2").exists()


def test_the_named_command_makes_the_lap_the_planner_reads(
    tmp_path: Path, empty_cache: Path, capsys
) -> None:
    """The command of the error, run as written (``racestack mintime --for cimpcc-line
    ...``), makes the artefact; then the loader finds it and the planner builds."""
    config = line_config(tmp_path)
    cfg = load_config(str(config))
    track = load_track(cfg.track.source)
    with pytest.raises(MinTimeArtefactMissingError) as info:
        make_planner(track, cfg.planner, cfg.curvature, vehicle=cfg.vehicle)
    command = info.value.for_config(str(config), cfg.track.source).command
    argv = shlex.split(command)
    assert argv[:2] == [RACESTACK, "mintime"]  # runnable as printed (shared.commands)
    out = tmp_path / "out"
    assert racestack_main([*argv[1:], "--out", str(out), "--no-figures"]) == 0
    printed = capsys.readouterr()
    assert "solving the minimum-time lap for cimpcc-line" in printed.out
    assert printed.err == ""
    assert (out / "mintime.json").is_file() and (out / "raceline.csv").is_file()
    # exactly the planner's lap: read back (no solve), and the planner builds on it
    car, settings = line_request(cfg.planner, cfg.vehicle)
    lap = load_min_time_lap(track, car, settings, use=LINE)
    assert lap.cache_hit and lap.success
    planner = make_planner(track, cfg.planner, cfg.curvature, vehicle=cfg.vehicle)
    assert planner.reference.speed.lap_time_s == pytest.approx(lap.lap_time_s, rel=0.02)
    # the tools' ensure_artefacts finds it too (nothing to solve)
    (again,) = ensure_artefacts(None, track, cfg.planner, cfg.vehicle)
    assert again.cache_hit and again.lap_time_s == lap.lap_time_s


# ----------------------------------------------------------------------- what to make
def test_ensure_artefacts_makes_what_the_method_races_on(monkeypatch) -> None:
    made: list = []

    def fake_make(track, car, settings, cache_dir=None, use_cache=True, *, use=None,
                  progress=None):
        made.append((use, car, settings))
        return use

    monkeypatch.setattr(store, "make_min_time_lap", fake_make)
    track = load_track(TRACK)
    s = PlannerSettings()
    for method in ("cimpcc", "mpcc", "mpcc-tuned", "cimpcc-tuned"):
        assert ensure_artefacts(method, track, s) == [] and not made
    curvature = s.model_copy(update={"raceline": s.raceline.model_copy(
        update={"line": "min_curvature"})})
    assert ensure_artefacts(RACELINE, track, curvature) == [] and laps_of(RACELINE, curvature) == ()
    assert ensure_artefacts(LINE, track, s) == [LINE]
    assert made[-1] == (LINE, *line_request(s, F1TENTH_GYM))
    assert ensure_artefacts(RACELINE, track, s) == [RACELINE]
    assert made[-1] == (RACELINE, *raceline_request(s, F1TENTH_GYM))
    # None: the settings' own method
    assert ensure_artefacts(None, track, s.model_copy(update={"method": LINE})) == [LINE]
    # a slow servo's out lap on a line of its own (``flying_servo_margin_m``): both laps
    fly = s.model_copy(update={"raceline": s.raceline.model_copy(
        update={"flying_servo_margin_m": 0.0})})
    out_lap = RACELINE + "-out-lap"
    assert ensure_artefacts(RACELINE, track, fly, REAL_CAR_IDENTIFIED) == [RACELINE, out_lap]
    assert made[-2:] == [(RACELINE, *raceline_request(fly, REAL_CAR_IDENTIFIED)),
                         (out_lap, *raceline_request(fly, REAL_CAR_IDENTIFIED, out_lap=True))]
    assert ensure_artefacts(RACELINE, track, fly) == [RACELINE]  # the gym's servo: one


# ------------------------------------------------- the same laps as before (cache keys)
def _previous_line(s: PlannerSettings, car: DynamicVehicleParams):
    """How ``min_time_reference`` built the cimpcc-line lap before the requests module."""
    line = s.cimpcc_line
    lo, hi = s.bounds.delta_rad
    update = {
        "steering_min_rad": max(car.steering_min_rad, lo),
        "steering_max_rad": min(car.steering_max_rad, hi),
    }
    if line.grip_fraction != 1.0:
        update["mu"] = car.mu * line.grip_fraction
    return (car.model_copy(update=update),
            MinTimeSettings(v_max_mps=line.v_max_mps, margin_m=line.line_margin_m))


def _previous_raceline(s: PlannerSettings, car: DynamicVehicleParams):
    """How ``RacelinePlanner`` built its lap before the requests module (within the
    planner's bounds: ``steering_range = "bounds"``; the car's own lock, the default since
    issue #21's fourteenth session, cuts nothing)."""
    f = s.raceline.min_time_steering_fraction
    if s.raceline.steering_range == "car":
        lo, hi = f * car.steering_min_rad, f * car.steering_max_rad
    else:
        lo = max(car.steering_min_rad, f * s.bounds.delta_rad[0])
        hi = min(car.steering_max_rad, f * s.bounds.delta_rad[1])
    if (lo, hi) != (car.steering_min_rad, car.steering_max_rad):
        car = DynamicVehicleParams.model_validate(
            {**car.model_dump(), "steering_min_rad": lo, "steering_max_rad": hi})
    o = s.raceline
    return car, MinTimeSettings(v_max_mps=o.v_max_mps, ds_m=o.ds_m, margin_m=o.min_time_margin_m)


def _previous_limit(s: PlannerSettings, car: DynamicVehicleParams):
    """How the bench (and the CLI with its defaults) built the limit before."""
    return car, MinTimeSettings(v_max_mps=s.cimpcc.v_up_mps[0])


CONFIGS = {
    "defaults": {},
    "changed": {
        "planner": {
            "bounds": {"delta_rad": [-0.3, 0.35]},
            "cimpcc": {"v_up_mps": [3.9, 1.5]},
            "cimpcc_line": {"grip_fraction": 0.93, "v_max_mps": 4.5, "line_margin_m": 0.05},
            "raceline": {"v_max_mps": 4.0, "ds_m": 0.2, "min_time_margin_m": 0.04,
                         "steering_range": "bounds", "min_time_steering_fraction": 1.0},
        },
        "vehicle": {"mu": 0.9, "steering_max_rad": 0.33},
    },
}


@pytest.mark.parametrize("name", list(CONFIGS))
def test_the_requests_are_the_laps_solved_before(name: str) -> None:
    cfg = config_from_dict(CONFIGS[name], name)
    car = cfg.vehicle
    track = load_track(TRACK)
    for request, previous in (
        (line_request, _previous_line),
        (raceline_request, _previous_raceline),
        (limit_request, _previous_limit),
    ):
        got = request(cfg.planner, car)
        want = previous(cfg.planner, car)
        # the Pacejka reserves (issue #21) are new and act on no other tyres: the same lap;
        # the high-speed reserve (issue #21) acts only above 4.18 m/s, over these caps
        assert not got.settings.reserve_active, request.__name__
        plain = dataclasses.replace(
            got.settings, slip_fraction=1.0, ellipse_fraction=1.0,
            **{f: getattr(want[1], f) for f in store.RESERVE_FIELDS},
        )
        assert plain == want[1], request.__name__
        assert store.cache_key(track, *got) == store.cache_key(track, *want), request.__name__
    # the default car is the simulator's default (F1TENTH gym)
    assert line_request(cfg.planner) == line_request(cfg.planner, F1TENTH_GYM)
    assert planning_vehicle(car, None) is car
    assert request_for(LIMIT, cfg.planner, car) == limit_request(cfg.planner, car)
    with pytest.raises(ValueError, match="unknown"):
        request_for("fastest", cfg.planner, car)


def _cli_request(monkeypatch, argv: list[str]) -> tuple[Track, DynamicVehicleParams,
                                                        MinTimeSettings]:
    """(track, car, settings) ``racestack mintime argv`` solves (stopped right there)."""
    seen = []

    def stop(track, car, settings, *_args, **_kwargs):
        seen.append((track, car, settings))
        raise MinTimeError("test", "stopped")

    monkeypatch.setattr(mintime_cli, "make_min_time_lap", stop)
    mintime_cli.main(argv)
    return seen[0]


def test_the_cli_makes_the_same_laps(tmp_path: Path, monkeypatch, capsys) -> None:
    config = tmp_path / "c.toml"
    config.write_text('[planner.cimpcc_line]\ngrip_fraction = 0.9\n'
                      '[vehicle]\nmu = 0.95\n')
    cfg = load_config(str(config))
    base = ["--config", str(config), "--track", TRACK, "--out", str(tmp_path / "o")]
    for use, request in ((LIMIT, limit_request), (LINE, line_request),
                         (RACELINE, raceline_request)):
        track, car, settings = _cli_request(monkeypatch, [*base, "--for", use])
        # the lap the stack's planner reads (``for_stack``: the pose source's margin)
        want = request(for_stack(cfg.planner, cfg.localization.pose_source), cfg.vehicle)
        assert store.cache_key(track, car, settings) == store.cache_key(track, *want), use
    # no --for: the limit, as before (the configured top speed, default grid and margin)
    track, car, settings = _cli_request(monkeypatch, base)
    assert (car, settings) == _previous_limit(cfg.planner, cfg.vehicle)
    # --v-max overrides the limit's top speed only
    _, _, settings = _cli_request(monkeypatch, [*base, "--v-max", "5"])
    assert settings == MinTimeSettings(v_max_mps=5.0)
    capsys.readouterr()


def test_the_cli_solves_for_vehicle_or_on_request_the_simulated_car(
    tmp_path: Path, monkeypatch, capsys
) -> None:
    config = tmp_path / "m.toml"
    config.write_text('[vehicle]\nmu = 0.95\n[simulator.vehicle]\nmu = 0.8\n')
    cfg = load_config(str(config))
    base = ["--config", str(config), "--track", TRACK, "--out", str(tmp_path / "o")]
    _, car, _ = _cli_request(monkeypatch, base)
    assert car == cfg.vehicle and car.mu == 0.95  # the planners' car by default
    _, car, _ = _cli_request(monkeypatch, [*base, "--simulated-car"])
    assert car == cfg.simulator.vehicle and car.mu == 0.8  # the bench's reference car
    _, car, _ = _cli_request(monkeypatch, [*base, "--for", LINE])
    assert car == line_request(cfg.planner, cfg.vehicle).car
    capsys.readouterr()
    assert mintime_cli.main([*base, "--for", LINE, "--simulated-car"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "--simulated-car: only with --for limit" in err, err


def test_the_planner_s_laps_take_no_overrides(tmp_path: Path, capsys) -> None:
    code = mintime_cli.main(["--for", LINE, "--v-max", "5", "--track", TRACK,
                             "--out", str(tmp_path / "o")])
    assert code == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "--v-max: only with --for limit" in err, err
