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
thread, by up to ``CACHE_FILL_LINES`` decisions in the first form on key K that fill the
cache of K for every message kind; they are not messages and are not counted. The fill ends
early at the first decision that is not one of them (a cached one, or on another key): a
session that matches no subject gets no fill lines at all. The zid of a cached decision is
mapped to the common name seen in the first form.

A certificate of the project's CA whose common name is no identity of the rules matches no
subject: Zenoh says so once (``<zid> did not match any configured ACL subject. Default
permission `Deny` will be applied on all messages``, at info) and then denies everything it
sends, mostly without a line per message (its client never learns of a subscriber, so it
sends little). That line is itself counted as a denial (``what`` = ``CONNECT_DENIED``, key
``*``) with the common name Zenoh's TLS link logged at debug just before on the same thread
(``zenoh_link_tls::unicast: Accepted TLS connection on A: B. Common Name: X.``), shown as
``X (unknown CN)``; its later decisions carry that name too.
"""

from __future__ import annotations

import re
import threading
from collections import Counter
from dataclasses import dataclass

#: The Zenoh log target of the access-control decisions.
ACL_TARGET = "zenoh::net::routing::interceptor::access_control"
#: The Zenoh log target that names the common name of each accepted TLS connection.
LINK_TARGET = "zenoh_link_tls::unicast"
#: The log directives the hub runs with: warnings from Zenoh, every ACL decision, and the
#: TLS link's one line per accepted connection (the common name of an unknown certificate).
ACL_LOG_DIRECTIVES = f"warn,{ACL_TARGET}=trace,{LINK_TARGET}=debug"
#: ``Denial.what`` of a session whose certificate matches no subject (everything denied).
CONNECT_DENIED = "Connect (no such identity: everything denied)"
#: ``Denial.identity`` suffix of a common name that is no identity of the rules.
UNKNOWN_CN = " (unknown CN)"
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
_CACHING_KEY = re.compile(r"caching permissions for `([^`]*)`")
_ACCEPTED_CN = re.compile(r"Accepted TLS connection on .*Common Name: (?P<cn>[^\s]*?)\.?\s*$")
_NO_SUBJECT = re.compile(r"(?P<zid>[0-9a-f]+) did not match any configured ACL subject")


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
        self._cache_fill: dict[str, tuple[str, int]] = {}  # thread -> (key, lines to skip)
        self._names: dict[str, str] = {}  # zid -> common name
        self._accepted: dict[str, str] = {}  # thread -> CN of the TLS link accepted last
        self.decisions = 0  #: counted decisions (allowed + denied), cache fills excluded
        self.strangers = 0  #: sessions whose certificate matched no subject

    @staticmethod
    def wants(line: str) -> bool:
        """Whether `line` is one the parser reads (the ACL trace, the TLS link's accepts)."""
        return ACL_TARGET in line or LINK_TARGET in line

    def feed(self, line: str) -> Denial | None:
        """The denial `line` reports, or None (other lines, allowed, cache fills)."""
        if not self.wants(line):
            return None
        line = _ANSI.sub("", line)
        m = _THREAD.search(line)
        thread = m.group(1) if m else ""
        if ACL_TARGET not in line:
            cn = _ACCEPTED_CN.search(line)
            if cn:
                self._accepted[thread] = cn["cn"]
            return None
        caching = _CACHING_KEY.search(line)
        if caching and _CACHING.search(line):
            self._cache_fill[thread] = (caching.group(1), CACHE_FILL_LINES)
            return None
        stranger = _NO_SUBJECT.search(line)
        if stranger:
            name = self._accepted.pop(thread, "?") + UNKNOWN_CN
            self._names[stranger["zid"]] = name
            self.strangers += 1
            return Denial(name, CONNECT_DENIED, "ingress", "*")
        d = _DECISION.search(line)
        if d is None:
            return None
        if d["subject"]:
            cn = _CN.search(d["subject"])
            if cn:
                self._names[d["zid"]] = cn.group(1)
        fill_key, left = self._cache_fill.get(thread, ("", 0))
        if left:
            if d["subject"] and d["key"] == fill_key:
                self._cache_fill[thread] = (fill_key, left - 1)
                return None
            self._cache_fill[thread] = ("", 0)  # not a fill line: the fill is over
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
