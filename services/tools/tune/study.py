"""The Optuna study of ``racestack tune``: storage, identity checks, and the trial loop.

Storage: an RDB URL, by default ``sqlite:///DIR/study.db``; several processes (or machines,
with a server database) given the same ``--storage`` share one study and its trial budget.

Identity: the study's name encodes the method and the track (``cimpcc@paperlike-1a2b3c4d``:
the track's name and a hash of its geometry; a family of several cells
``cimpcc@family-1a2b3c4d``, a hash of its tracks and cars), and the study records what its
values mean (method, tracks, cars, aggregate, constraints, laps, seeds, margin, noise, top
speed, base configuration). Resuming a study
with anything else is a ``StudyMismatchError`` (the values would not be comparable), and so
is a default study file in DIR that already holds the study of another method or track.

The loop (``run_trials``) uses Optuna's ask-and-tell interface: a trial whose evaluation
raises is told FAILED with its error text as the user attribute ``error`` (one line on the
log, never a traceback); Ctrl-C (or SIGTERM, turned into KeyboardInterrupt by the command)
tells the running trial FAILED with ``interrupted`` set and ends the loop (``GracefulStop``:
a signal outside a race waits for the storage write in progress). ``--trials N`` is
the study's budget: the loop stops once N trials finished (COMPLETE, or FAILED other than
by an interruption), counting every process's trials.
"""

from __future__ import annotations

import logging
import os
import socket
import time
import warnings
from collections.abc import Callable, Iterator, Mapping
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import optuna
from optuna.exceptions import UpdateFinishedTrialError
from optuna.trial import FrozenTrial, TrialState

from services.tools.tune.evaluate import TrialOutcome
from services.tools.tune.search import CONSTRAINTS, Params, SearchSpace, dotted

#: The study user attribute holding what the study's values mean.
META_KEY = "racestack_tune"
#: Keys of that record a resume must match.
IDENTITY_KEYS = ("method", "track", "track_fingerprint", "cars", "aggregate", "constraints",
                 "objective", "v_max_mps", "config")
#: TPE's random start-up trials (Optuna's default) before it models the history.
STARTUP_TRIALS = 10
#: Seconds a SQLite writer waits for another process's lock.
SQLITE_TIMEOUT_S = 60.0
#: Times a worker retries opening a storage whose tables another worker is creating.
SCHEMA_RACE_RETRIES = 5
#: Longest wait [s] of a worker whose budget is met for trials other workers still race (a
#: worker that died leaves its trial RUNNING for ever: the wait gives up then).
WAIT_FOR_OTHERS_S = 900.0
#: Seconds between two looks at the other workers' running trials.
WAIT_POLL_S = 1.0

log = logging.getLogger("racestack.tune")


class StudyMismatchError(ValueError):
    """The storage or study belongs to another method, track or objective."""


def default_storage(out_dir: Path) -> str:
    """``sqlite:///DIR/study.db`` (absolute path)."""
    return f"sqlite:///{(out_dir / 'study.db').resolve()}"


def study_name(method: str, track_name: str, track_fingerprint: str) -> str:
    """The study's name: method and track (``cimpcc@paperlike-1a2b3c4d``; a family's
    `track_name` is ``family``)."""
    return f"{method}@{track_name}-{track_fingerprint}"


def make_storage(url: str) -> optuna.storages.RDBStorage:
    """An RDB storage; SQLite waits for other processes' locks instead of failing."""
    kwargs: dict[str, Any] = {}
    if url.startswith("sqlite"):
        kwargs = {"connect_args": {"timeout": SQLITE_TIMEOUT_S}}
    for attempt in range(SCHEMA_RACE_RETRIES + 1):
        try:
            return optuna.storages.RDBStorage(url, engine_kwargs=kwargs)
        except Exception as exc:  # SQLAlchemy raises many kinds for a bad URL or database
            if attempt < SCHEMA_RACE_RETRIES and _schema_race(exc):
                # two workers started together both create the tables; the loser retries
                # and finds the tables the other one made
                time.sleep(0.2 * (attempt + 1))
                continue
            raise StudyMismatchError(f"cannot open storage {url!r}: {_one_line(exc)}") from None
    raise AssertionError("unreachable")


def _schema_race(exc: BaseException) -> bool:
    """The error of a worker that lost the race to create a new database's tables."""
    text = str(exc).lower()
    # SQLite: "table ... already exists", "database is locked", and the alembic version
    # row both workers insert: "UNIQUE constraint failed: alembic_version.version_num"
    return any(k in text for k in ("already exists", "duplicate", "locked", "unique constraint"))


def _one_line(exc: BaseException) -> str:
    text = str(exc).strip().splitlines()
    return f"{type(exc).__name__}: {text[0] if text else ''}".rstrip(": ")


def _describe(meta: Mapping[str, Any]) -> str:
    obj = meta.get("objective", {})
    return (
        f"method {meta.get('method')}, track {meta.get('track')} "
        f"({meta.get('track_fingerprint')}), cars {meta.get('cars')}, laps {obj.get('laps')}, "
        f"seeds {obj.get('seeds')}"
    )


