"""Counting the hub's access-control denials from Zenoh's own trace (pure: lines in, counts out).

Zenoh 1.10.2 denies silently: a message its ``access_control`` refuses is dropped on the hub
and only the trace of the target ``zenoh::net::routing::interceptor::access_control`` says so
(the Python wheel has no ``stats`` feature, so the admin space has no drop counters). With
that target at ``trace`` every decision is one line (one subject per identity; see
``shared.security.acl``), in one of two forms::

    <zid> on Interface(lo)+CertCommonName(telemetry)+Transport(Tls)+<zid> is unauthorized
        to Put (ingress) on racestack/car0/cmd/drive
    Using cached result: <zid> is unauthorized to Put (ingress) on racestack/car0/cmd/drive

A line ``ACL (ingress|egress): caching permissions for `K` ...`` is followed, on the same
thread, by ``CACHE_FILL_LINES`` decisions that fill the cache of key expression K for every
message kind; they are not messages and are not counted. The zid of a cached decision is
mapped to the common name seen in the first form.
"""

from __future__ import annotations

import re
import threading
from collections import Counter
from dataclasses import dataclass

#: The Zenoh log target of the access-control decisions.
ACL_TARGET = "zenoh::net::routing::interceptor::access_control"
#: The log directives the hub runs with: warnings from Zenoh, every ACL decision.
ACL_LOG_DIRECTIVES = f"warn,{ACL_TARGET}=trace"
#: Decisions that follow one ``caching permissions`` line (one per message kind).
CACHE_FILL_LINES = 9

_ANSI = re.compile(r"\x1b\[[0-9;]*m")
_THREAD = re.compile(r"ThreadId\((\d+)\)")
_CACHING = re.compile(r"ACL \((?:ingress|egress)\): caching permissions for `")
_DECISION = re.compile(
    r"(?:Using cached result: )?(?P<zid>[0-9a-f]+)(?: on (?P<subject>\S+))? is "
    r"(?P<verdict>authorized|unauthorized) to (?P<what>.+?) \((?P<flow>ingress|egress)\)"
    r" on (?P<key>\S+)\s*$"
)
_CN = re.compile(r"CertCommonName\(([^)]*)\)")


@dataclass(frozen=True)
class Denial:
    """One message the hub refused.

    Attributes:
        identity: the sender's certificate common name ("?" if not yet seen).
        what: the message kind as Zenoh names it ("Put", "Liveliness Token", ...).
        flow: "ingress" (from that session) or "egress" (towards it).
        key: the key expression.
    """

    identity: str
    what: str
    flow: str
    key: str


class DenialParser:
    """Turns Zenoh log lines into ``Denial``s (feed lines in order; not thread-safe)."""

    def __init__(self) -> None:
        self._cache_fill: dict[str, int] = {}  # thread id -> decisions still to skip
        self._names: dict[str, str] = {}  # zid -> common name
        self.decisions = 0  #: counted decisions (allowed + denied), cache fills excluded

    def feed(self, line: str) -> Denial | None:
        """The denial `line` reports, or None (other lines, allowed, cache fills)."""
        if ACL_TARGET not in line:
            return None
        line = _ANSI.sub("", line)
        m = _THREAD.search(line)
        thread = m.group(1) if m else ""
        if _CACHING.search(line):
            self._cache_fill[thread] = CACHE_FILL_LINES
            return None
        d = _DECISION.search(line)
        if d is None:
            return None
        if d["subject"]:
            cn = _CN.search(d["subject"])
            if cn:
                self._names[d["zid"]] = cn.group(1)
        left = self._cache_fill.get(thread, 0)
        if left:
            self._cache_fill[thread] = left - 1
            return None
        self.decisions += 1
        if d["verdict"] != "unauthorized":
            return None
        return Denial(self._names.get(d["zid"], "?"), d["what"], d["flow"], d["key"])


class DenialCounter:
    """Thread-safe counts of denials by ``Denial`` (the tap's thread adds, the service reads)."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._counts: Counter[Denial] = Counter()

    def add(self, denial: Denial) -> None:
        """Count one denial."""
        with self._lock:
            self._counts[denial] += 1

    def snapshot(self) -> dict[Denial, int]:
        """A copy of the counts."""
        with self._lock:
            return dict(self._counts)

    @property
    def total(self) -> int:
        """Every denial so far."""
        with self._lock:
            return sum(self._counts.values())


def growth_text(now: dict[Denial, int], last: dict[Denial, int]) -> tuple[int, str]:
    """(new denials, one line naming each) between two snapshots, e.g.
    ``telemetry Put (ingress) racestack/car0/cmd/drive x40``."""
    new = {d: n - last.get(d, 0) for d, n in now.items() if n > last.get(d, 0)}
    parts = [
        f"{d.identity} {d.what} ({d.flow}) {d.key} x{n}"
        for d, n in sorted(new.items(), key=lambda kv: (-kv[1], kv[0].key))
    ]
    return sum(new.values()), ", ".join(parts)
