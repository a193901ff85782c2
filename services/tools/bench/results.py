"""Moved to ``shared.evaluation.results`` (the bench, the telemetry report and the launcher
share it); re-exported here so the bench's imports keep working."""

from shared.evaluation.results import (
    LapRecord,
    MethodRun,
    Trace,
    method_json,
    results_document,
    solve_time_stats,
    write_results,
)

__all__ = [
    "LapRecord",
    "MethodRun",
    "Trace",
    "method_json",
    "results_document",
    "solve_time_stats",
    "write_results",
]
