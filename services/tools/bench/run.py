"""``racestack bench``: the paper's lap-time experiment, in process, with table and figures.

    racestack bench --track PATH_OR_NAME --laps 17 --methods cimpcc,mpcc,mpcc-tuned --out DIR

Methods: every method of the registry (``shared.config.methods``), the planner's own and the
bench's variants of them:
- a bench variant with ``bench_variant = "sweep"`` (``mpcc-tuned``) races its base method
  with the progress-speed reference swept (v_l ref = 1.1 x v_p ref) over a few laps each;
  then the full run at the fastest value whose laps were all completed with no off-track
  event. The chosen value and the sweep are recorded in results.json;
- one with ``bench_variant = "tuned_file"`` (``cimpcc-tuned``) races its base method with
  ``[planner.cimpcc]`` and ``[curvature]`` of ``--tuned FILE`` (``racestack tune``'s
  best.toml); without it, the configuration's own (said on stderr).

The planners come from one ``PlannerPool``: the MPC methods whose problems have the same
structure share one built (and compiled) problem and solver.

The cars: the planners (and the minimum-time lines they race on) are built for
``[vehicle]``; the simulator races ``cfg.simulator.vehicle``, the same car unless
``[simulator.vehicle]`` overrides it (a model mismatch, said on stderr). results.json's meta
records both (``vehicle``, ``simulator_vehicle``).

Reference: unless ``--no-reference``, the bench first computes (or loads from the cache)
the minimum-time lap of its simulated car on the track (``services.planner.mintime.ocp``, top
speed the planners' ``[planner.cimpcc] v_up_mps[0]``) and reports every method's mean lap
over it (``ratio_to_min_time`` in results.json, the last row of the table): the limit of
the car whose laps it judges.

Pose: ``--estimator`` (truth, ekf, lidar) is the pose the planners see; they are built with
that pose source's settings (``services.planner.for_pose_source``: the raceline's margin
widened by ``[planner.raceline] ekf_margin_m`` / ``lidar_margin_m``, the tube of that
localisation's lateral error, or ``truth_margin_m``, the tracker's own), as the stack's
planner on that ``[localization] pose_source``.
"""

from __future__ import annotations

import argparse
import os
import sys
import threading
import time
from pathlib import Path

import numpy as np

from services.planner import (
    MIN_TIME_LIMIT,
    MinTimeError,
    Planner,
    PlannerLike,
    PlannerPool,
    RacelinePlanner,
    ensure_artefacts,
    for_pose_source,
    limit_request,
    make_min_time_lap,
)
from services.tools.bench.closed_loop import LoopOptions, run_method
from services.tools.bench.estimation import ESTIMATORS
from services.tools.bench.head_to_head import (
    SOURCES,
    HeadToHeadOptions,
    OpponentSpec,
    format_head_to_head,
    run_head_to_head,
)
from services.tools.bench.tuned import TunedCimpcc, load_tuned, tuned_planner
from shared.config import ConfigError, RacestackConfig, load_config
from shared.config.methods import CIMPCC, METHODS, MPCC, bench_methods
from shared.config.planner import MethodWeights
from shared.curvature import track_profile
from shared.evaluation import (
    MethodRun,
    ReferenceLine,
    format_paper_table,
    format_table,
    paper_table_applies,
    reference_document,
    results_document,
    write_figures,
    write_results,
)
from shared.evaluation.plotting import FORMATS, add_figure_formats_argument
from shared.outdir import writable_dir_problem
from shared.service_shell import OneLineArgumentParser, count_problem, positive_int
from shared.track import TRACK_SPEC_HELP, Track, TrackError, load_track

#: The methods ``--methods`` races by default: the paper's two.
DEFAULT_METHODS = (CIMPCC, MPCC)
#: Progress-speed references [m/s] a swept variant tries (v_l ref = 1.1 x v_p ref).
DEFAULT_SWEEP_MPS = (2.2, 2.4, 2.6, 2.8, 3.0, 3.2, 3.4)


class BenchError(ValueError):
    """A bench argument is wrong (reported before anything runs)."""


