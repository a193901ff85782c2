"""Car-to-car incidents as text (issue #24): the line the simulator says on ``events/log``
for each contact episode and the parser the launcher reads it back with::

    contact 1: car1 hit car0 at t = 12.345 s, depth 0.021 m, 1.52 m/s closing
"""

from __future__ import annotations

import re
from dataclasses import dataclass

__all__ = ["IncidentRecord", "incident_line", "parse_incident"]


@dataclass(frozen=True)
class IncidentRecord:
    """One contact as the simulator said it.

    Attributes:
        number: the incident's number in the run (1, 2, ...).
        striker, struck: car names (striker "none": undecided; then `struck` is "a+b").
        t_s: simulation time [s]; depth_m: penetration at the start [m]; closing_mps: the
            relative speed along the normal at the start [m/s].
    """

    number: int
    striker: str
    struck: str
    t_s: float
    depth_m: float
    closing_mps: float


def incident_line(rec: IncidentRecord) -> str:
    """The ``events/log`` text of an incident (module docstring)."""
    who = (f"{rec.striker} hit {rec.struck}" if rec.striker != "none"
           else f"{rec.struck.replace('+', ' and ')} touched")
    return (f"contact {rec.number}: {who} at t = {rec.t_s:.3f} s, depth {rec.depth_m:.3f} m, "
            f"{rec.closing_mps:.2f} m/s closing")


_LINE = re.compile(
    r"contact (?P<n>\d+): (?:(?P<a>[\w-]+) hit (?P<b>[\w-]+)|(?P<c>[\w-]+) and (?P<d>[\w-]+) "
    r"touched) at t = (?P<t>[-\d.]+) s, depth (?P<depth>[-\d.]+) m, (?P<v>[-\d.]+) m/s closing"
)


def parse_incident(text: str) -> IncidentRecord | None:
    """The incident of an ``incident_line`` text (None: not one)."""
    m = _LINE.fullmatch(text.strip())
    if m is None:
        return None
    if m["a"]:
        striker, struck = m["a"], m["b"]
    else:
        striker, struck = "none", f"{m['c']}+{m['d']}"
    return IncidentRecord(int(m["n"]), striker, struck, float(m["t"]), float(m["depth"]),
                          float(m["v"]))
