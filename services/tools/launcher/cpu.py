"""CPU time of the stack's processes over a race, for ``racestack up``'s report.

Read from ``/proc/<pid>/stat`` (Linux: ``utime`` and ``stime``, fields 14 and 15 of
proc(5), in clock ticks of ``SC_CLK_TCK``; all threads of the process, not its children).
Where there is no ``/proc`` (or a process has exited before the second reading) a row says
"n/a". ``CpuMeter`` takes one reading per process at the start of the race and one at its
end; ``format_cpu`` prints the differences with the share of one core over the wall time
between them::

    meter = CpuMeter({"planner": 4242}, own="launcher (with the hub)")
    meter.start()
    ...                                   # the race
    print(format_cpu(meter.stop()))
"""

from __future__ import annotations

import os
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path

#: Where the per-process statistics are (Linux).
PROC = Path("/proc")


@dataclass(frozen=True, slots=True)
class CpuTimes:
    """CPU time of one process: `user_s` and `system_s` [s]."""

    user_s: float
    system_s: float

    @property
    def total_s(self) -> float:
        """User + system [s]."""
        return self.user_s + self.system_s

    def __sub__(self, other: CpuTimes) -> CpuTimes:
        return CpuTimes(self.user_s - other.user_s, self.system_s - other.system_s)


def parse_stat(line: str, ticks_per_s: float) -> CpuTimes:
    """The user and system time of one ``/proc/<pid>/stat`` line (``ticks_per_s``: the
    kernel's ``SC_CLK_TCK``). The command name (field 2, in parentheses) may hold spaces
    and parentheses, so the fields are counted from its last ``)``. ValueError if the line
    is not such a line."""
    end = line.rfind(")")
    if end < 0 or not ticks_per_s > 0:
        raise ValueError(f"not a /proc/<pid>/stat line: {line[:80]!r}")
    fields = line[end + 1 :].split()  # fields[0] is field 3 (state)
    if len(fields) < 13:
        raise ValueError(f"a /proc/<pid>/stat line with {len(fields) + 2} fields")
    utime, stime = int(fields[11]), int(fields[12])
    if utime < 0 or stime < 0:
        raise ValueError(f"negative CPU time in /proc/<pid>/stat: {utime}, {stime}")
    return CpuTimes(utime / ticks_per_s, stime / ticks_per_s)


def _ticks_per_s() -> float | None:
    try:
        ticks = os.sysconf("SC_CLK_TCK")
    except (AttributeError, ValueError, OSError):
        return None
    return float(ticks) if ticks > 0 else None


def read_cpu(pid: int, proc: Path = PROC) -> CpuTimes | None:
    """The CPU time of process `pid` so far, or None where it cannot be read (no
    ``/proc``, the process gone, an unreadable line)."""
    ticks = _ticks_per_s()
    if ticks is None:
        return None
    try:
        return parse_stat((proc / str(pid) / "stat").read_text(), ticks)
    except (OSError, ValueError):
        return None


@dataclass(frozen=True, slots=True)
class CpuUse:
    """One row of the report: `name`, its CPU time over the interval (None: n/a)."""

    name: str
    cpu: CpuTimes | None


@dataclass(frozen=True, slots=True)
class CpuReport:
    """The CPU use of every process over `wall_s` [s] of wall time."""

    wall_s: float
    rows: tuple[CpuUse, ...]


class CpuMeter:
    """Two readings of the CPU time of named processes and of this one (`own` names it).

    Args:
        pids: process name -> pid.
        own: the name of this process's row (None: no row for it).
        clock: the wall clock of the interval [s].
        read: how one process is read (``read_cpu``).
    """

    def __init__(
        self,
        pids: Mapping[str, int],
        own: str | None = None,
        clock: Callable[[], float] = time.monotonic,
        read: Callable[[int], CpuTimes | None] = read_cpu,
    ) -> None:
        self.pids = dict(pids)
        if own is not None:
            self.pids[own] = os.getpid()
        self.clock = clock
        self.read = read
        self._t0: float | None = None
        self._first: dict[str, CpuTimes | None] = {}

    def start(self) -> None:
        """The first reading (the start of the race)."""
        self._first = {name: self.read(pid) for name, pid in self.pids.items()}
        self._t0 = self.clock()

    def stop(self) -> CpuReport:
        """The second reading: the CPU time of each process since ``start``."""
        if self._t0 is None:
            raise RuntimeError("CpuMeter.stop() before start()")
        wall = self.clock() - self._t0
        rows = []
        for name, pid in self.pids.items():
            a, b = self._first.get(name), self.read(pid)
            rows.append(CpuUse(name, b - a if a is not None and b is not None else None))
        return CpuReport(wall, tuple(rows))


def format_cpu(report: CpuReport) -> str:
    """The report as lines: per process the CPU seconds (user + system), the share of one
    core over the wall time and the split, then the sum of those that could be read."""
    wall = report.wall_s
    known = [r.cpu for r in report.rows if r.cpu is not None]
    total_name = "all" if len(known) == len(report.rows) else "all read"
    width = max([len(r.name) for r in report.rows] + [len(total_name)])

    def row(name: str, seconds: float) -> str:
        pct = f"{100.0 * seconds / wall:5.1f} %" if wall > 0 else "  n/a  "
        return f"  {name:<{width}}  {seconds:7.2f} s  {pct}"

    lines = [f"CPU over the race ({wall:.1f} s): user + system seconds, share of one core"]
    for r in report.rows:
        if r.cpu is None:
            lines.append(f"  {r.name:<{width}}  n/a")
        else:
            lines.append(row(r.name, r.cpu.total_s)
                         + f"  (user {r.cpu.user_s:.2f}, system {r.cpu.system_s:.2f})")
    if known:
        lines.append(row(total_name, sum(c.total_s for c in known)))
    return "\n".join(lines)
