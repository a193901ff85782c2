"""``benchmarks.standing_starts`` prints a row per track and the totals (issue #21)."""

from __future__ import annotations

from benchmarks.standing_starts import main


def test_the_benchmark_prints_each_track_and_the_totals(capsys) -> None:
    assert main(["--tracks", "paperlike", "--starts", "2", "--seconds", "0.5"]) == 0
    out = capsys.readouterr().out
    row = next(line for line in out.splitlines() if line.startswith("paperlike"))
    assert row.split()[1] == "2"  # starts
    assert "raceline standing starts: 2, left the track 0" in out
    assert "step median / p99" in out
