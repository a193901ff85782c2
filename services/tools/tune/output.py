"""What ``racestack tune`` writes into DIR, always from the storage (so every worker's
trials are in it, and a resumed or interrupted run rewrites it whole):

- ``best.toml``: the base configuration with the best feasible trial's overlay, a
  configuration ``racestack bench --config`` (and ``--tuned``) loads; validated after writing;
- ``trials.json`` (the study's identity, the best trial and every trial) and ``trials.csv``
  (one row per trial: state, value, feasibility, parameters, laps, clearance, error);
- ``history.png``: each trial's mean lap (feasible, infeasible, failed) with the best so far.

Files are written to a temporary name and renamed, so two workers finishing together never
leave a half-written file.
"""

from __future__ import annotations

import csv
import io
import json
import os
import time
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from optuna.trial import FrozenTrial

from services.tools.tune.search import deep_merge, dotted
from shared.config import RacestackConfig, load_config
from shared.config import toml_write as toml_out
from shared.config.methods import CIMPCC

BEST = "best.toml"
TRIALS_JSON = "trials.json"
TRIALS_CSV = "trials.csv"
HISTORY_PNG = "history.png"


def _replace(path: Path, data: bytes) -> None:
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    tmp.write_bytes(data)
    os.replace(tmp, path)


def trial_row(t: FrozenTrial, names: Sequence[str]) -> dict[str, Any]:
    """One trial as a flat record (the CSV row; the JSON adds the seeds and overlay)."""
    ua = t.user_attrs
    seeds = ua.get("seeds", [])
    return {
        "number": t.number,
        "state": t.state.name,
        "value": t.value,
        "feasible": bool(ua.get("feasible", False)),
        "mean_lap_s": ua.get("mean_lap_s"),
        "laps": sum(len(s["lap_times_s"]) for s in seeds),
        "off_track_events": sum(s["off_track_events"] for s in seeds),
        "recoveries": sum(s["recoveries"] for s in seeds),
        "spins": sum(s.get("spins", 0) for s in seeds),
        "below_limit_laps": sum(s.get("below_limit_laps", 0) for s in seeds),
        "min_clearance_m": min(
            (s["min_clearance_m"] for s in seeds if s["min_clearance_m"] is not None),
            default=None,
        ),
        "reasons": "; ".join(ua.get("reasons", [])),
        "error": ua.get("error", ""),
        "baseline": bool(ua.get("baseline", False)),
        "worker": ua.get("worker", ""),
        "wall_s": ua.get("wall_s"),
        "started": t.datetime_start.isoformat(timespec="seconds") if t.datetime_start else "",
        **{f"param_{n}": t.params.get(n) for n in names},
        **{f"ratio_{c['track']}/{c['car']}": c.get("ratio") for c in ua.get("cells", [])},
    }


def trials_document(
    meta: Mapping[str, Any], trials: Sequence[FrozenTrial], best: FrozenTrial | None,
    names: Sequence[str],
) -> dict[str, Any]:
    """The ``trials.json`` document."""
    rows = []
    for t in trials:
        row = trial_row(t, names)
        row["params"] = dict(t.params)
        row["seeds"] = t.user_attrs.get("seeds", [])
        row["overlay"] = t.user_attrs.get("overlay")
        row["cells"] = t.user_attrs.get("cells", [])
        rows.append(row)
    return {
        "study": dict(meta),
        "best": None if best is None else {
            "number": best.number,
            "mean_lap_s": best.value,
            "params": dict(best.params),
            "overlay": best.user_attrs.get("overlay"),
            "cells": best.user_attrs.get("cells", []),
        },
        "trials": rows,
    }


def write_history(out_dir: Path, doc: Mapping[str, Any], names: Sequence[str],
                  trials: Sequence[FrozenTrial]) -> None:
    """``trials.json`` and ``trials.csv``."""
    _replace(out_dir / TRIALS_JSON, (json.dumps(doc, indent=1) + "\n").encode())
    rows = [trial_row(t, names) for t in trials]
    buf = io.StringIO()
    fields = list(dict.fromkeys(k for r in rows for k in r)) or ["number", "state", "value"]
    w = csv.DictWriter(buf, fieldnames=fields, lineterminator="\n", restval="")
    w.writeheader()
    for r in rows:
        w.writerow({k: "" if v is None else v for k, v in r.items()})
    _replace(out_dir / TRIALS_CSV, buf.getvalue().encode())


