"""The printed table (issue #16): no "vs best" columns for one method, the paper's Table I
only beside results on its track (map416)."""

from __future__ import annotations

from shared.evaluation import (
    LapRecord,
    MethodRun,
    Trace,
    format_table,
    paper_table_applies,
    results_document,
)


def _run(name: str, lap_s: float, laps: int = 2, requested: int = 2) -> MethodRun:
    recs = [LapRecord(lap_s, 30.0 / lap_s, 0, 0.1) for _ in range(laps)]
    return MethodRun(name, recs, Trace(), [1.0, 2.0, 3.0], 0, requested)


def test_table_of_one_method_has_no_vs_best_columns() -> None:
    one = format_table(results_document("map416", 30.0, [_run("cimpcc", 10.0)]))
    assert "vs best" not in one and "+0.0 %" not in one and "cimpcc" in one
    two = format_table(results_document("map416", 30.0, [_run("cimpcc", 10.0),
                                                         _run("mpcc", 11.0)]))
    assert "vs best" in two and "+10.0 %" in two


def test_table_note_counts_laps_in_words() -> None:
    text = format_table(results_document("t", 30.0, [_run("cimpcc", 10.0, 0, 1)]))
    assert "completed only 0 of 1 lap (" in text


def test_paper_table_only_beside_map416() -> None:
    assert paper_table_applies("map416") and paper_table_applies("map416_extracted")
    assert not paper_table_applies("paperlike") and not paper_table_applies("Monza")


def test_table_says_the_raceline_has_no_solver() -> None:
    text = format_table(results_document("t", 30.0, [_run("raceline", 10.0)]))
    assert "raceline runs no online solver: a feed-forward + feedback tracker" in text
    assert "pure pursuit" not in text  # replaced by the tracker (issue #22)
