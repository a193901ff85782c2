"""The stack tests N times in a row with a CPU hog on one core (issue 25's last line).

"The stack tests" are the tests that start ``racestack up`` or service processes: every
test file under ``tests/`` that names ``Supervisor``, ``racestack up`` or ``Popen`` (the
same ``grep -rl`` the issue uses; ``--files`` gives others instead). Each round runs them
in one ``pytest`` subprocess (``-q -p no:cacheprovider``, this interpreter, the project root
first on ``PYTHONPATH``) while the busy loop of ``benchmarks/hog.py`` spins pinned to the
last CPU (started by PID before the first round, stopped by PID after the last;
``--no-hog``: without). Prints per round PASS/FAIL, the pytest summary line and the wall
time, then the rounds passed, the longest run of passes from the first round, and the
total and median wall time per round (a CI estimate: the suite's other tests are not in
it). Exit code 0 only when every round passed.

    .venv/bin/python -m benchmarks.stack_tests_hog --rounds 10
    .venv/bin/python -m benchmarks.stack_tests_hog --rounds 2 --files tests/stack/test_stack_up.py
"""

from __future__ import annotations

import argparse
import os
import re
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from benchmarks.hog import hog_cpu, load_average, start_hog
from services.tools.launcher.supervisor import stop_process

ROOT = Path(__file__).resolve().parents[1]
#: What marks a test file as a stack test (issue 25: ``grep -rl "Supervisor\\|racestack
#: up\\|Popen" tests``).
STACK_TEST = re.compile(r"Supervisor|racestack up|Popen")
#: pytest's closing summary (``-q``: ``1 failed, 2 passed in 257.15s (0:04:17)``).
SUMMARY = re.compile(r"^=*\s*(\d+ (?:passed|failed|error).* in [\d.]+s.*?)\s*=*$", re.MULTILINE)


def stack_test_files(tests: Path) -> list[Path]:
    """The test files under `tests` (``test_*.py``) that name a process start, sorted."""
    return sorted(p for p in tests.rglob("test_*.py")
                  if STACK_TEST.search(p.read_text(encoding="utf-8", errors="replace")))


def run_round(
    files: list[Path], timeout_s: float, env: dict[str, str], log: Path | None = None
) -> tuple[bool, str, float]:
    """One pytest run of `files`: (passed, its summary line, wall time [s]); its whole
    output goes to `log` when given."""
    t0 = time.monotonic()
    cmd = [sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider",
           *[str(f) for f in files]]
    try:
        res = subprocess.run(cmd, cwd=str(ROOT), env=env, capture_output=True, text=True,
                             timeout=timeout_s)
    except subprocess.TimeoutExpired:
        return False, f"timed out after {timeout_s:g} s", time.monotonic() - t0
    if log is not None:
        log.write_text(res.stdout + res.stderr, encoding="utf-8")
    found = SUMMARY.findall(res.stdout)
    summary = found[-1] if found else (res.stdout or res.stderr).strip()[-200:]
    failed = [line for line in res.stdout.splitlines() if line.startswith(("FAILED", "ERROR"))]
    if failed:
        summary += "; " + "; ".join(failed[:5])
    return res.returncode == 0, summary, time.monotonic() - t0


def main(argv: list[str] | None = None) -> int:
    """Command line entry point."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rounds", type=int, default=10, help="rounds (default 10)")
    ap.add_argument("--files", nargs="*", default=None,
                    help="test files to run (default: the stack tests found under tests/)")
    ap.add_argument("--no-hog", action="store_true",
                    help="no CPU hog (default: a busy loop pinned to the last CPU)")
    ap.add_argument("--out", default=None,
                    help="folder for each round's pytest output, round-K.txt (default: a "
                         "temp folder)")
    ap.add_argument("--timeout-s", type=float, default=3600.0,
                    help="longest round before it counts as failed [s] (default 3600)")
    args = ap.parse_args(argv)
    if args.rounds < 1:
        ap.error("--rounds must be at least 1")
    files = [Path(f) for f in args.files] if args.files else stack_test_files(ROOT / "tests")
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(
        [str(ROOT), *filter(None, [os.environ.get("PYTHONPATH")])])}
    print(f"stack_tests_hog: {len(files)} files x {args.rounds} rounds, hog "
          f"{'off' if args.no_hog else f'on CPU {hog_cpu()}'}; load average {load_average()}",
          flush=True)
    for f in files:
        print(f"  {f.relative_to(ROOT) if f.is_absolute() else f}")
    out = Path(args.out) if args.out else Path(tempfile.mkdtemp(prefix="racestack-tests-"))
    out.mkdir(parents=True, exist_ok=True)
    print(f"  each round's output: {out}/round-K.txt", flush=True)
    hog = None if args.no_hog else start_hog(hog_cpu())
    results: list[tuple[bool, float]] = []
    try:
        for k in range(1, args.rounds + 1):
            ok, summary, wall = run_round(files, args.timeout_s, env, out / f"round-{k}.txt")
            results.append((ok, wall))
            print(f"round {k}: {'PASS' if ok else 'FAIL'} in {wall:.0f} s ({summary}); "
                  f"load average {load_average()}", flush=True)
    except KeyboardInterrupt:
        print("stack_tests_hog: interrupted", flush=True)
    finally:
        if hog is not None:
            stop_process(hog, grace_s=2.0)
    passed = sum(ok for ok, _ in results)
    streak = next((i for i, (ok, _) in enumerate(results) if not ok), len(results))
    walls = [w for _, w in results]
    if walls:
        print(f"{passed}/{len(results)} rounds passed, {streak} in a row from the first; "
              f"wall time {sum(walls):.0f} s in all, median {statistics.median(walls):.0f} s "
              "a round")
    return 0 if results and passed == len(results) == args.rounds else 1


if __name__ == "__main__":
    sys.exit(main())