def parse_methods(text: str) -> list[str]:
    """Split and check the --methods list."""
    names = [m.strip() for m in text.split(",") if m.strip()]
    if not names:
        raise BenchError("no method given")
    unknown = [m for m in names if m not in METHODS]
    if unknown:
        raise BenchError(
            f"unknown method(s) {', '.join(unknown)}; choose from {', '.join(bench_methods())}"
        )
    if len(set(names)) != len(names):
        raise BenchError("a method is listed twice")
    return names


def check_out_dir(path: Path) -> None:
    """Create the output folder and prove it is writable."""
    problem = writable_dir_problem(path)
    if problem:
        raise BenchError(problem)


class ProgressBar:
    """Progress of one method on stderr: the laps done and the distance of the lap being
    driven (the out lap first: the start is just past the line).

    On a terminal one bar is rewritten in place (at most every ``TTY_PERIOD_S``); else
    (a log file, a pipe) a plain line at each completed lap and every ``LINE_PERIOD_S``
    of wall time, so a long lap (Monza: 446 m) is not minutes of silence.
    """

    TTY_PERIOD_S = 0.2
    LINE_PERIOD_S = 10.0

    def __init__(
        self, label: str, stream=None, length_m: float = 0.0, total: int = 0
    ) -> None:
        self.label = label
        self.stream = stream or sys.stderr
        self.tty = bool(getattr(self.stream, "isatty", lambda: False)())
        self.length_m = length_m
        self.t0 = time.perf_counter()
        self._shown = self.t0
        self.done = 0
        self.total = total  #: laps to drive (0: told by the first call)
        self.s_m = 0.0
        self.crossings = 0  #: start-line crossings so far (0: still in the out lap)
        self._s_last: float | None = None
        self._open = False

    def _text(self) -> str:
        width = 30
        filled = int(width * self.done / max(self.total, 1))
        bar = "#" * filled + "." * (width - filled)
        where = ""
        if self.length_m > 0 and self.done < max(self.total, 1):
            lap = "out lap" if self.crossings == 0 else f"lap {self.done + 1}"
            where = f", {lap} {self.s_m:.0f}/{self.length_m:.0f} m"
        return (f"{self.label:<28} [{bar}] {self.done}/{self.total} laps{where} "
                f"{time.perf_counter() - self.t0:5.1f} s")

    def _write(self, end: bool = False) -> None:
        if self.tty:
            self.stream.write("\r\033[K" + self._text() + ("\n" if end else ""))
            self._open = not end
        else:
            self.stream.write(self._text() + "\n")
        self.stream.flush()

    def __call__(self, done: int, total: int) -> None:
        """A lap completed: `done` of `total`."""
        self.done, self.total = done, total
        self.s_m = 0.0  # the next lap starts at the line
        self._shown = time.perf_counter()
        self._write(end=done >= total)

    def at(self, s_m: float) -> None:
        """The car's progress along the centreline now [m] (called every tick)."""
        L = self.length_m
        if self._s_last is not None and L > 0 and s_m < self._s_last - 0.5 * L:
            self.crossings += 1
        self._s_last = self.s_m = s_m
        now = time.perf_counter()
        if now - self._shown >= (self.TTY_PERIOD_S if self.tty else self.LINE_PERIOD_S):
            self._shown = now
            self._write()

    def close(self) -> None:
        """End the line."""
        if self.tty and self._open:
            self.stream.write("\n")
            self.stream.flush()
            self._open = False


