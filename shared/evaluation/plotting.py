"""What every figure of ``shared.evaluation`` shares: the save helper, the methods' styles,
the legend row, and the data-level helpers (gaps in s, the minimum-time line as data).

``save_figure`` writes one figure as vector PDF and SVG beside a 300 dpi PNG (``FORMATS``,
or the formats asked for: ``parse_formats``). The figure is saved at its own size (no
"tight" bounding box): a legend never widens a file, and the PNG is exactly
``figsize x DPI`` pixels. Figures use matplotlib's constrained layout, which makes room for
the titles and the legend rows inside that size.

Titles carry no "Fig. N:": the figure number is in the file name (``fig4_curvature.pdf``)
and in the caption (``CAPTIONS``, written beside the figures as ``captions.md``).

matplotlib is imported only when a figure is drawn (``pyplot``).
"""

from __future__ import annotations

import argparse
import logging
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

#: Resolution of the PNG files [dots per inch].
DPI = 300
#: The file formats every figure is written in, in this order (vector first).
FORMATS: tuple[str, ...] = ("pdf", "svg", "png")
#: A jump in s larger than this share of the lap (or than ``GAP_MIN_M``) is a gap [-].
GAP_SHARE = 0.02
#: ... and never less than this [m].
GAP_MIN_M = 0.5
#: Line styles and markers of the methods, by their index in the run (colour ``C{i}``):
#: methods on the same line (the raceline, cimpcc-line, the limit) stay apart by style.
LINESTYLES = ("-", (0, (5, 1.5)), (0, (3, 1, 1, 1)), (0, (1, 1)), (0, (6, 2, 1, 2, 1, 2)))
MARKERS = ("o", "s", "^", "D", "v", "P", "X")
#: Style of the minimum-time line: a wide grey band under the methods' lines.
LIMIT_STYLE: dict[str, Any] = {"color": "0.35", "lw": 5.0, "alpha": 0.35,
                               "solid_capstyle": "butt"}
#: Off-track events: a red cross with a dark edge, over every line.
OFF_TRACK_STYLE: dict[str, Any] = {"marker": "X", "s": 70, "color": "red",
                                   "edgecolors": "k", "linewidths": 0.6, "zorder": 8}


@dataclass(frozen=True)
class ReferenceLine:
    """The minimum-time lap of the simulated car, as the figures need it.

    Attributes:
        lap_time_s: its lap time [s].
        x_m, y_m: (N,) its path [m].
        s_m: (N,) progress of each point along the track's centreline [m], in [0, L).
        v_mps: (N,) its speed [m/s].
        name: the legend label.
    """

    lap_time_s: float
    x_m: np.ndarray
    y_m: np.ndarray
    s_m: np.ndarray
    v_mps: np.ndarray
    name: str = "minimum-time line"


def plural(n: int, word: str) -> str:
    """``"1 lap"``, ``"3 laps"``."""
    return f"{n} {word}" if n == 1 else f"{n} {word}s"


def parse_formats(text: str | Iterable[str]) -> tuple[str, ...]:
    """The figure formats of a ``--figure-formats`` value ("pdf,svg,png", any subset, any
    order, case-insensitive); ValueError naming a format that is not one of ``FORMATS``
    or an empty list."""
    items = text.split(",") if isinstance(text, str) else list(text)
    out: list[str] = []
    for item in (i.strip().lower().lstrip(".") for i in items):
        if not item:
            continue
        if item not in FORMATS:
            raise ValueError(f"unknown figure format {item!r} (one of {', '.join(FORMATS)})")
        if item not in out:
            out.append(item)
    if not out:
        raise ValueError(f"no figure format given (one of {', '.join(FORMATS)})")
    return tuple(out)


def add_figure_formats_argument(ap: argparse.ArgumentParser) -> None:
    """``--figure-formats pdf,svg,png`` on a tool's parser (``args.figure_formats``, a tuple;
    default all of ``FORMATS``; a wrong format is an argument error)."""

    def formats(text: str) -> tuple[str, ...]:
        try:
            return parse_formats(text)
        except ValueError as exc:
            raise argparse.ArgumentTypeError(str(exc)) from None

    ap.add_argument("--figure-formats", type=formats, default=FORMATS, metavar="LIST",
                    help=f"comma list of the figures' file formats (default "
                         f"{','.join(FORMATS)}: vector PDF and SVG beside a {DPI} dpi PNG)")


