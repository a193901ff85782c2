"""``racestack up``'s lap table: its off-track total agrees with its rows (an excursion in a
lap counts in that lap's row and in the total; one in the out lap only in the total)."""

from __future__ import annotations

import re

from services.tools.launcher.up import OffTrackTally
from shared.evaluation import LapRecord, format_table, results_document
from shared.messages import LapEvent
from shared.messages.vocab import LapKindName


def _ev(kind: str, lap: int, off: int, lap_time: float | None = None) -> LapEvent:
    return LapEvent(kind=kind, stamp_s=1.0, lap=lap, lap_time_s=lap_time,
                    mean_speed_mps=3.0 if lap_time else None, off_track_events=off,
                    max_abs_e_con_m=0.1)


def _total(table: str) -> int:
    return int(re.search(r"off-track \(all laps\)\s+(\d+)", table).group(1))


def test_the_total_counts_every_excursion_of_the_run() -> None:
    tally = OffTrackTally()
    events = [
        _ev(LapKindName.OFF_TRACK, 0, 1),  # in the out lap
        _ev(LapKindName.BACK_ON_TRACK, 0, 1),
        _ev(LapKindName.START, 0, 0),
        _ev(LapKindName.OFF_TRACK, 0, 1),  # in lap 1
        _ev(LapKindName.BACK_ON_TRACK, 0, 1),
        _ev(LapKindName.LAP, 1, 1, 10.0),
        _ev(LapKindName.LAP, 2, 0, 10.1),
    ]
    laps = []
    for ev in events:
        tally.see(ev)
        if ev.kind == LapKindName.LAP:
            laps.append(LapRecord(ev.lap_time_s, 3.0, ev.off_track_events, 0.1))
    run = tally.run("cimpcc", laps, [1.0], 2)
    assert (run.run_off_track_events, run.out_lap_off_track_events) == (2, 1)
    table = format_table(results_document("t", 30.0, [run]))
    assert _total(table) == 2 >= sum(lap.off_track_events for lap in laps)


def test_the_total_is_never_below_the_rows() -> None:
    """Lap events lost or a run joined late: the laps' own counts still add up."""
    tally = OffTrackTally()
    laps = [LapRecord(10.0, 3.0, 1, 0.1), LapRecord(10.0, 3.0, 2, 0.1)]
    run = tally.run("cimpcc", laps, [1.0], 2)
    assert _total(format_table(results_document("t", 30.0, [run]))) == 3