class Heartbeat:
    """While a long step runs (IPOPT on the minimum-time lap, building and compiling a
    planner): a line on `stream` every `period_s` [s] of wall time, ``LABEL: still at it,
    20 s``, so a 400 m track's minutes of solving are not minutes of silence; nothing when
    the step ends sooner (a cache hit says nothing). A context manager: the lines come from
    a daemon thread (IPOPT runs in C, the thread gets its turn)."""

    def __init__(self, label: str, stream=None, period_s: float = 10.0) -> None:
        self.label = label
        self.stream = stream or sys.stderr
        self.period_s = period_s
        self.lines = 0  #: lines written so far
        self._done = threading.Event()
        self._thread = threading.Thread(target=self._beat, name="heartbeat", daemon=True)
        self._t0 = 0.0

    def _beat(self) -> None:
        while not self._done.wait(self.period_s):
            self.stream.write(f"{self.label}: still at it, "
                              f"{time.perf_counter() - self._t0:.0f} s\n")
            self.stream.flush()
            self.lines += 1

    def __enter__(self) -> Heartbeat:
        self._t0 = time.perf_counter()
        self._thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self._done.set()
        self._thread.join()

    @property
    def elapsed_s(self) -> float:
        """Wall time since the step started [s]."""
        return time.perf_counter() - self._t0


def _stderr(line: str) -> None:
    """A progress line of the bench (stderr: stdout holds the table)."""
    print(line, file=sys.stderr, flush=True)


class _Watched:
    """A planner that tells a ``ProgressBar`` the progress of every step (all else is the
    planner's own)."""

    def __init__(self, planner: PlannerLike, bar: ProgressBar) -> None:
        object.__setattr__(self, "_planner", planner)
        object.__setattr__(self, "_bar", bar)

    def __getattr__(self, name: str):
        return getattr(self._planner, name)

    def step(self, *args, **kwargs):
        """The planner's ``step``; its result's progress goes to the bar."""
        res = self._planner.step(*args, **kwargs)
        self._bar.at(float(res.s_m))
        return res


def mpcc_weights_for(base: MethodWeights, v_p_ref: float) -> MethodWeights:
    """MPCC weights with the speed references set to (1.1 v_p_ref, 0, v_p_ref)."""
    return base.model_copy(update={"u_ref": (round(1.1 * v_p_ref, 4), 0.0, v_p_ref)})


def sweep_mpcc(
    planner: Planner,
    base: MethodWeights,
    track,
    cfg: RacestackConfig,
    opts: LoopOptions,
    values: list[float],
    sweep_laps: int,
    label: str = "sweep",
) -> tuple[float | None, list[dict]]:
    """Try each progress-speed reference over `base` weights for a few laps; the fastest
    clean one wins."""
    rows = []
    for v in values:
        planner.weights = mpcc_weights_for(base, v)
        bar = ProgressBar(f"{label} sweep v_p={v:.2f}", length_m=track.length_m,
                          total=sweep_laps)
        run = run_method(
            "sweep",
            _Watched(planner, bar),
            track,
            cfg.simulator,
            LoopOptions(**{**opts.__dict__, "laps": sweep_laps}),
            bar,
        )
        if run.completed_laps < sweep_laps:
            bar.close()
        off = sum(lap.off_track_events for lap in run.laps)
        clean = run.completed_laps == sweep_laps and off == 0
        mean = float(np.mean([lap.lap_time_s for lap in run.laps])) if run.laps else None
        rows.append(
            {
                "v_p_ref_mps": v,
                "v_l_ref_mps": round(1.1 * v, 4),
                "completed_laps": run.completed_laps,
                "off_track_events": off,
                "mean_lap_time_s": mean,
                "clean": clean,
            }
        )
    clean_rows = [r for r in rows if r["clean"]]
    if not clean_rows:
        return None, rows
    best = min(clean_rows, key=lambda r: r["mean_lap_time_s"])
    return best["v_p_ref_mps"], rows


def profile_lap_time_s(planner: PlannerLike) -> float:
    """The lap time of the plan a planner follows [s]: its line's speed profile (a method
    on the minimum-time line) or its raceline."""
    if isinstance(planner, RacelinePlanner):
        return float(planner.raceline.lap_time_s)
    return float(planner.reference.speed.lap_time_s)  # type: ignore[attr-defined]


