"""``racestack tune``: search a method's parameters for the fastest clean laps.

    racestack tune --method cimpcc --track paperlike --trials 40 --out DIR
                   [--storage URL] [--study NAME] [--config F] [--laps K] [--seeds 0,1,2]
                   [--margin M] [--pose-noise X] [--v-max V] [--seed S]
    racestack tune --method raceline --tracks gen:1001,gen:1002 --cars default,identified
                   --aggregate worst --out DIR ...

Each trial races the method with one point of its search space (``services.tools.tune.search``)
over ``--laps`` timed laps for each noise seed (``services.tools.tune.evaluate``) in every cell
of the family, each track of ``--tracks`` with each car of ``--cars``
(``services.tools.tune.family``); the objective is the mean lap time (one cell) or the worst or
mean ratio of a cell's mean lap to its car's minimum-time lap (several cells), and a trial that
leaves the track, needs the recovery rule, spins, drives a lap below the minimum-time lap,
comes closer than ``--margin`` to a boundary or misses a lap is infeasible. Optuna's seeded TPE
sampler proposes the points; the first trial is the configuration's own point (the baseline).
The study lives in ``--storage`` (default ``sqlite:///DIR/study.db``): run the same command
again to resume it, or in several processes to share it (give each its own ``--seed``). Writes
DIR/best.toml, DIR/trials.json, DIR/trials.csv and DIR/history.png (see
``services.tools.tune.output``). Ctrl-C stops after telling the running trial FAILED and writes
everything from the trials finished so far.

Exit codes: 0 with a best.toml written, 1 when no trial was feasible, 2 for bad input (one
line on stderr), 130 when interrupted (outputs written).
"""

from __future__ import annotations

import argparse
import json
import signal
import sys
import time
import tomllib
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from services.planner import MinTimeError
from services.tools.tune.evaluate import ObjectiveSettings
from services.tools.tune.family import FamilyCell, FamilyEvaluator, cell_config, limit_lap_s
from services.tools.tune.search import (
    AGGREGATES,
    CONSTRAINTS,
    PENALTY_S,
    SearchSpace,
    UnknownMethodError,
    fingerprint,
    space_for,
    tunable_methods,
)
from shared.config import ConfigError, load_config
from shared.evaluation.car_family import CARS, UnknownCarError, car_names
from shared.outdir import writable_dir_problem
from shared.track import TRACK_SPEC_HELP, Track, TrackError, load_track

if TYPE_CHECKING:  # optuna is imported only when a study runs
    from services.tools.tune.study import GracefulStop

PROG = "racestack tune"


class TuneArgumentError(ValueError):
    """A command-line value is wrong (one line, exit code 2)."""


def build_parser(ap: argparse.ArgumentParser | None = None) -> argparse.ArgumentParser:
    """Arguments of ``racestack tune``."""
    ap = ap or argparse.ArgumentParser(prog=PROG, description=__doc__.splitlines()[0])
    ap.add_argument("--method", required=True, help=f"one of {', '.join(tunable_methods())}")
    ap.add_argument("--track", help=f"{TRACK_SPEC_HELP} (default: the config's)")
    ap.add_argument("--tracks", default=None,
                    help="comma list of track specs to tune over, the family's tracks "
                    "(default: --track alone)")
    ap.add_argument("--cars", default="default",
                    help=f"comma list of cars to tune over, of {', '.join(CARS)} or "
                    "varied:SEED (as the robustness benchmark's; default default)")
    ap.add_argument("--aggregate", choices=AGGREGATES, default="worst",
                    help="with several cells (tracks x cars), the objective is the worst or "
                    "the mean ratio of a cell's mean lap to its minimum-time lap (default "
                    "worst)")
    ap.add_argument("--trials", type=int, default=40,
                    help="the study's trial budget, all workers together (default 40)")
    ap.add_argument("--out", required=True, help="output folder (best.toml, trials, figure)")
    ap.add_argument("--storage", help="Optuna RDB URL (default sqlite:///OUT/study.db)")
    ap.add_argument("--study", help="study name (default METHOD@TRACK-HASH)")
    ap.add_argument("--config", help="base TOML configuration (best.toml builds on it; "
                    "default: the built-in configuration)")
    ap.add_argument("--laps", type=int, default=2, help="timed laps per seed (default 2)")
    ap.add_argument("--seeds", default="0,1,2", help="noise seeds, comma list (default 0,1,2)")
    ap.add_argument("--margin", type=float, default=0.05,
                    help="the car's body stays this far inside the boundaries [m] (default "
                    "0.05)")
    ap.add_argument("--pose-noise", type=float, default=1.0,
                    help="pose noise seen by the planner, x the [simulator.pose] deviations "
                    "(default 1.0)")
    ap.add_argument("--v-max", type=float, default=None,
                    help="top speed v_l may reach [m/s] (default: the config's v_up v_l, "
                         "the paper's 4.18)")
    ap.add_argument("--seed", type=int, default=0, help="sampler seed (default 0)")
    return ap