def check_identity(name: str, found: Mapping[str, Any] | None, wanted: Mapping[str, Any]) -> None:
    """StudyMismatchError when the study `name` was made for something else."""
    if found is None:
        raise StudyMismatchError(
            f"study {name!r} was not made by racestack tune; choose another --study or --out"
        )
    diff = [k for k in IDENTITY_KEYS if found.get(k) != wanted.get(k)]
    if diff:
        raise StudyMismatchError(
            f"study {name!r} was made for {_describe(found)}, not {_describe(wanted)} "
            f"(differs in: {', '.join(diff)}); resume it with its own settings, or use "
            "another --out / --study"
        )


def open_study(
    storage_url: str,
    name: str,
    meta: Mapping[str, Any],
    seed: int,
    exclusive: bool,
) -> optuna.Study:
    """Create or resume the study `name`, checking that it is the same tuning.

    Args:
        storage_url: RDB URL.
        name: the study's name.
        meta: what the study's values mean (``META_KEY``; compared on IDENTITY_KEYS).
        seed: the sampler's seed (``sampler_seed`` mixes in the trials already there).
        exclusive: the storage belongs to this tuning alone (the default file in DIR): any
            other study in it is an error.
    """
    storage = make_storage(storage_url)
    summaries = {s.study_name: s for s in optuna.get_all_study_summaries(storage)}
    n0 = 0
    if name in summaries:
        found = summaries[name].user_attrs.get(META_KEY)
        n0 = summaries[name].n_trials
        if found is not None or n0:  # else: another worker is creating it right now
            check_identity(name, found, meta)
    elif exclusive and summaries:
        other, summary = next(iter(summaries.items()))
        found = summary.user_attrs.get(META_KEY) or {}
        raise StudyMismatchError(
            f"{storage_url} holds the study {other!r} ({_describe(found)}), not one for "
            f"{_describe(meta)}; use another --out (or --storage)"
        )
    study = optuna.create_study(
        storage=storage,
        study_name=name,
        sampler=make_sampler(sampler_seed(seed, n0)),
        direction="minimize",
        load_if_exists=True,
    )
    if META_KEY not in study.user_attrs:
        study.set_user_attr(META_KEY, dict(meta))
    # two workers creating the study at once both set the record: the last one stays, and
    # whichever of them does not match it fails here
    check_identity(name, study.user_attrs.get(META_KEY), meta)
    return study


def make_sampler(seed: int) -> optuna.samplers.TPESampler:
    """Seeded multivariate TPE (constant liar for parallel workers); it ranks infeasible
    trials (``Trial.set_constraint``) behind feasible ones, by how much they violate."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", optuna.exceptions.ExperimentalWarning)
        return optuna.samplers.TPESampler(
            seed=seed, n_startup_trials=STARTUP_TRIALS, multivariate=True, constant_liar=True
        )


def sampler_seed(seed: int, trials_so_far: int) -> int:
    """The sampler's seed: `seed` for a fresh study, another one per resume point (so a
    resumed study does not redraw the random start-up points it already tried)."""
    return (seed * 1_000_003 + trials_so_far) % (2**31 - 1)


def enqueue_baseline(study: optuna.Study, params: Params) -> None:
    """Queue the configuration's own point as the first trial (once)."""
    if not study.get_trials(deepcopy=False):
        study.enqueue_trial(dict(params), user_attrs={"baseline": True}, skip_if_exists=True)


def interrupted(t: FrozenTrial) -> bool:
    """A trial stopped by Ctrl-C (does not count towards the budget)."""
    return t.state == TrialState.FAIL and bool(t.user_attrs.get("interrupted"))


def finished_count(study: optuna.Study) -> tuple[int, int]:
    """(finished trials, trials running in some process)."""
    trials = study.get_trials(deepcopy=False)
    done = sum(
        1
        for t in trials
        if t.state in (TrialState.COMPLETE, TrialState.PRUNED)
        or (t.state == TrialState.FAIL and not interrupted(t))
    )
    running = sum(1 for t in trials if t.state == TrialState.RUNNING)
    return done, running


def worker_id() -> str:
    """host:pid of this process."""
    return f"{socket.gethostname()}:{os.getpid()}"


@dataclass
class LoopReport:
    """What this process did."""

    told: int = 0
    failed: int = 0
    interrupted: bool = False
    #: trials another worker had finished first (a queued trial popped twice)
    duplicates: int = 0


class GracefulStop:
    """Ctrl-C / SIGTERM for the trial loop (``handler`` is the signal handler).

    Inside a trial's race the signal raises KeyboardInterrupt at once (the race is plain
    computation); anywhere else, e.g. while the storage is written, it only sets
    ``requested``, which the loop checks before the next trial, so no database transaction
    is ever cut in half.
    """

    def __init__(self) -> None:
        self.requested = False
        self._racing = False

    def handler(self, _signum: int, _frame: object) -> None:
        """Request the stop; interrupt the race if one is running."""
        self.requested = True
        if self._racing:
            raise KeyboardInterrupt

    @contextmanager
    def racing(self) -> Iterator[None]:
        """The span in which a signal interrupts at once."""
        self._racing = True
        try:
            yield
        finally:
            self._racing = False