def min_time_reference(
    track: Track, cfg: RacestackConfig, lines: list[ReferenceLine] | None = None,
    ds_m: float | None = None,
) -> dict | None:
    """The ``reference`` of results.json: the minimum-time lap of the simulated car on
    `track` at the planners' top speed (cached per track and car; grid `ds_m` [m], None:
    the default), or None (with a line on stderr) when the track allows none. Its line for
    the figures is appended to `lines` (when given)."""
    try:
        with Heartbeat("minimum-time reference lap") as beat:
            lap = make_min_time_lap(track, *limit_request(cfg.planner, cfg.simulator.vehicle,
                                                          ds_m),
                                    use=MIN_TIME_LIMIT, progress=_stderr)
    except MinTimeError as exc:
        print(f"no minimum-time reference: {exc}", file=sys.stderr)
        return None
    how = ("from the cache" if lap.cache_hit else
           f"solved in {beat.elapsed_s:.0f} s, cached for the next run")
    _stderr(f"minimum-time reference lap on {track.name}: {lap.lap_time_s:.3f} s ({how})")
    if lines is not None:
        s_m, _ = track.project(np.stack([lap.x_m, lap.y_m], axis=1))
        lines.append(ReferenceLine(lap.lap_time_s, np.asarray(lap.x_m), np.asarray(lap.y_m),
                                   np.mod(s_m, track.length_m), np.asarray(lap.v_mps)))
    return reference_document(lap)


def mismatch_note(cfg: RacestackConfig) -> str:
    """One line saying that the simulator races another car than the planners believe."""
    plan, sim = cfg.vehicle, cfg.simulator.vehicle
    differ = [k for k in type(plan).model_fields
              if k != "preset" and getattr(plan, k) != getattr(sim, k)]
    shown = (", ".join(differ[:6]) + (", ..." if len(differ) > 6 else "")) or "the preset"
    return (f"model mismatch: the planners believe [vehicle] (preset {plan.preset}), the "
            f"simulator races [simulator.vehicle] (preset {sim.preset}; differs in {shown}); "
            "the reference is the simulated car's limit")