def parse_seeds(text: str) -> tuple[int, ...]:
    """The --seeds list."""
    try:
        seeds = tuple(int(s) for s in text.split(",") if s.strip())
    except ValueError:
        raise TuneArgumentError(f"--seeds must be integers, got {text!r}") from None
    return seeds


def track_fingerprint(track: Track) -> str:
    """A hash of the track's geometry (mm)."""
    arr = np.round(np.column_stack([track.xy, track.w_right_m, track.w_left_m]) * 1e3)
    return fingerprint(arr.astype(np.int64).tobytes().hex())


def track_source(spec: str, track: Track) -> str:
    """How best.toml names the track: an absolute path, or ``builtin:NAME``."""
    p = Path(spec).expanduser()
    return str(p.resolve()) if p.exists() else track.source


def check_out_dir(out: Path, name: str, storage: str) -> None:
    """Create DIR; a DIR that holds the outputs of another study is an error."""
    problem = writable_dir_problem(out)
    if problem:
        raise TuneArgumentError(problem)
    doc_path = out / "trials.json"
    if doc_path.exists():
        try:
            study = json.loads(doc_path.read_text()).get("study", {})
        except (OSError, ValueError):
            return
        if study.get("study") != name or study.get("storage") != storage:
            from services.tools.tune.study import StudyMismatchError

            raise StudyMismatchError(
                f"{out} holds the results of study {study.get('study')!r} "
                f"({study.get('storage')}), not {name!r}; use another --out"
            )


@contextmanager
def stop_signals(stop: GracefulStop) -> Iterator[None]:
    """SIGTERM, and SIGINT unless inherited ignored (a shell's background job), go to
    `stop` while inside."""
    sigs = [signal.SIGTERM]
    if signal.getsignal(signal.SIGINT) is not signal.SIG_IGN:
        sigs.append(signal.SIGINT)
    try:
        old = {s: signal.signal(s, stop.handler) for s in sigs}
    except ValueError:  # not the main thread: no handlers
        yield
        return
    try:
        yield
    finally:
        for s, h in old.items():
            signal.signal(s, h)


def _say(text: str) -> None:
    print(f"{PROG}: {text}", file=sys.stderr, flush=True)


def _family(args: argparse.Namespace, default_spec: str) -> tuple[list[str], list[str]]:
    """The family's track specs and car names from --track / --tracks / --cars."""
    if args.track and args.tracks:
        raise TuneArgumentError("give --track or --tracks, not both")
    if args.tracks is not None:
        specs = list(dict.fromkeys(t.strip() for t in args.tracks.split(",") if t.strip()))
        if not specs:
            raise TuneArgumentError("--tracks names no track")
    else:
        specs = [args.track or default_spec]
    try:
        cars = car_names(args.cars)
    except UnknownCarError as exc:
        raise TuneArgumentError(f"--cars: {exc}") from None
    return specs, cars


