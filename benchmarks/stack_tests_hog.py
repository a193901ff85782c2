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
it). A round that leaves a process of its tests running fails, and the process is stopped
by its PID; so does each round's when interrupted (Ctrl-C). Exit code 0 only when every
round passed.

    .venv/bin/python -m benchmarks.stack_tests_hog --rounds 10
    .venv/bin/python -m benchmarks.stack_tests_hog --rounds 2 --files tests/stack/test_stack_up.py
"""

from __future__ import annotations

import argparse
import os
import re
import signal
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


def _start_time(pid: int) -> str | None:
    """The start time of process `pid` (``/proc/PID/stat`` field 22, clock ticks since boot;
    None: gone or a zombie): with the PID it names one process, not a later one given the
    same PID."""
    try:
        stat = Path(f"/proc/{pid}/stat").read_text(encoding="ascii", errors="replace")
    except OSError:
        return None
    fields = stat[stat.rfind(")") + 2:].split()  # the name may hold spaces
    return fields[19] if len(fields) > 19 and fields[0] != "Z" else None


def children(pid: int, zombies: bool = False) -> dict[int, str]:
    """The direct children of `pid` (Linux ``/proc/PID/task/*/children``): PID -> start
    time (zombies too with `zombies`, start time "")."""
    found: dict[int, str] = {}
    try:
        tasks = list(Path(f"/proc/{pid}/task").iterdir())
    except OSError:
        return found
    for task in tasks:
        try:
            kids = (task / "children").read_text(encoding="ascii").split()
        except OSError:
            continue
        for kid in map(int, kids):
            start = _start_time(kid)
            if start is not None or zombies:
                found[kid] = start or ""
    return found


def descendants(pid: int) -> dict[int, str]:
    """Every live process below `pid` (children, theirs, ...): PID -> start time. Services
    started in their own session are included."""
    found: dict[int, str] = {}
    todo = [pid]
    while todo:
        for kid, start in children(todo.pop()).items():
            if kid not in found:
                found[kid] = start
                todo.append(kid)
    return found


def become_subreaper() -> bool:
    """Make this process the child subreaper of what it starts (Linux ``prctl
    PR_SET_CHILD_SUBREAPER``): a process a test leaves behind is re-parented here when its
    parent ends, not to init, so it can be found and stopped. False where not available."""
    try:
        import ctypes

        libc = ctypes.CDLL(None, use_errno=True)
        return libc.prctl(PR_SET_CHILD_SUBREAPER, 1, 0, 0, 0) == 0
    except (OSError, AttributeError):
        return False


#: ``<linux/prctl.h>``
PR_SET_CHILD_SUBREAPER = 36


def stop_leftovers(known: dict[int, str], grace_s: float = 5.0) -> list[int]:
    """Stop the processes of `known` (PID -> start time, from ``descendants``) that still
    run as the same process: SIGTERM, then SIGKILL after `grace_s`; the ones that became
    this process's children are reaped. Returns the PIDs stopped."""
    alive = [pid for pid, start in known.items() if _start_time(pid) == start]
    for pid in alive:
        _signal(pid, signal.SIGTERM)
    deadline = time.monotonic() + grace_s
    while time.monotonic() < deadline and any(
            _start_time(p) == known[p] for p in alive):
        time.sleep(0.1)
    for pid in alive:
        if _start_time(pid) == known[pid]:
            _signal(pid, signal.SIGKILL)
    reap(set(alive))
    return alive


def reap(pids: set[int]) -> None:
    """Collect the exit of each of `pids` that is a child of this process (a re-parented
    orphan, now ended), waiting up to 5 s for each."""
    for pid in pids:
        deadline = time.monotonic() + 5.0
        while True:
            try:
                done, _ = os.waitpid(pid, os.WNOHANG)
            except ChildProcessError:  # not ours, or already collected
                break
            if done or time.monotonic() > deadline:
                break
            time.sleep(0.05)


def _signal(pid: int, sig: int) -> None:
    try:
        os.kill(pid, sig)
    except (ProcessLookupError, PermissionError):
        pass


def run_round(
    files: list[Path], timeout_s: float, env: dict[str, str], log: Path | None = None
) -> tuple[bool, str, float]:
    """One pytest run of `files`: (passed, its summary line, wall time [s]); its whole
    output goes to `log` when given (written as it comes: an interrupted round keeps it).

    Every process below the pytest is noted once a second; this process should be the
    subreaper (``become_subreaper``, as ``main`` makes it), so what the tests leave behind
    ends up among its own children when the pytest ends. Interrupted (Ctrl-C) or timed out,
    the pytest gets SIGINT (its fixtures stop what they started), 30 s, then SIGKILL. Then
    whatever it started still runs (a service a test left behind, which at the critical
    path's real-time priority would disturb the next round) is stopped by its PID and makes
    the round a failure. KeyboardInterrupt is raised on after the clean-up.
    """
    t0 = time.monotonic()
    cmd = [sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider",
           *[str(f) for f in files]]
    out_path = log or Path(tempfile.mkstemp(prefix="racestack-round-", suffix=".txt")[1])
    before = set(children(os.getpid(), zombies=True))  # the hog: not the round's
    known: dict[int, str] = {}
    interrupted = timed_out = False
    with open(out_path, "w", encoding="utf-8") as out:
        proc = subprocess.Popen(cmd, cwd=str(ROOT), env=env, stdout=out,
                                stderr=subprocess.STDOUT, text=True)
        try:
            while proc.poll() is None:
                known.update(descendants(proc.pid))
                if time.monotonic() - t0 > timeout_s:
                    timed_out = True
                    break
                time.sleep(1.0)
        except KeyboardInterrupt:
            interrupted = True
        if proc.poll() is None:
            known.update(descendants(proc.pid))
            proc.send_signal(signal.SIGINT)
            try:
                proc.wait(timeout=30.0)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait(timeout=10.0)
    orphans: dict[int, str] = {}
    for kid, start in children(os.getpid()).items():
        if kid not in before:  # not the hog's tree
            orphans[kid] = start
            orphans.update(descendants(kid))
    left = stop_leftovers({**known, **orphans})
    reap(set(children(os.getpid(), zombies=True)) - before - {proc.pid})
    text = out_path.read_text(encoding="utf-8", errors="replace")
    if log is None:
        out_path.unlink(missing_ok=True)
    if interrupted:
        raise KeyboardInterrupt
    found = SUMMARY.findall(text)
    summary = found[-1] if found else text.strip()[-200:]
    if timed_out:
        summary = f"timed out after {timeout_s:g} s"
    failed = [line for line in text.splitlines() if line.startswith(("FAILED", "ERROR"))]
    if failed:
        summary += "; " + "; ".join(failed[:5])
    if left:
        summary += f"; {len(left)} processes left running, stopped (PIDs {left[:8]})"
    return proc.returncode == 0 and not timed_out and not left, summary, time.monotonic() - t0


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
        print(f"  {f.relative_to(ROOT) if f.is_relative_to(ROOT) else f}")
    if not become_subreaper():
        print("  (not a child subreaper here: a process a test leaves behind after its "
              "parent ends may be missed)", flush=True)
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
