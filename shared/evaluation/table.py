"""The lap-time table in the layout of the paper's Table I, as text."""

from __future__ import annotations

from typing import Any

from shared.evaluation.figures import no_solver, plural

#: The paper's Table I (real car, 17 laps each), for printing beside a bench result.
PAPER_TABLE_I = {
    "MPCC": {"lap_time_s": (16.654, 15.801, 16.106), "mean_speed_mps": (2.963, 2.816, 2.910)},
    "RDM+OTG": {"lap_time_s": (16.437, 15.743, 16.083), "mean_speed_mps": (2.901, 2.819, 2.864)},
    "CiMPCC": {"lap_time_s": (14.568, 13.945, 14.202), "mean_speed_mps": (3.404, 3.294, 3.351)},
}


#: The track of the paper's Table I (the authors' map416): its numbers are printed only
#: beside results on it.
PAPER_TRACK = "map416"


def paper_table_applies(track_name: str) -> bool:
    """True when results on `track_name` can stand beside the paper's Table I (map416)."""
    return track_name.lower().startswith(PAPER_TRACK)


def _fmt(v: float | None, unit: str = "") -> str:
    return "-" if v is None else f"{v:.3f}{unit}"


def _pct(v: float | None, best: float | None) -> str:
    if v is None or best is None or best == 0:
        return "-"
    return f"{100.0 * (v - best) / best:+.1f} %"


def format_table(doc: dict[str, Any]) -> str:
    """Lap time and mean speed (max / min / mean) per method, with % against the best.

    The best method is the one with the lowest mean lap time (for lap time) and the highest
    mean speed (for speed); each cell's percentage is against that best value. A table of
    one method has no "vs best" columns (they would all read +0.0 %). With a ``reference``
    (the minimum-time lap) a last row gives each mean lap over that limit.
    """
    methods = doc["methods"]
    names = list(methods)
    width = max(12, *(len(n) + 2 for n in names))
    pw = 10 if len(names) > 1 else 0  # width of the "vs best" columns (none for one method)
    header = f"{'':>24}" + "".join(f"{n:>{width}}" + ("vs best".rjust(pw) if pw else "")
                                   for n in names)
    lines = [f"track {doc['track']} ({doc['track_length_m']:.2f} m)"]
    ref = doc.get("reference")
    if ref:
        lines.append(
            f"minimum-time lap of the simulated car (the limit): {ref['min_time_lap_s']:.3f} s "
            f"at v_max {ref['v_max_mps']:g} m/s"
        )
    lines.append(header)
    for key, label, unit, better in (
        ("lap_time_s", "Lap time [s]", "", min),
        ("mean_speed_mps", "Mean speed [m/s]", "", max),
    ):
        for stat in ("max", "min", "mean"):
            values = [methods[n][key][stat] for n in names]
            present = [v for v in values if v is not None]
            best = better(present) if present else None
            row = f"{label if stat == 'max' else '':>17} {stat:>6}"
            for v in values:
                row += f"{_fmt(v, unit):>{width}}" + (_pct(v, best).rjust(pw) if pw else "")
            lines.append(row)
    lines.append("")
    row_laps = f"{'completed laps':>24}"
    row_off = f"{'off-track (all laps)':>24}"
    row_e = f"{'max |e_con| [m]':>24}"
    row_t = f"{'solve median/p99 [ms]':>24}"
    for n in names:
        m = methods[n]
        laps = f"{m['completed_laps']}/{m.get('requested_laps', m['completed_laps'])}"
        row_laps += f"{laps:>{width}}{'':>{pw}}"
        off = m.get("off_track_events_all", sum(lap["off_track_events"] for lap in m["laps"]))
        row_off += f"{off:>{width}}{'':>{pw}}"
        e = max((lap["max_abs_e_con_m"] for lap in m["laps"]), default=None)
        row_e += f"{_fmt(e):>{width}}{'':>{pw}}"
        st = m["solve_time_ms"]
        t = "-" if st["median"] is None else f"{st['median']:.2f}/{st['p99']:.2f}"
        row_t += f"{t:>{width}}{'':>{pw}}"
    lines += [row_laps, row_off, row_e, row_t]
    if ref:
        row_r = f"{'mean lap / min-time':>24}"
        row_b = f"{'laps below the limit':>24}"
        row_c = f"{'over the speed cap':>24}"
        for n in names:
            r = methods[n].get("ratio_to_min_time")
            row_r += f"{'-' if r is None else f'{r:.3f}':>{width}}{'':>{pw}}"
            row_b += f"{methods[n].get('below_limit_laps', '-'):>{width}}{'':>{pw}}"
            row_c += f"{methods[n].get('over_cap_events', '-'):>{width}}{'':>{pw}}"
        lines += [row_r, row_b, row_c]
        for n in names:
            for err in methods[n].get("errors", []):
                lines.append(f"ERROR {n}: {err}")
    for n in names:
        if no_solver(n):
            lines.append(f"note: {n} runs no online solver: a feed-forward + feedback tracker "
                         "on its precomputed line (by default the minimum-time lap, solved "
                         "offline once and cached); its solve time is the compute time of "
                         "its planner tick")
    for n in names:
        m = methods[n]
        if m["completed_laps"] < m.get("requested_laps", m["completed_laps"]):
            why = m.get("aborted") or "stopped early"
            lines.append(f"note: {n} completed only {m['completed_laps']} of "
                         f"{plural(m['requested_laps'], 'lap')} ({why}); its statistics cover "
                         "those laps")
    return "\n".join(lines)


def format_paper_table() -> str:
    """The paper's Table I for comparison (real car, 17 laps)."""
    lines = [
        "paper, Table I (real car, 17 laps each):",
        f"{'':>24}{'MPCC':>10}{'RDM+OTG':>10}{'CiMPCC':>10}",
    ]
    for key, label in (("lap_time_s", "Lap time [s]"), ("mean_speed_mps", "Mean speed [m/s]")):
        for i, stat in enumerate(("max", "min", "mean")):
            row = f"{label if i == 0 else '':>17} {stat:>6}"
            for name in ("MPCC", "RDM+OTG", "CiMPCC"):
                row += f"{PAPER_TABLE_I[name][key][i]:>10.3f}"
            lines.append(row)
    return "\n".join(lines)
