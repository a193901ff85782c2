"""``racestack up``'s CPU report: the ``/proc/<pid>/stat`` parser, the two readings, the
lines it prints (and "n/a" where a process cannot be read)."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

from services.tools.launcher.cpu import (
    CpuMeter,
    CpuReport,
    CpuTimes,
    CpuUse,
    format_cpu,
    parse_stat,
    read_cpu,
)

#: A real line (python3, 52 fields), utime 1234 and stime 56 ticks.
STAT = (
    "4242 (python3) S 4200 4242 4200 34816 4242 4194304 15000 0 0 0 1234 56 0 0 20 0 9 0 "
    "123456 2000000000 30000 18446744073709551615 1 1 0 0 0 0 0 16781312 2 0 0 0 17 1 0 0 "
    "0 0 0 0 0 0 0 0 0 0 0"
)


def test_the_parser_reads_user_and_system_time_in_ticks() -> None:
    c = parse_stat(STAT, 100.0)
    assert (c.user_s, c.system_s) == (12.34, 0.56)
    assert c.total_s == pytest.approx(12.90)


@pytest.mark.parametrize("comm", ["(a b)", "(x) S 1 2 (y)", "()", "(((("])
def test_a_command_name_with_spaces_or_parentheses_does_not_shift_the_fields(comm: str) -> None:
    line = STAT.replace("(python3)", f"({comm})")
    assert parse_stat(line, 100.0) == CpuTimes(12.34, 0.56)


@pytest.mark.parametrize(
    "line", ["", "4242 python3 S", "4242 (python3) S 1 2 3", "4242 (p) S " + "x " * 20]
)
def test_a_line_that_is_not_a_stat_line_is_refused(line: str) -> None:
    with pytest.raises(ValueError):
        parse_stat(line, 100.0)


@pytest.mark.skipif(not Path("/proc/self/stat").exists(), reason="no /proc (not Linux)")
def test_this_process_is_read_from_proc_and_its_time_grows() -> None:
    a = read_cpu(os.getpid())
    assert a is not None
    sum(i * i for i in range(300_000))  # some CPU
    b = read_cpu(os.getpid())
    assert b is not None and b.total_s >= a.total_s and b.user_s >= a.user_s


def test_without_proc_or_the_process_a_reading_is_none(tmp_path: Path) -> None:
    assert read_cpu(os.getpid(), proc=tmp_path) is None  # a system without /proc
    (tmp_path / "7").mkdir()
    (tmp_path / "7" / "stat").write_text("garbage")
    assert read_cpu(7, proc=tmp_path) is None


def test_the_meter_takes_the_difference_over_the_interval() -> None:
    t = {"now": 100.0}
    readings = {1: [CpuTimes(1.0, 0.5), CpuTimes(3.0, 1.0)], 2: [CpuTimes(0.0, 0.0), None]}
    meter = CpuMeter({"sim": 1, "gone": 2}, own=None, clock=lambda: t["now"],
                     read=lambda pid: readings[pid].pop(0))
    with pytest.raises(RuntimeError):
        meter.stop()
    meter.start()
    t["now"] = 110.0
    report = meter.stop()
    assert report.wall_s == 10.0
    assert report.rows == (CpuUse("sim", CpuTimes(2.0, 0.5)), CpuUse("gone", None))


def test_the_meter_has_a_row_for_this_process() -> None:
    meter = CpuMeter({}, own="launcher", read=lambda pid: CpuTimes(float(pid == os.getpid()), 0))
    meter.start()
    assert [r.name for r in meter.stop().rows] == ["launcher"]


def test_the_report_gives_seconds_and_the_share_of_one_core() -> None:
    report = CpuReport(
        20.0,
        (
            CpuUse("simulator", CpuTimes(3.0, 0.4)),
            CpuUse("planner", CpuTimes(1.5, 0.3)),
            CpuUse("launcher (with the hub)", CpuTimes(0.1, 0.1)),
        ),
    )
    lines = format_cpu(report).splitlines()
    assert lines[0] == "CPU over the race (20.0 s): user + system seconds, share of one core"
    assert lines[1].split() == ["simulator", "3.40", "s", "17.0", "%", "(user", "3.00,",
                                "system", "0.40)"]
    assert "launcher (with the hub)     0.20 s    1.0 %" in lines[3]
    assert lines[4].split() == ["all", "5.40", "s", "27.0", "%"]
    assert len({line.index(" s ") for line in lines[1:]}) == 1  # one column of seconds


def test_a_process_that_cannot_be_read_says_n_a() -> None:
    report = CpuReport(5.0, (CpuUse("simulator", None), CpuUse("planner", CpuTimes(1.0, 0.0))))
    lines = format_cpu(report).splitlines()
    assert lines[1].split() == ["simulator", "n/a"]
    assert lines[-1].split()[:3] == ["all", "read", "1.00"]
    assert format_cpu(CpuReport(5.0, (CpuUse("x", None),))).splitlines()[-1].split() == [
        "x", "n/a"
    ]


def test_a_zero_interval_has_no_share() -> None:
    text = format_cpu(CpuReport(0.0, (CpuUse("x", CpuTimes(0.0, 0.0)),)))
    assert "n/a" in text and "inf" not in text  # no division by zero