def run_bench(
    cfg: RacestackConfig,
    track_spec: str,
    methods: list[str],
    laps: int,
    out_dir: Path,
    opts: LoopOptions,
    sweep_values: list[float],
    sweep_laps: int,
    figures: bool = True,
    reference: bool = True,
    tuned: TunedCimpcc | None = None,
    figure_formats: tuple[str, ...] = FORMATS,
) -> dict:
    """Run every method and write results.json and the figures (each in every one of
    `figure_formats`); returns the document.

    With `reference`, the minimum-time lap comes first (``min_time_reference``)."""
    track = load_track(track_spec)
    t_start = time.perf_counter()
    timings: dict[str, float] = {}
    ref_doc = None
    ref_lines: list[ReferenceLine] = []
    if reference:
        ref_doc = min_time_reference(track, cfg, ref_lines)
        timings["min-time reference"] = time.perf_counter() - t_start
    # the planners' settings for the pose they see: the raceline's margin widened by the
    # pose source's tube (``for_pose_source``: [planner.raceline] truth_margin_m,
    # ekf_margin_m, lidar_margin_m)
    settings = for_pose_source(cfg.planner, opts.estimator)
    for name in methods:  # the minimum-time laps the planners read (made once, cached)
        with Heartbeat(f"the minimum-time lap {name} races on"):
            ensure_artefacts(name, track, settings, cfg.vehicle, progress=_stderr)
    pool = PlannerPool(track, cfg.vehicle)  # the planners' car; the simulator races its own
    # built first: a track that allows no line is an error before anything races
    planners = {}
    for name in methods:
        spec = METHODS[name]
        what = "line and planner" if spec.reference != "centreline" else "planner"
        how = " (its compiled problem: once per structure, then from the cache)" if (
            spec.kind == "mpc") else ""
        _stderr(f"building the {what} for {name} on {track.name}{how} ...")
        with Heartbeat(f"building the {what} for {name}"):
            planners[name] = pool.planner(settings, name, cfg.curvature)
    profile = track_profile(track, cfg.curvature)
    runs: list[MethodRun] = []
    for name in methods:
        t0 = time.perf_counter()
        spec = METHODS[name]
        planner: PlannerLike = planners[name]
        extra: dict = {}
        if spec.reference != "centreline":
            extra = {"profile_lap_time_s": round(profile_lap_time_s(planner), 3)}
        if spec.bench_variant == "tuned_file":
            tuned = tuned or load_tuned(None, cfg)
            planner, extra = tuned_planner(pool, cfg, tuned, name), tuned.extra()
        elif spec.bench_variant == "sweep":
            assert isinstance(planner, Planner)
            base_weights = cfg.planner.weights(spec.base)
            chosen, rows = sweep_mpcc(
                planner, base_weights, track, cfg, opts, sweep_values, sweep_laps, name
            )
            timings[f"{name} sweep"] = time.perf_counter() - t0
            extra = {"sweep": rows, "sweep_laps": sweep_laps, "chosen_v_p_ref_mps": chosen}
            if chosen is None:
                print(
                    f"{name}: no swept value stayed clean; running the slowest one",
                    file=sys.stderr,
                )
                chosen = min(sweep_values)
            planner.weights = mpcc_weights_for(base_weights, chosen)
            extra["u_ref"] = list(planner.weights.u_ref)
            t0 = time.perf_counter()
        bar = ProgressBar(name, length_m=track.length_m, total=laps)
        run = run_method(
            name, _Watched(planner, bar), track, cfg.simulator,
            LoopOptions(**{**opts.__dict__, "laps": laps}), bar
        )
        if run.completed_laps < laps:
            bar.close()
            print(
                f"{name}: {run.completed_laps}/{laps} laps ({run.extra.get('aborted', '')})",
                file=sys.stderr,
            )
        run.extra.update(extra)
        runs.append(run)
        timings[name] = time.perf_counter() - t0
    meta = {
        "laps_requested": laps,
        "delay_mode": opts.delay_mode,
        "compute_delay_s": opts.compute_delay_s,
        "planner_dt_s": cfg.planner.dt_s,
        "horizon_steps": cfg.planner.horizon_steps,
        "vehicle": cfg.vehicle.model_dump(),
        "simulator_vehicle": cfg.simulator.vehicle.model_dump(),
        "wall_time_s": {k: round(v, 2) for k, v in timings.items()},
        "wall_time_total_s": round(time.perf_counter() - t_start, 2),
        "track_source": track.source,
    }
    doc = results_document(track.name, track.length_m, runs, meta, reference=ref_doc)
    write_results(out_dir / "results.json", doc)
    if figures:
        write_figures(out_dir, track, profile, runs,
                      reference=ref_lines[0] if ref_lines else None,
                      formats=figure_formats, planner_period_s=cfg.planner.dt_s)
    return doc