def pyplot():
    """matplotlib's pyplot on the Agg backend (no display), imported on first use."""
    import matplotlib

    matplotlib.use("Agg", force=True)
    import matplotlib.pyplot as plt

    return plt


def new_figure(figsize: tuple[float, float]):
    """(figure, body): a figure of `figsize` [in] in constrained layout, and the subfigure
    its axes and legend row go in (the figure's title sits above the body, so a legend row
    at the body's top never runs into the title; the layout makes room for both inside
    `figsize`)."""
    fig = pyplot().figure(figsize=figsize, layout="constrained")
    return fig, fig.subfigures(1, 1)


def save_figure(
    fig, stem: str | Path, formats: Sequence[str] = FORMATS, dpi: int = DPI
) -> list[Path]:
    """Write `fig` as ``<stem>.<format>`` for each of `formats` and close it.

    PDF and SVG are vector files (text as text in the PDF: TrueType fonts); the PNG has
    `dpi` dots per inch, recorded in the file. The figure keeps its size: no tight bounding
    box, so the PNG is ``figsize x dpi`` pixels.

    Args:
        fig: a matplotlib figure.
        stem: the path without the extension (an extension given is replaced).
        formats: some of ``FORMATS`` (``parse_formats`` checks a user's list).

    Returns:
        The paths written, in the order of `formats`.
    """
    import matplotlib

    # the PDF's font subsetting logs every table it prunes at INFO: not the tool's output
    logging.getLogger("fontTools").setLevel(logging.WARNING)
    stem = Path(stem)
    stem = stem.with_suffix("") if stem.suffix.lstrip(".").lower() in FORMATS else stem
    paths = []
    with matplotlib.rc_context({"pdf.fonttype": 42, "svg.hashsalt": "racestack"}):
        for fmt in parse_formats(formats):
            path = stem.parent / f"{stem.name}.{fmt}"
            meta = {"Date": None} if fmt in ("pdf", "svg") else {}
            fig.savefig(path, format=fmt, dpi=dpi, metadata=meta)
            paths.append(path)
    pyplot().close(fig)
    return paths


def method_style(i: int) -> dict[str, Any]:
    """Colour, line style and marker of the `i`-th method (the same in every figure)."""
    return {"color": f"C{i % 10}", "ls": LINESTYLES[i % len(LINESTYLES)],
            "marker": MARKERS[i % len(MARKERS)]}


def legend_row(body, handles: Sequence[Any], labels: Sequence[str], max_cols: int = 4):
    """The legend as a compact row (or rows) at the top of `body` (``new_figure``'s
    subfigure): above the axes, below the figure's title, inside the figure (constrained
    layout makes room), over no curve; as many columns (up to `max_cols`) as fit the
    figure's width. None without entries."""
    if not handles:
        return None
    renderer = body.figure.canvas.get_renderer()
    width = body.figure.bbox.width
    for ncol in range(min(len(handles), max_cols), 0, -1):  # as many columns as fit
        legend = body.legend(handles, labels, loc="outside upper center", ncol=ncol,
                             fontsize=8, frameon=False, handlelength=3.0, columnspacing=1.6)
        if ncol == 1 or legend.get_window_extent(renderer).width <= 0.96 * width:
            return legend
        legend.remove()
    return None


def break_gaps(
    s: np.ndarray, values: np.ndarray, gap_m: float
) -> tuple[np.ndarray, np.ndarray]:
    """Sort (s, values) by s and put a NaN between neighbours more than `gap_m` apart.

    A line drawn through the result stops at a gap in the data (a lap recorded only in
    part, a stretch where nothing was recorded) instead of joining its ends straight.

    Args:
        s: (N,) progress [m]; values: (N,) the plotted quantity.
        gap_m: the largest step in s that is still drawn [m].

    Returns:
        (s', values'), each (N + gaps,), sorted by s, NaN at the gaps.
    """
    s = np.asarray(s, dtype=float)
    v = np.asarray(values, dtype=float)
    order = np.argsort(s, kind="stable")
    s, v = s[order], v[order]
    cut = np.flatnonzero(np.diff(s) > gap_m) + 1
    return np.insert(s, cut, np.nan), np.insert(v, cut, np.nan)


def gap_for(length_m: float) -> float:
    """The gap threshold of `break_gaps` on a lap of `length_m` [m]."""
    return max(GAP_MIN_M, GAP_SHARE * length_m)