def _prepare(
    args: argparse.Namespace,
) -> tuple[SearchSpace, ObjectiveSettings, dict[str, Any], dict[str, Any], list[FamilyCell]]:
    """Validate everything before anything races: (space, settings, base data, meta, cells)."""
    if args.method not in tunable_methods():
        raise UnknownMethodError(
            f"unknown method {args.method!r}; choose from {', '.join(tunable_methods())}"
        )
    if args.trials < 1:
        raise TuneArgumentError("--trials must be at least 1")
    cfg = load_config(args.config)
    base_data: dict[str, Any] = {}
    if args.config:
        base_data = tomllib.loads(Path(args.config).read_text(encoding="utf-8"))
    v_max = args.v_max if args.v_max is not None else cfg.planner.cimpcc.v_up_mps[0]
    try:
        settings = ObjectiveSettings(laps=args.laps, seeds=parse_seeds(args.seeds),
                                     margin_m=args.margin, pose_noise=args.pose_noise)
        space = space_for(args.method, v_max, cfg)
    except UnknownMethodError:
        raise
    except ValueError as exc:
        raise TuneArgumentError(str(exc)) from None
    specs, cars = _family(args, cfg.track.source)
    tracks = {spec: load_track(spec) for spec in specs}
    cells = [FamilyCell(spec, tracks[spec], car) for spec in specs for car in cars]
    family = len(cells) > 1
    first = cells[0].track
    fps = {spec: track_fingerprint(t) for spec, t in tracks.items()}
    if len(specs) == 1 and cars == ["default"]:
        name, tfp = first.name, fps[specs[0]]
    else:
        name = ",".join(t.name for t in tracks.values())
        tfp = fingerprint([[fps[s] for s in specs], cars])
    meta = {
        "method": args.method,
        "track": name,
        "track_fingerprint": tfp,
        "track_source": track_source(specs[0], first),
        "track_length_m": round(first.length_m, 3),
        "tracks": [{"name": t.name, "source": track_source(s, t), "fingerprint": fps[s],
                    "length_m": round(t.length_m, 3)} for s, t in tracks.items()],
        "cars": cars,
        "cells": [{"track": c.track.name, "car": c.car} for c in cells],
        "aggregate": args.aggregate if family else None,
        "value": f"{args.aggregate} ratio to the minimum-time lap" if family else "mean lap [s]",
        "constraints": list(CONSTRAINTS),
        "objective": settings.to_json(),
        "v_max_mps": v_max,
        "config": fingerprint(base_data),
        "config_path": str(Path(args.config).resolve()) if args.config else None,
        "space": [p.__dict__ for p in space.params],
    }
    return space, settings, base_data, meta, cells


def _limits(cells: list[FamilyCell], base_data: dict[str, Any], v_max: float) -> list[float]:
    """Each cell's minimum-time lap [s] (read from the cache, or solved once), a line each."""
    limits = []
    for cell in cells:
        try:
            lim, cached = limit_lap_s(cell.track, cell_config(base_data, cell.car), v_max,
                                      progress=None if len(cells) == 1 else _say)
        except MinTimeError as exc:
            raise TuneArgumentError(
                f"no minimum-time lap of car {cell.car} on {cell.track.name}: {exc}") from None
        limits.append(lim)
        _say(f"minimum-time lap of {cell.label}: {lim:.3f} s "
             f"({'cached' if cached else 'solved, cached'})")
    return limits


def _line(t: Any, budget: int, names: list[str], unit: str = " s") -> str:
    ua = t.user_attrs
    pts = " ".join(f"{n}={t.params[n]:.3g}" for n in names if n in t.params)
    if t.state.name == "FAIL":
        what = f"FAILED: {ua.get('error', '')}"
    elif ua.get("feasible"):
        what = f"{t.value:.3f}{unit}"
    else:
        lap = ua.get("mean_lap_s")
        what = ("infeasible" + (f" ({lap:.3f}{unit})" if lap else "") + ": "
                + "; ".join(ua.get("reasons", [])))
    return f"trial {t.number + 1:>3}/{budget}  {what}  [{pts}]  {ua.get('wall_s', 0):.1f} s"


