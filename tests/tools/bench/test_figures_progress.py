"""Progress within long laps (issue #16): the bench's bar and the launcher's lap line."""

from __future__ import annotations

import io

import pytest

from services.tools.bench.run import ProgressBar
from services.tools.launcher.up import LiveLine, lap_progress_line
from shared.evaluation.figures import plural


class _Tty(io.StringIO):
    def isatty(self) -> bool:
        return True


def test_bench_progress_says_the_distance_of_the_lap_in_lines_when_not_a_tty(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    monkeypatch.setattr(ProgressBar, "LINE_PERIOD_S", 0.0)
    out = io.StringIO()
    bar = ProgressBar("cimpcc", stream=out, length_m=446.0, total=2)
    for s in (0.3, 100.0, 445.0, 2.0, 223.0):  # the out lap, the line, half of lap 1
        bar.at(s)
    bar(1, 2)
    text = out.getvalue()
    assert "\r" not in text  # a log file gets whole lines
    assert "0/2 laps, out lap 100/446 m" in text and "lap 1 223/446 m" in text
    assert text.splitlines()[-1].split("]")[1].startswith(" 1/2 laps")


def test_bench_progress_rewrites_one_line_on_a_tty(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(ProgressBar, "TTY_PERIOD_S", 0.0)
    out = _Tty()
    bar = ProgressBar("mpcc", stream=out, length_m=32.8)
    bar.total = 1
    bar.at(10.0)
    bar(1, 1)
    text = out.getvalue()
    assert text.count("\r") == 2 and text.endswith("\n") and "1/1 laps" in text


def test_up_lap_progress_line_and_plural() -> None:
    assert lap_progress_line(2, 3, 12.34, 32.77, 3.214) == (
        "lap 2/3: 12.3 of 32.8 m (38 %), 3.21 m/s")
    assert lap_progress_line(1, 1, 40.0, 32.77, 1.0).startswith("lap 1/1: 7.2 of")  # wrapped
    assert plural(1, "lap") == "1 lap" and plural(3, "lap") == "3 laps"
    out = io.StringIO()
    live = LiveLine(out, period_s=5.0)
    live.show("a", now=live._last + 1.0)  # too early
    live.show("b", now=live._last + 6.0)
    assert out.getvalue() == "b\n"


def test_a_long_step_says_it_is_still_at_it_and_a_short_one_says_nothing() -> None:
    """Issue #22: minutes of IPOPT on a 400 m track are not minutes of silence."""
    import threading

    from services.tools.bench.run import Heartbeat

    quiet = io.StringIO()
    with Heartbeat("the minimum-time lap", stream=quiet, period_s=60.0):
        pass  # a cache hit
    assert quiet.getvalue() == ""
    out = io.StringIO()
    seen = threading.Event()
    with Heartbeat("the minimum-time lap", stream=out, period_s=0.01) as beat:
        while beat.lines == 0:  # the step runs until the heartbeat spoke once
            seen.wait(0.01)
    first = out.getvalue().splitlines()[0]
    assert first.startswith("the minimum-time lap: still at it, ") and first.endswith(" s")
