"""Read a telemetry recording back: the bench's lap table and figures of a recorded run.

``racestack report RUN.rrd`` (or the run folder) prints the lap table of the run
(``shared.evaluation.format_table`` on a ``results_document`` built from the recorded
lap events) and writes ``results.json`` plus the bench's figures (``shared.evaluation``)
into ``<run folder>/report/`` (``--out DIR``), so a race on the real car is analysed like a
bench run. The track comes from ``--track``, else from the recording's static
``meta/track`` source, else from the recorded centreline and boundaries themselves.

The trace has one row per recorded plan (else per state, else per truth sample); position,
speed, progress and contour error come from the simulator truth when recorded, else from
the state and the plan (or a projection on the track).
"""

from __future__ import annotations

import math
import sys
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc

from services.telemetry import SIM_TIME, WALL_TIME, find_segments, read_store
from shared.config import ConfigError, RacestackConfig, load_config
from shared.config.methods import METHODS
from shared.curvature import CurvatureProfile, track_profile
from shared.evaluation import (
    LapRecord,
    MethodRun,
    Trace,
    format_table,
    reference_document,
    results_document,
    write_figures,
    write_results,
)
from shared.evaluation.plotting import add_figure_formats_argument
from shared.extras import MissingExtraError, require
from shared.outdir import missing_dirs, remove_empty_dirs, writable_dir_problem
from shared.service_shell import OneLineArgumentParser, plain_help
from shared.track import TRACK_SPEC_HELP, Track, TrackError, load_track

_ROW_ID = "rerun.controls.RowId"
_SCALARS = "Scalars:scalars"
#: Temporal entities (path prefixes) whose rows (AnyValues fields, text logs) are read.
ROW_ENTITIES = ("events/", "plan/info")


@dataclass
class RecordingData:
    """What the report needs from a recording.

    Attributes:
        path: the ``.rrd`` file (the first segment of a segmented recording).
        segments: every file read, in order (one for a single-file recording).
        series: entity -> (t [s], values), sorted by t (scalar series).
        rows: entity -> rows (dicts of field -> value, plus ``t_s`` [s]) of ``ROW_ENTITIES``
            (text logs under ``TextLog:text`` / ``TextLog:level``).
        static: entity -> field -> value of the static entities (line strips as arrays).
        timelines: the message timelines found (``sim_time`` and/or ``wall_time``).
        complete: False when a file has no footer (the recorder did not close it).
    """

    path: Path
    segments: list[Path] = field(default_factory=list)
    series: dict[str, tuple[np.ndarray, np.ndarray]] = field(default_factory=dict)
    rows: dict[str, list[dict[str, Any]]] = field(default_factory=dict)
    static: dict[str, dict[str, Any]] = field(default_factory=dict)
    timelines: set[str] = field(default_factory=set)
    complete: bool = True  #: False: no footer (the recorder was killed; read up to the cut)


def find_recording(path: str | Path) -> Path:
    """The first ``.rrd`` of the recording `path` names (``rrd_files.find_segments``: a
    file, a run folder, or the ``<stem>.rrd`` of a segmented run). FileNotFoundError if
    there is none."""
    return find_segments(path)[0]


def _cell(v: Any) -> Any:
    """The single value of an AnyValues / component cell (a one-element list)."""
    if isinstance(v, list):
        v = v[0] if len(v) == 1 else v
    if isinstance(v, float) and math.isnan(v):
        return None
    return v


def read_recording(path: str | Path) -> RecordingData:
    """Read the scalar series, the event rows and the static data of a recording: every
    segment of a segmented run, in order, as one recording.

    Reads with ``rr.chunk.RrdReader`` (streams: a segment cut short by a crash reads up
    to its last complete chunk, ``rrd_files.read_store``).
    """
    segments = find_segments(path)
    data = RecordingData(path=segments[0], segments=segments)
    series: dict[str, tuple[list[np.ndarray], list[np.ndarray]]] = {}
    rows: dict[str, list[tuple[float, dict[str, Any]]]] = {}
    for segment in segments:
        store, complete = read_store(segment)
        data.complete = data.complete and complete
        _read_chunks(store, data, series, rows)
    for entity, (ts, vs) in series.items():
        t = np.concatenate(ts)
        v = np.concatenate(vs)
        order = np.argsort(t, kind="stable")
        data.series[entity] = (t[order], v[order])
    for entity, items in rows.items():
        items.sort(key=lambda it: it[0])
        data.rows[entity] = [{**row, "t_s": t} for t, row in items]
    return data