def build_parser(ap: argparse.ArgumentParser | None = None) -> argparse.ArgumentParser:
    """Arguments of ``racestack bench``."""
    ap = ap or OneLineArgumentParser(prog="racestack bench",
                                     description=__doc__.splitlines()[0])
    ap.add_argument("--config", help="TOML configuration file (default: the built-in "
                    "configuration)")
    ap.add_argument(
        "--track", help=f"{TRACK_SPEC_HELP} (default: the config's [track] source)"
    )
    ap.add_argument(
        "--laps", type=positive_int, default=17,
        help="timed flying laps per method, after an untimed out lap (a whole number >= 1; "
        "default 17, the paper's)",
    )
    ap.add_argument(
        "--methods", default=",".join(DEFAULT_METHODS),
        help=f"the methods to race, a comma list of {', '.join(bench_methods())} (default "
        f"{','.join(DEFAULT_METHODS)})",
    )
    ap.add_argument("--out", default=None, help="output folder (default runs/bench-<time>)")
    ap.add_argument(
        "--delay",
        choices=["fixed", "measured"],
        default="fixed",
        help="compute delay before a command acts: fixed (default) or measured",
    )
    ap.add_argument(
        "--compute-delay-ms",
        type=float,
        default=2.0,
        help="with --delay fixed: how long the previous command still acts after each "
        "planner tick [ms] (0 .. the planner period; default 2)",
    )
    ap.add_argument(
        "--sweep",
        default=",".join(f"{v:g}" for v in DEFAULT_SWEEP_MPS),
        help="a swept variant (mpcc-tuned): progress-speed references to try [m/s], a comma "
        "list (default %(default)s)",
    )
    ap.add_argument(
        "--sweep-laps", type=positive_int, default=3,
        help="a swept variant (mpcc-tuned): laps raced at each swept value before the full "
        "run (a whole number >= 1; default 3)",
    )
    ap.add_argument("--tuned", metavar="FILE",
                    help="cimpcc-tuned: a tuned configuration (racestack tune's best.toml); "
                    "default: the configuration's own [planner.cimpcc]")
    ap.add_argument(
        "--no-figures", action="store_true",
        help="write results.json only, no figures (default: the paper's figures too, in "
        "--figure-formats)"
    )
    add_figure_formats_argument(ap)
    ap.add_argument(
        "--no-reference",
        action="store_true",
        help="skip the minimum-time reference lap (solved once per track and car, cached; "
        "default: race against it, the table's min-time ratio)",
    )
    ap.add_argument(
        "--estimator",
        choices=list(ESTIMATORS),
        default="truth",
        help="the pose the planner sees: truth (default), ekf (the simulator's pose sensor, "
        "IMU and odometry through the bridge's EKF) or lidar (its lidar through the particle "
        "filter into the EKF)",
    )
    ap.add_argument(
        "--opponent", metavar="METHOD[:SPEED_SCALE]", default=None,
        help="head to head: race each method against an opponent car, e.g. raceline:0.85 "
        "(its line's speed profile scaled; a scale needs a line-tracking method), over "
        "--seeds random start gaps; --laps is then the laps each start races (default: "
        "none, the solo bench)",
    )
    ap.add_argument(
        "--seeds", type=positive_int, default=10,
        help="head to head: seeded starts per method (a whole number >= 1; default 10)",
    )
    ap.add_argument(
        "--opponent-source", choices=list(SOURCES), default="truth",
        help="head to head: the ego sees the opponent from the simulator's truth (default) "
        "or from the tracker on its simulated lidar (lidar)",
    )
    ap.add_argument(
        "--opponent-aware", action="store_true",
        help="head to head: the opponent also plans around the ego when its method can "
        "(default: it races its line blind)",
    )
    return ap


def main_head_to_head(args: argparse.Namespace, cfg: RacestackConfig, methods: list[str],
                      track_spec: str, out: Path) -> int:
    """``--opponent``: the head-to-head races, their table and results.json."""
    try:
        spec = OpponentSpec.parse(args.opponent)
        if spec.method not in METHODS:
            raise BenchError(f"unknown --opponent method {spec.method}; choose from "
                             f"{', '.join(bench_methods())}")
    except ValueError as exc:
        print(f"racestack bench: error: {exc}", file=sys.stderr)
        return 2
    opts = HeadToHeadOptions(
        laps=args.laps, seeds=args.seeds, source=args.opponent_source,
        opponent_aware=args.opponent_aware, compute_delay_s=args.compute_delay_ms / 1e3,
    )
    track = load_track(track_spec)
    t0 = time.perf_counter()
    try:
        doc = run_head_to_head(cfg, track, methods, spec, opts, progress=_stderr)
    except (ValueError, TrackError) as exc:
        print(f"racestack bench: error: {exc}", file=sys.stderr)
        return 2
    results = {
        "track": track.name,
        "track_length_m": track.length_m,
        "opponent": {"method": spec.method, "speed_scale": spec.speed_scale},
        "options": {k: v for k, v in opts.__dict__.items()},
        "head_to_head": doc,
        "wall_time_s": round(time.perf_counter() - t0, 2),
    }
    write_results(out / "results.json", results)
    print(format_head_to_head(track.name, spec, doc, opts.laps))
    print(f"results: {out / 'results.json'}")
    return 0


