"""Load shedding of the telemetry: what it logs less of, as pure functions (no Rerun, no I/O).

* ``Decimator``: at most ``max_hz`` scalar samples per second of message time per key (a
  viewer plots 20-30 Hz as well as 100 Hz; the recording and the live stream get the same).
  A message is kept when it is the first one in its ``1 / max_hz`` slot of message time, so
  a 40 Hz key kept at 30 Hz keeps 30 of every 40, a 100 Hz key 30 of 100, and a key below
  ``max_hz`` keeps (nearly) every message.
* ``parse_overwritten_drops`` / ``DropSummary``: the services' ``DropReporter`` says every
  second, at info level, "dropped N valid messages (total T): <key> overwritten xN, ..." when
  a newest-value channel replaced a value its consumer had no time for (by design). In a live
  run those lines are most of the event log and push the warnings out of view; the telemetry
  logs them at debug level on ``events/drops/<source>`` and one summary per source per
  ``drop_summary_interval_s`` in the event log. Drop lines with other reasons (stale, queue
  full) are warnings and stay as they are.
"""

from __future__ import annotations

import math
import re
from collections.abc import Mapping
from dataclasses import dataclass, field

#: "dropped 5 valid messages (total 9): racestack/car0/vehicle/pose overwritten x5, ..."
_DROP_LINE = re.compile(r"^dropped (\d+) valid messages \(total (\d+)\): (.+)$")
_DROP_PART = re.compile(r"^(\S+) (\S+) x(\d+)$")
#: The one drop reason that is by design (a newer value replaced one nobody took).
OVERWRITTEN = "overwritten"


class Decimator:
    """Keeps at most `max_hz` messages per second of message time per key.

    Args:
        max_hz: most samples kept per second [Hz]; 0 keeps every message.
    """

    def __init__(self, max_hz: float) -> None:
        if max_hz < 0.0 or not math.isfinite(max_hz):
            raise ValueError(f"max_hz must be a finite number >= 0, not {max_hz}")
        self.max_hz = max_hz
        self._slot: dict[str, int] = {}
        self.kept = 0  #: messages kept
        self.skipped = 0  #: messages whose samples were shed

    def due(self, key: str, t_s: float) -> bool:
        """True when the message of `key` stamped `t_s` [s] is to be logged (and note it).

        A stamp going backwards (a restarted simulation) starts the key afresh."""
        if self.max_hz <= 0.0:
            self.kept += 1
            return True
        slot = math.floor(t_s * self.max_hz)
        last = self._slot.get(key)
        if last is not None and last == slot:
            self.skipped += 1
            return False
        self._slot[key] = slot
        self.kept += 1
        return True


def parse_overwritten_drops(text: str) -> dict[str, int] | None:
    """The per-key counts of a ``DropReporter`` line whose every reason is ``overwritten``
    (``{"racestack/car0/vehicle/pose": 5, ...}``); None for any other text (other reasons,
    or not a drop line)."""
    m = _DROP_LINE.match(text.strip())
    if m is None:
        return None
    counts: dict[str, int] = {}
    for part in m.group(3).split(", "):
        p = _DROP_PART.match(part.strip())
        if p is None or p.group(2) != OVERWRITTEN:
            return None
        counts[p.group(1)] = counts.get(p.group(1), 0) + int(p.group(3))
    return counts or None


@dataclass
class _Window:
    start_s: float
    lines: int = 0
    counts: dict[str, int] = field(default_factory=dict)


@dataclass(frozen=True)
class Summary:
    """One summary line of a source's overwritten-drop reports over a window of time."""

    source: str
    start_s: float  #: message time of the window's first line [s]
    end_s: float  #: message time of its last line [s]
    lines: int  #: drop lines summarised
    counts: Mapping[str, int]  #: messages overwritten per key

    @property
    def total(self) -> int:
        """Messages overwritten in the window."""
        return sum(self.counts.values())

    def text(self) -> str:
        """``[planner] 57 valid messages overwritten in 30.0 s (12 reports; newest-value
        channels, by design): racestack/car0/vehicle/pose x50, ...``"""
        span = max(0.0, self.end_s - self.start_s)
        by_count = sorted(self.counts.items(), key=lambda kv: -kv[1])
        parts = ", ".join(f"{k} x{n}" for k, n in by_count)
        return (f"[{self.source}] {self.total} valid messages overwritten in {span:.1f} s "
                f"({self.lines} reports; newest-value channels, by design): {parts}")


class DropSummary:
    """Aggregates overwritten-drop lines per source into one summary per `interval_s`.

    ``add`` returns the summary of the source's window when this line closes it (the line
    is `interval_s` or more after the window's first one; the line is counted in it);
    ``due(now)`` the summaries of every window whose first line is `interval_s` or more
    before `now`; ``flush()`` every open window (at the end of a run).
    """

    def __init__(self, interval_s: float) -> None:
        if interval_s <= 0.0:
            raise ValueError("interval_s must be > 0")
        self.interval_s = interval_s
        self._open: dict[str, _Window] = {}
        self._last_t: dict[str, float] = {}

    def add(self, source: str, t_s: float, counts: Mapping[str, int]) -> Summary | None:
        """Count one drop line of `source` at message time `t_s` [s]."""
        w = self._open.get(source)
        if w is None or t_s < w.start_s:
            w = self._open[source] = _Window(t_s)
        w.lines += 1
        for k, n in counts.items():
            w.counts[k] = w.counts.get(k, 0) + n
        self._last_t[source] = t_s
        if t_s - w.start_s >= self.interval_s:
            return self._close(source)
        return None

    def due(self, now_s: float) -> list[Summary]:
        """Close and return the windows that started `interval_s` or more before `now_s`."""
        late = [s for s, w in self._open.items() if now_s - w.start_s >= self.interval_s]
        return [self._close(s) for s in late]

    def flush(self) -> list[Summary]:
        """Close and return every open window."""
        return [self._close(s) for s in list(self._open)]

    def _close(self, source: str) -> Summary:
        w = self._open.pop(source)
        return Summary(source, w.start_s, self._last_t.get(source, w.start_s), w.lines,
                       dict(w.counts))