def best_config_text(
    base_data: Mapping[str, Any], best: FrozenTrial, meta: Mapping[str, Any]
) -> str:
    """``best.toml``: the base configuration with the best trial's overlay, commented."""
    overlay = best.user_attrs["overlay"]
    data = deep_merge(base_data, overlay)
    data = deep_merge(data, {"track": {"source": meta["track_source"]}})
    obj = meta["objective"]
    cells = [(c["track"], c["car"]) for c in meta.get("cells", [])]
    header = "\n".join(
        [
            f"racestack tune: best of study {meta['study']!r}, trial {best.number}",
            (f"{meta.get('aggregate')} ratio to the minimum-time lap {best.value:.4f} over "
             f"{len(cells)} cells ({', '.join(f'{c[0]}/{c[1]}' for c in cells)})"
             if len(cells) > 1 else f"mean lap {best.value:.3f} s")
            + f" over {obj['laps']} lap(s) x seeds {obj['seeds']}, no off-track event, "
            f"recovery, spin or lap below the limit, body >= {obj['margin_m']:g} m inside the "
            "boundaries",
            f"method {meta['method']} on {meta['track']} ({meta['track_source']}); "
            f"written {time.strftime('%Y-%m-%d %H:%M:%S')}",
            "tuned keys: " + ", ".join(best.user_attrs.get("tuned_keys") or dotted(overlay)),
            f"base configuration: {meta.get('config_path') or 'the defaults'}",
            "race it: racestack bench --config THIS"
            + ("  (or --methods cimpcc,cimpcc-tuned --tuned THIS)"
               if meta["method"] == CIMPCC else ""),
        ]
    )
    return toml_out.dumps(data, header)


def write_best(out_dir: Path, base_data: Mapping[str, Any], best: FrozenTrial,
               meta: Mapping[str, Any]) -> RacestackConfig:
    """Write ``best.toml`` and prove it loads; returns the loaded configuration."""
    path = out_dir / BEST
    _replace(path, best_config_text(base_data, best, meta).encode())
    return load_config(path)


def value_label(meta: Mapping[str, Any]) -> str:
    """The y label of a study's values: the mean lap [s], or a family's ratio [1]."""
    if len(meta.get("cells", [])) > 1:
        return f"{meta.get('aggregate')} ratio to the minimum-time lap [1]"
    return "mean lap time [s]"


def plot_history(path: Path, trials: Sequence[FrozenTrial], title: str,
                 ylabel: str = "mean lap time [s]") -> None:
    """``history.png``: mean lap per trial, best feasible so far, baseline."""
    import matplotlib

    matplotlib.use("Agg", force=True)
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(8, 4.2), constrained_layout=True)
    feas = [(t.number, t.user_attrs["mean_lap_s"]) for t in trials
            if t.user_attrs.get("feasible") and t.user_attrs.get("mean_lap_s") is not None]
    infeas = [(t.number, t.user_attrs["mean_lap_s"]) for t in trials
              if not t.user_attrs.get("feasible") and t.user_attrs.get("mean_lap_s") is not None]
    failed = [t.number for t in trials if t.state.name == "FAIL"]
    no_laps = [t.number for t in trials
               if t.state.name == "COMPLETE" and t.user_attrs.get("mean_lap_s") is None]
    if feas:
        ax.plot(*zip(*feas, strict=True), "o", color="C0", label="feasible")
        best, xs, ys = float("inf"), [], []
        for n, v in sorted(feas):
            best = min(best, v)
            xs.append(n)
            ys.append(best)
        ax.step(xs, ys, where="post", color="C0", lw=1.2, label="best so far")
    if infeas:
        ax.plot(*zip(*infeas, strict=True), "x", color="C3",
                label="infeasible (off track, recovery, margin)")
    base = [t for t in trials if t.user_attrs.get("baseline")
            and t.user_attrs.get("mean_lap_s") is not None]
    if base:
        ax.axhline(base[0].user_attrs["mean_lap_s"], color="0.5", ls=":", lw=1,
                   label="baseline (configuration)")
    lo, hi = ax.get_ylim() if (feas or infeas) else (0.0, 1.0)
    for ns, mark, lab in ((no_laps, "v", "no complete laps"), (failed, "s", "failed")):
        if ns:
            ax.plot(ns, [hi] * len(ns), mark, color="0.3", ms=5, label=lab, clip_on=False)
    ax.set_ylim(lo, hi)
    ax.set_xlabel("trial")
    ax.set_ylabel(ylabel)
    ax.set_title(title, fontsize=10)
    ax.grid(alpha=0.3)
    if ax.get_legend_handles_labels()[0]:
        ax.legend(fontsize=8, loc="upper right")
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=110)
    plt.close(fig)
    _replace(path, buf.getvalue())