def main(argv: list[str] | None = None, args: argparse.Namespace | None = None) -> int:
    """Run the bench from the command line; exit code 0 on success, 2 on bad arguments."""
    if args is None:
        try:  # a usage error (e.g. --laps 0) is the parser's one line and exit code 2
            args = build_parser().parse_args(argv)
        except SystemExit as exc:
            return exc.code if isinstance(exc.code, int) else 2
    try:
        cfg = load_config(args.config)
        methods = parse_methods(args.methods)
        for option, value in (("--laps", args.laps), ("--sweep-laps", args.sweep_laps)):
            problem = count_problem(option, value)
            if problem:
                raise BenchError(problem)
        if not 0.0 <= args.compute_delay_ms <= 1e3 * cfg.planner.dt_s:
            raise BenchError(f"--compute-delay-ms must be in [0, {1e3 * cfg.planner.dt_s:g}]")
        try:
            sweep = [float(v) for v in args.sweep.split(",") if v.strip()]
        except ValueError:
            raise BenchError(f"--sweep must be numbers, got {args.sweep!r}") from None
        if not sweep and any(METHODS[m].bench_variant == "sweep" for m in methods):
            raise BenchError("--sweep is empty")
        track_spec = args.track or cfg.track.source
        load_track(track_spec)  # a wrong track fails here, before anything runs
        out = Path(args.out or Path("runs") / time.strftime("bench-%Y%m%d-%H%M%S"))
        check_out_dir(out)
        tuned = (
            load_tuned(args.tuned, cfg)
            if any(METHODS[m].bench_variant == "tuned_file" for m in methods)
            else None
        )
    except (BenchError, ConfigError, TrackError) as exc:
        print(f"racestack bench: error: {exc}", file=sys.stderr)
        return 2
    if getattr(args, "opponent", None):
        return main_head_to_head(args, cfg, methods, track_spec, out)
    if tuned is not None:
        print(tuned.describe(), file=sys.stderr)
    if cfg.simulates_another_car:
        print(mismatch_note(cfg), file=sys.stderr)
    opts = LoopOptions(
        laps=args.laps, delay_mode=args.delay, compute_delay_s=args.compute_delay_ms / 1e3,
        estimator=getattr(args, "estimator", "truth"), localization=cfg.localization,
    )
    try:
        doc = run_bench(
            cfg,
            track_spec,
            methods,
            args.laps,
            out,
            opts,
            sweep,
            args.sweep_laps,
            figures=not args.no_figures,
            reference=not args.no_reference,
            tuned=tuned,
            figure_formats=getattr(args, "figure_formats", FORMATS),
        )
    except TrackError as exc:  # e.g. no raceline on this track (raised before any race)
        print(f"racestack bench: error: {exc}", file=sys.stderr)
        return 2
    print(format_table(doc))
    if paper_table_applies(doc["track"]):  # the paper's numbers are of map416 only
        print()
        print(format_paper_table())
    wall = doc["meta"]["wall_time_s"]
    print("\nwall time: " + ", ".join(f"{k} {v:.1f} s" for k, v in wall.items()))
    for name, m in doc["methods"].items():
        if "chosen_v_p_ref_mps" in m:
            print(
                f"{name}: chosen v_p ref {m['chosen_v_p_ref_mps']} m/s "
                f"(u_ref {m['u_ref']}) from a {m['sweep_laps']}-lap sweep"
            )
    for name, m in doc["methods"].items():
        if loc := m.get("localisation"):
            print(
                f"localisation {name} ({loc['estimator']}): position RMS "
                f"{100 * (loc['rms_position_m'] or 0):.2f} cm, max "
                f"{100 * (loc['max_position_m'] or 0):.2f} cm, lateral RMS / p95 / p99 "
                f"{100 * (loc.get('rms_lateral_m') or 0):.2f} / "
                f"{100 * (loc.get('p95_lateral_m') or 0):.2f} / "
                f"{100 * (loc.get('p99_lateral_m') or 0):.2f} cm, yaw RMS "
                f"{loc['rms_yaw_deg'] or 0:.2f} deg, invalid ticks {loc['invalid_ticks']}"
            )
    print(f"results: {out / 'results.json'}" + ("" if args.no_figures else f", figures in {out}"))
    return 0


if __name__ == "__main__":
    os.environ.setdefault("MPLBACKEND", "Agg")
    sys.exit(main())