def _read_chunks(
    store: Any,
    data: RecordingData,
    series: dict[str, tuple[list[np.ndarray], list[np.ndarray]]],
    rows: dict[str, list[tuple[float, dict[str, Any]]]],
) -> None:
    """Add the chunks of one file's `store` to `data` (static), `series` and `rows`."""
    for chunk in store.stream():
        entity = chunk.entity_path.lstrip("/")
        rb = chunk.to_record_batch()
        names = rb.schema.names
        tl = next((n for n in (SIM_TIME, WALL_TIME) if n in names), None)
        if tl is None:
            if chunk.is_static or not any(n in names for n in ("log_time", "log_tick")):
                entry = data.static.setdefault(entity, {})
                for name in names:
                    if name == _ROW_ID:
                        continue
                    cells = [c for c in rb.column(name).to_pylist() if c is not None]
                    if cells:
                        entry[name] = cells[-1]
            continue
        data.timelines.add(tl)
        t = rb.column(tl).cast(pa.int64()).to_numpy(zero_copy_only=False) / 1e9
        if _SCALARS in names:
            col = rb.column(_SCALARS)
            first = pc.list_element(pc.fill_null(col, pa.scalar([float("nan")], col.type)), 0)
            v = first.to_numpy(zero_copy_only=False).astype(float)
            keep = np.isfinite(v)
            if keep.any():
                ts, vs = series.setdefault(entity, ([], []))
                ts.append(t[keep])
                vs.append(v[keep])
        if entity.startswith(ROW_ENTITIES):
            fields = [n for n in names if n != _ROW_ID and n != tl and not n.startswith("log_")]
            cols = {n: rb.column(n).to_pylist() for n in fields}
            out = rows.setdefault(entity, [])
            for i in range(rb.num_rows):
                row = {n: _cell(cols[n][i]) for n in fields if cols[n][i] is not None}
                if row:
                    out.append((float(t[i]), row))


def _strip(data: RecordingData, entity: str) -> np.ndarray | None:
    cell = data.static.get(entity, {}).get("LineStrips2D:strips")
    if not cell:
        return None
    pts = np.asarray(cell[0], dtype=float)
    if len(pts) > 1 and np.allclose(pts[0], pts[-1]):
        pts = pts[:-1]
    return pts


def track_from_recording(data: RecordingData) -> Track:
    """The track of the recording's static centreline and boundaries (TrackError if absent)."""
    centre = _strip(data, "world/track/centerline")
    left = _strip(data, "world/track/left")
    right = _strip(data, "world/track/right")
    meta = data.static.get("meta/track", {})
    name = str(_cell(meta.get("name")) or "recorded")
    if centre is None or left is None or right is None:
        raise TrackError(str(data.path), "the recording has no static track geometry")
    return Track(
        name=name,
        xy=centre,
        w_right_m=np.linalg.norm(right - centre, axis=1),
        w_left_m=np.linalg.norm(left - centre, axis=1),
        source=f"{data.path}#world/track",
    )


def track_of(data: RecordingData, spec: str | None = None) -> Track:
    """The track: `spec` if given, else the recorded source, else the recorded geometry."""
    if spec:
        return load_track(spec)
    source = _cell(data.static.get("meta/track", {}).get("source"))
    if source:
        try:
            return load_track(str(source))
        except TrackError:
            pass
    return track_from_recording(data)


def _at(data: RecordingData, entity: str, t: np.ndarray) -> np.ndarray | None:
    """Latest-at values of `entity` at times `t` (the first value before it starts)."""
    if entity not in data.series:
        return None
    ts, vs = data.series[entity]
    idx = np.clip(np.searchsorted(ts, t, side="right") - 1, 0, len(ts) - 1)
    return vs[idx]


def lap_events(data: RecordingData) -> list[dict[str, Any]]:
    """The recorded lap events (kind, lap, lap_time_s, ..., t_s), in time order."""
    return [r for r in data.rows.get("events/lap", []) if "kind" in r]


