"""Evaluation of laps, shared by the bench, the telemetry report and the launcher.

- ``results``: per-lap records (``LapRecord``), traces (``Trace``), one method's run
  (``MethodRun``) and the ``results.json`` document (``results_document``, ``write_results``);
- ``table``: the lap table in the layout of the paper's Table I (``format_table``) and the
  paper's own table (``format_paper_table``);
- ``figures``: the paper's figures 4-8 as PNG files (``write_figures``, with the
  minimum-time line as data: ``ReferenceLine``; matplotlib is imported only when a figure
  is drawn).

Plain Python + numpy (+ matplotlib for figures): no bus, no services.
"""

from shared.evaluation.figures import ReferenceLine, write_figures
from shared.evaluation.results import (
    LapRecord,
    MethodRun,
    Trace,
    method_json,
    reference_document,
    results_document,
    solve_time_stats,
    write_results,
)
from shared.evaluation.table import (
    PAPER_TABLE_I,
    format_paper_table,
    format_table,
    paper_table_applies,
)

__all__ = [
    "PAPER_TABLE_I",
    "LapRecord",
    "MethodRun",
    "ReferenceLine",
    "Trace",
    "format_paper_table",
    "format_table",
    "method_json",
    "paper_table_applies",
    "reference_document",
    "results_document",
    "solve_time_stats",
    "write_figures",
    "write_results",
]