def main(argv: list[str] | None = None, args: argparse.Namespace | None = None) -> int:
    """Run the tuning; see the module docstring for the exit codes."""
    args = args or build_parser().parse_args(argv)
    try:
        space, settings, base_data, meta, cells = _prepare(args)
    except (TuneArgumentError, UnknownMethodError, ConfigError, TrackError) as exc:
        print(f"{PROG}: error: {exc}", file=sys.stderr)
        return 2
    out = Path(args.out)
    from services.tools.tune import study as st

    family = len(cells) > 1
    name = args.study or st.study_name(args.method, "family" if family else meta["track"],
                                       meta["track_fingerprint"])
    storage = args.storage or st.default_storage(out)
    meta |= {"study": name, "storage": storage}
    import optuna

    optuna.logging.set_verbosity(optuna.logging.WARNING)
    try:
        check_out_dir(out, name, storage)
        study = st.open_study(storage, name, meta, args.seed, exclusive=not args.storage)
        st.enqueue_baseline(study, space.baseline(load_config(args.config)))
        limits = _limits(cells, base_data, meta["v_max_mps"])
        for rec, lim in zip(meta["cells"], limits, strict=True):
            rec["limit_s"] = lim
        evaluator = FamilyEvaluator(space, cells, base_data, settings, limits, args.aggregate)
    except (TuneArgumentError, st.StudyMismatchError, ConfigError) as exc:
        print(f"{PROG}: error: {exc}", file=sys.stderr)
        return 2
    done, _ = st.finished_count(study)
    print(f"{PROG}: study {name!r} in {storage}: {done} of {args.trials} trials done; "
          f"{args.laps} lap(s) x seeds {list(settings.seeds)}, margin {settings.margin_m:g} m"
          + (f"; {len(cells)} cells ({', '.join(c.label for c in cells)}), objective the "
             f"{args.aggregate} ratio to the minimum-time lap" if family else ""),
          file=sys.stderr)
    unit = "" if family else " s"
    names = space.names()
    t0 = time.perf_counter()
    stop = st.GracefulStop()
    with stop_signals(stop):
        rep = st.run_trials(study, space, evaluator, args.trials,
                            lambda t: print(_line(t, args.trials, names, unit), file=sys.stderr),
                            stop, say=_say)
        wall = time.perf_counter() - t0
        if rep.interrupted:
            print(f"{PROG}: interrupted; writing what was found", file=sys.stderr)
        code = _write_outputs(study, out, base_data, meta, names)
    print(f"{PROG}: {rep.told} trial(s) here in {wall:.0f} s ({rep.failed} failed)",
          file=sys.stderr)
    return 130 if rep.interrupted else code


def _write_outputs(study: Any, out: Path, base_data: dict, meta: dict, names: list[str]) -> int:
    """Write DIR's files from the storage; 0 when a best.toml was written, 1 otherwise."""
    from services.tools.tune import output
    from services.tools.tune import study as st

    trials = study.get_trials(deepcopy=False)
    best = st.best_trial(study)
    doc = output.trials_document(meta, trials, best, names)
    output.write_history(out, doc, names, trials)
    output.plot_history(out / output.HISTORY_PNG, trials,
                        f"racestack tune: {meta['method']} on {meta['track']} ({meta['study']})",
                        ylabel=output.value_label(meta))
    if best is None:
        print(f"{PROG}: no feasible trial yet; no best.toml (see {out / output.TRIALS_CSV})",
              file=sys.stderr)
        return 1
    output.write_best(out, base_data, best, meta)
    base = [t for t in trials if t.user_attrs.get("baseline") and t.state.name == "COMPLETE"]
    vs = ""
    ratio = len(meta.get("cells", [])) > 1
    unit = "" if ratio else " s"
    if base and base[0].value is not None and base[0].value < PENALTY_S:
        vs = (f" (baseline {base[0].value:.3f}{unit}, "
              f"{100 * (best.value / base[0].value - 1):+.1f} %)")
    what = f"{meta['aggregate']} ratio to the minimum-time lap" if ratio else "mean lap"
    print(f"best: trial {best.number}, {what} {best.value:.3f}{unit}{vs}")
    for cell in best.user_attrs.get("cells", []) if ratio else []:
        print(f"  {cell['track']}/{cell['car']}: mean lap {cell['mean_lap_s']:.3f} s, "
              f"limit {cell['limit_s']:.3f} s, ratio {cell['ratio']:.4f}")
    for k, v in best.params.items():
        print(f"  {k} = {v:.4g}")
    print(f"written: {out / output.BEST}, {out / output.TRIALS_JSON}, "
          f"{out / output.TRIALS_CSV}, {out / output.HISTORY_PNG}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