def method_run(data: RecordingData, track: Track, profile: CurvatureProfile) -> MethodRun:
    """A bench ``MethodRun`` (laps, trace, solve times) of the recorded run."""
    L = track.length_m
    base = next((e for e in ("plan/s_m", "state/x_m", "truth/x_m") if e in data.series), None)
    t = data.series[base][0] if base else np.zeros(0)
    truth = "truth/x_m" in data.series
    src = ("truth/x_m", "truth/y_m", "speed/truth") if truth else (
        "state/x_m", "state/y_m", "speed/measured")
    nan = np.full(t.shape, np.nan)
    x = _at(data, src[0], t)
    y = _at(data, src[1], t)
    speed = _at(data, src[2], t)
    x = nan if x is None else x
    y = nan if y is None else y
    speed = nan if speed is None else speed
    s = _at(data, "truth/s_m", t) if truth else _at(data, "plan/s_m", t)
    e = _at(data, "track_error/e_con_truth", t) if truth else _at(data, "track_error/e_con", t)
    if (s is None or e is None) and t.size and np.isfinite(x).all() and np.isfinite(y).all():
        s_p, e_p = track.project(np.stack([x, y], axis=1))
        s = s_p if s is None else s
        e = e_p if e is None else e
    s = nan if s is None else np.mod(s, L)
    e = nan if e is None else e
    beta = _at(data, "beta/beta", t)
    if beta is None:
        beta = np.asarray(profile.beta_at(s)) if np.isfinite(s).all() else nan
    cmd = _at(data, "speed/commanded", t)
    cmd = nan if cmd is None else cmd
    events = lap_events(data)
    marks = [(ev["t_s"], int(ev.get("lap", 0)) + 1) for ev in events
             if ev["kind"] in ("start", "lap")]
    lap_idx = np.zeros(t.shape, dtype=int)
    if marks:
        mt = np.array([m[0] for m in marks])
        mv = np.array([m[1] for m in marks])
        k = np.searchsorted(mt, t, side="right") - 1
        lap_idx = np.where(k >= 0, mv[np.clip(k, 0, None)], 0)
    t0 = float(t[0]) if t.size else 0.0
    trace = Trace(
        t_s=(t - t0).tolist(), s_m=s.tolist(), x_m=x.tolist(), y_m=y.tolist(),
        speed_mps=speed.tolist(), cmd_speed_mps=cmd.tolist(), e_con_m=e.tolist(),
        beta=np.asarray(beta, dtype=float).tolist(), lap=lap_idx.tolist(),
    )
    laps = []
    for ev in events:
        if ev["kind"] != "lap" or ev.get("lap_time_s") is None:
            continue
        lap_time = float(ev["lap_time_s"])
        mean_speed = ev.get("mean_speed_mps")
        if mean_speed is None:
            mean_speed = L / lap_time if lap_time > 0 else float("nan")
        max_e = ev.get("max_abs_e_con_m")
        if max_e is None:
            sel = (lap_idx == int(ev["lap"])) & np.isfinite(e)
            max_e = float(np.abs(e[sel]).max()) if sel.any() else float("nan")
        laps.append(LapRecord(lap_time_s=lap_time, mean_speed_mps=float(mean_speed),
                              off_track_events=int(ev.get("off_track_events") or 0),
                              max_abs_e_con_m=float(max_e)))
    off_xy = []
    for ev in events:  # where the car was when it left the track
        if ev["kind"] == "off_track":
            at = [_at(data, src[k], np.array([ev["t_s"]])) for k in (0, 1)]
            if at[0] is not None and at[1] is not None:
                off_xy.append((float(at[0][0]), float(at[1][0])))
    solve = data.series.get("solver/solve_time_ms", (None, np.zeros(0)))[1]
    status = data.series.get("solver/status_code", (None, np.zeros(0)))[1]
    infos = data.rows.get("plan/info", [])
    method = str(infos[-1].get("method")) if infos else ""
    return MethodRun(
        name=method if method in METHODS else "recorded",
        laps=laps,
        trace=trace,
        solve_times_ms=[float(v) for v in solve],
        solver_failures=int(np.count_nonzero(status != 0)),
        requested_laps=len(laps),
        extra={"recording": str(data.path)},
        off_track_xy=off_xy,
    )


def build_report(
    path: str | Path, track_spec: str | None = None, config: str | None = None
) -> tuple[dict[str, Any], MethodRun, Track, CurvatureProfile]:
    """(results document, method run, track, curvature profile) of a recording."""
    data = read_recording(path)
    cfg = load_config(config)
    track = track_of(data, track_spec)
    profile = track_profile(track, cfg.curvature)
    run = method_run(data, track, profile)
    reference, why_not = limit_reference(track, cfg)
    meta = {"recording": str(data.path), "complete": data.complete,
            "timelines": sorted(data.timelines), "planner_dt_s": cfg.planner.dt_s}
    if why_not:
        meta["no_reference"] = why_not
    doc = results_document(track.name, track.length_m, [run], meta=meta, reference=reference)
    return doc, run, track, profile