Evaluate = Callable[[Params], TrialOutcome]
Report = Callable[[FrozenTrial], None]


def suggest(trial: optuna.Trial, space: SearchSpace) -> dict[str, float]:
    """The trial's point in the space."""
    return {p.name: trial.suggest_float(p.name, p.low, p.high, log=p.log) for p in space.params}


def _tell_outcome(
    study: optuna.Study, trial: optuna.Trial, space: SearchSpace, out: TrialOutcome
) -> FrozenTrial:
    sc = out.score
    for key, value in zip(CONSTRAINTS, sc.constraints, strict=True):
        trial.set_constraint(key, value)
    trial.set_user_attr("feasible", sc.feasible)
    trial.set_user_attr("reasons", list(sc.reasons))
    trial.set_user_attr("mean_lap_s", sc.mean_lap_s)
    trial.set_user_attr("seeds", [r.to_json() for r in out.seeds])
    trial.set_user_attr("overlay", out.overlay)
    trial.set_user_attr("tuned_keys", dotted(space.overlay(trial.params)))
    trial.set_user_attr("details", out.details)
    if out.cells:
        trial.set_user_attr("cells", list(out.cells))
    return study.tell(trial, sc.value)


def _run_one(
    study: optuna.Study,
    trial: optuna.Trial,
    space: SearchSpace,
    evaluate: Evaluate,
    stop: GracefulStop,
    me: str,
    rep: LoopReport,
) -> tuple[FrozenTrial | None, bool]:
    """Evaluate and tell one asked trial; (its frozen record, whether a stop interrupted it)."""
    trial.set_user_attr("worker", me)
    params = suggest(trial, space)
    t0 = time.perf_counter()
    try:
        with stop.racing():
            out = evaluate(params)
    except KeyboardInterrupt:
        trial.set_user_attr("error", "interrupted")
        trial.set_user_attr("interrupted", True)
        study.tell(trial, state=TrialState.FAIL)
        rep.interrupted = True
        return None, True
    except Exception as exc:  # a crashing trial is a FAILED trial, not a crash
        trial.set_user_attr("wall_s", round(time.perf_counter() - t0, 3))
        trial.set_user_attr("error", _one_line(exc))
        frozen = study.tell(trial, state=TrialState.FAIL)
        rep.failed += 1
        return frozen, False
    trial.set_user_attr("wall_s", round(time.perf_counter() - t0, 3))
    return _tell_outcome(study, trial, space, out), False


def run_trials(
    study: optuna.Study,
    space: SearchSpace,
    evaluate: Evaluate,
    budget: int,
    report: Report | None = None,
    stop: GracefulStop | None = None,
    wait_s: float = WAIT_FOR_OTHERS_S,
    say: Callable[[str], None] | None = None,
) -> LoopReport:
    """Ask, evaluate and tell trials until the study has `budget` finished ones, or a stop
    (KeyboardInterrupt from `evaluate`, or `stop` requested). Once the budget is taken,
    the trials other workers still race are waited for (at most `wait_s`, ``wait_for_others``),
    so that this worker's outputs hold the whole study."""
    rep = LoopReport()
    me = worker_id()
    stop = stop or GracefulStop()
    while not stop.requested:
        done, running = finished_count(study)
        if done + running >= budget:
            wait_for_others(study, running, stop, wait_s, say)
            break
        trial = study.ask()
        try:
            frozen, stopped = _run_one(study, trial, space, evaluate, stop, me, rep)
        except UpdateFinishedTrialError:
            # two workers popped the same queued trial (SQLite has no row locks): the
            # other one finished it first; this result is dropped, nothing is lost
            rep.duplicates += 1
            continue
        if stopped:
            break
        rep.told += 1
        if report is not None:
            report(frozen)
    rep.interrupted = rep.interrupted or stop.requested
    return rep


def wait_for_others(
    study: optuna.Study, running: int, stop: GracefulStop, wait_s: float,
    say: Callable[[str], None] | None = None,
) -> int:
    """Wait until no trial of the study is RUNNING (other workers' trials), `wait_s` passed
    or a stop is requested; the number still running then (one line via `say` first)."""
    if running and say is not None:
        say(f"the budget is taken; waiting for {running} trial(s) of other workers "
            f"(at most {wait_s:.0f} s)")
    deadline = time.monotonic() + wait_s
    while running and not stop.requested and time.monotonic() < deadline:
        time.sleep(WAIT_POLL_S)
        running = finished_count(study)[1]
    return running


def best_trial(study: optuna.Study) -> FrozenTrial | None:
    """The fastest feasible complete trial, or None."""
    good = [
        t
        for t in study.get_trials(deepcopy=False, states=(TrialState.COMPLETE,))
        if t.user_attrs.get("feasible") and t.value is not None
    ]
    return min(good, key=lambda t: (t.value, t.number)) if good else None
