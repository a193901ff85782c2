"""No piece of code is written twice: no run of ``MIN_LINES`` (10) or more identical lines
stands in two places of the source tree (two files, or two places in one file).

The checker is this file's own (no external tool). Over every git-tracked ``.py`` file under
``services/``, ``shared/`` and ``benchmarks/`` (not ``tests/``), each line is stripped of
its indentation and trailing blanks; blank lines and comment-only lines are dropped. Every
window of ``MIN_LINES`` consecutive remaining lines that occurs twice (not overlapping
itself) is a repeat; windows that follow each other in both places merge into one run,
reported as ``a.py:first-last ~ b.py:first-last`` with the files' own line numbers. The
fix of a repeat is one shared function (or constant) that both places use.
"""

from __future__ import annotations

import subprocess
from collections import defaultdict
from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
#: Shortest run of identical lines that counts as written twice.
MIN_LINES = 10
#: The folders checked (the tests may repeat themselves: each reads on its own).
FOLDERS = ("services", "shared", "benchmarks")


@dataclass(frozen=True, order=True)
class Repeat:
    """One run of identical code lines in two places (line numbers of the files, 1-based)."""

    path_a: str
    first_a: int
    last_a: int
    path_b: str
    first_b: int
    last_b: int
    lines: int  #: code lines in the run (blank and comment lines not counted)

    def __str__(self) -> str:
        return (f"{self.path_a}:{self.first_a}-{self.last_a} ~ "
                f"{self.path_b}:{self.first_b}-{self.last_b} ({self.lines} lines)")


def code_lines(text: str) -> list[tuple[int, str]]:
    """(line number, stripped text) of each line that is not blank or only a comment."""
    out = []
    for number, line in enumerate(text.splitlines(), start=1):
        s = line.strip()
        if s and not s.startswith("#"):
            out.append((number, s))
    return out


def find_repeats(sources: Mapping[str, str], min_lines: int = MIN_LINES) -> list[Repeat]:
    """Every maximal run of `min_lines` or more identical code lines found in two places of
    `sources` (path -> text), sorted."""
    lines = {path: code_lines(text) for path, text in sources.items()}
    windows: dict[tuple[str, ...], list[tuple[str, int]]] = defaultdict(list)
    for path, rows in lines.items():
        texts = [t for _, t in rows]
        for k in range(len(texts) - min_lines + 1):
            windows[tuple(texts[k : k + min_lines])].append((path, k))
    # matching window pairs, grouped by (file a, file b, offset b - a): a run is consecutive
    starts: dict[tuple[str, str, int], set[int]] = defaultdict(set)
    for places in windows.values():
        for i, (pa, ka) in enumerate(places):
            for pb, kb in places[i + 1 :]:
                if pa == pb and abs(kb - ka) < min_lines:
                    continue  # a window overlapping itself (a block of equal lines)
                (pa, ka), (pb, kb) = sorted([(pa, ka), (pb, kb)])
                starts[(pa, pb, kb - ka)].add(ka)
    out = []
    for (pa, pb, offset), ks in starts.items():
        for first, last in _runs(sorted(ks)):
            ra, rb = lines[pa], lines[pb]
            end = last + min_lines - 1
            out.append(Repeat(pa, ra[first][0], ra[end][0], pb, rb[first + offset][0],
                              rb[end + offset][0], end - first + 1))
    return sorted(out)


def _runs(ks: Iterable[int]) -> list[tuple[int, int]]:
    """Consecutive integers as (first, last) runs."""
    runs: list[tuple[int, int]] = []
    for k in ks:
        if runs and k == runs[-1][1] + 1:
            runs[-1] = (runs[-1][0], k)
        else:
            runs.append((k, k))
    return runs


def tracked_sources(root: Path = ROOT) -> dict[str, str]:
    """Path (relative, ``/``-separated) -> text of every tracked ``.py`` file in
    ``FOLDERS`` (every ``.py`` file there when `root` is not a git checkout)."""
    try:
        listed = subprocess.run(
            ["git", "ls-files", "-z", "--", *FOLDERS], cwd=root, capture_output=True,
            check=True, text=True,
        ).stdout.split("\0")
        paths = [p for p in listed if p.endswith(".py") and (root / p).is_file()]
    except (OSError, subprocess.CalledProcessError):
        paths = [p.relative_to(root).as_posix() for f in FOLDERS
                 for p in (root / f).rglob("*.py") if "__pycache__" not in p.parts]
    return {p: (root / p).read_text(encoding="utf-8") for p in sorted(paths)}


def test_no_code_is_written_twice() -> None:
    sources = tracked_sources()
    assert len(sources) > 100  # the tree was found
    repeats = find_repeats(sources)
    assert not repeats, (
        f"{len(repeats)} run(s) of {MIN_LINES}+ identical code lines in two places (make one "
        "shared function or constant and use it in both):\n" + "\n".join(map(str, repeats))
    )


# ------------------------------------------------------------------ the checker's self-test
def _block(n: int, tag: str = "x") -> list[str]:
    return [f"{tag}{i} = compute({i}, {tag!r})" for i in range(n)]


def test_checker_finds_a_crafted_pair_with_file_and_lines() -> None:
    a = ["import os", "", *_block(10)[:4], "    # a comment", "", *_block(10)[4:], "done()"]
    b = ["def f():", *(f"    {line}" for line in _block(10)), "    return 1"]  # indented
    found = find_repeats({"a.py": "\n".join(a), "b.py": "\n".join(b)})
    assert [str(r) for r in found] == ["a.py:3-14 ~ b.py:2-11 (10 lines)"]


def test_checker_ignores_nine_lines_and_merges_longer_runs() -> None:
    nine = _block(9)
    assert find_repeats({"a.py": "\n".join(["a()", *nine, "b()"]),
                         "b.py": "\n".join(["c()", *nine, "d()"])}) == []
    long = _block(14)
    found = find_repeats({"a.py": "\n".join(long), "b.py": "\n".join(["z()", *long])})
    assert [str(r) for r in found] == ["a.py:1-14 ~ b.py:2-15 (14 lines)"]


def test_checker_finds_a_repeat_in_one_file_but_not_a_block_of_equal_lines() -> None:
    text = "\n".join([*_block(10), "middle()", *_block(10)])
    assert [str(r) for r in find_repeats({"m.py": text})] == ["m.py:1-10 ~ m.py:12-21 (10 lines)"]
    assert find_repeats({"s.py": "\n".join(["pass"] * 15)}) == []  # overlaps itself only