def limit_reference(track: Track, cfg: RacestackConfig) -> tuple[dict[str, Any] | None, str]:
    """(the ``reference`` of results.json, "") when the minimum-time lap of the simulated car
    on `track` (the bench's reference: ``limit_request``) is in the cache, else (None, one
    line saying why and the command that makes it). Never solves."""
    from services.planner import (
        MIN_TIME_LIMIT,
        MinTimeArtefactMissingError,
        MinTimeError,
        limit_request,
        load_min_time_lap,
    )

    try:
        lap = load_min_time_lap(track, *limit_request(cfg.planner, cfg.simulator.vehicle),
                                use=MIN_TIME_LIMIT)
    except MinTimeArtefactMissingError as exc:
        return None, (f"no min-time ratio: no minimum-time lap of this car on {track.name} "
                      f"in the cache (make it with: {exc.command})")
    except MinTimeError as exc:
        return None, f"no min-time ratio: {exc}"
    return reference_document(lap), ""


def build_parser() -> OneLineArgumentParser:
    """The arguments of ``racestack report``."""
    ap = OneLineArgumentParser(prog="racestack report", description=plain_help(__doc__))
    ap.add_argument("recording", help="a telemetry .rrd file or its run folder")
    ap.add_argument("--out", metavar="DIR",
                    help="where results.json and the figures go (default: <run>/report)")
    ap.add_argument("--track", help=f"{TRACK_SPEC_HELP} instead of the recorded one "
                    "(default: the recording's meta/track source, else its recorded lines)")
    ap.add_argument("--config", help="TOML configuration: the curvature settings of Fig. 4/5 "
                    "and the car of the min-time ratio (default: the built-in configuration)")
    ap.add_argument("--no-figures", action="store_true",
                    help="print the table and write results.json only (default: the figures "
                    "too)")
    add_figure_formats_argument(ap)
    return ap


def main(argv: Sequence[str] | None = None) -> int:
    """``racestack report RUN.rrd|RUN_DIR [--out DIR] [--track SPEC] [--config FILE]``."""
    args = build_parser().parse_args(argv)
    if not args.no_figures:
        try:
            require("matplotlib")  # the [tools] extra
        except MissingExtraError as exc:
            print(f"racestack report: {exc}", file=sys.stderr)
            return 2
    created: list[Path] = []

    def unusable(out: Path) -> bool:  # before the table: an error is then the only output
        created.extend(missing_dirs(out))
        problem = writable_dir_problem(out)
        if problem:
            remove_empty_dirs(created)
            print(f"racestack report: error: {problem}; give --out a folder you can write",
                  file=sys.stderr)
        return problem is not None

    if args.out and unusable(Path(args.out)):  # checked before the recording is read
        return 2
    try:
        doc, run, track, profile = build_report(args.recording, args.track, args.config)
    except (FileNotFoundError, ConfigError, TrackError) as exc:
        remove_empty_dirs(created)
        print(f"racestack report: error: {exc}", file=sys.stderr)
        return 2
    except (OSError, RuntimeError, ValueError) as exc:  # e.g. not an .rrd (rerun's reader)
        remove_empty_dirs(created)
        print(f"racestack report: error: {args.recording}: not a readable telemetry "
              f"recording ({' '.join(str(exc).split())})", file=sys.stderr)
        return 2
    rrd = Path(doc["meta"]["recording"])
    out = Path(args.out) if args.out else rrd.parent / "report"
    if not args.out and unusable(out):
        return 2
    cut = "" if doc["meta"]["complete"] else ", cut short: no footer"
    print(f"recording {rrd} ({run.name}, {len(run.trace.t_s)} planner ticks, "
          f"{len(run.solve_times_ms)} solves{cut})")
    print(format_table(doc))
    if doc["meta"].get("no_reference"):
        print(doc["meta"]["no_reference"])
    out.mkdir(parents=True, exist_ok=True)
    write_results(out / "results.json", doc)
    if not args.no_figures:
        paths = write_figures(out, track, profile, [run], formats=args.figure_formats,
                              planner_period_s=doc["meta"].get("planner_dt_s"))
        stems = sorted({p.stem for p in paths})
        print(f"figures in {out}: {', '.join(stems)} "
              f"({'/'.join(args.figure_formats)}; captions.md)")
    print(f"results: {out / 'results.json'}")
    return 0


if __name__ == "__main__":  # python -m services.tools.report RUN.rrd
    sys.exit(main())
