"""A CPU hog for the benchmarks: a busy loop pinned to one core, started and stopped by PID.

Shared by ``benchmarks/stack_latency.py``, ``benchmarks/soak.py``, ``benchmarks/garbage_flood.py``
and ``benchmarks/stack_tests_hog.py`` (issue 25: "a CPU hog on one of the two cores").

    hog = start_hog(hog_cpu())
    ...
    stop_process(hog, grace_s=2.0)   # services.tools.launcher.supervisor: by its PID
"""

from __future__ import annotations

import os
import sys
from subprocess import DEVNULL, Popen

#: The hog: a busy loop that a SIGINT ends without a traceback.
HOG_CODE = "import signal\nsignal.signal(signal.SIGINT, signal.SIG_DFL)\nwhile True:\n    pass\n"


def start_hog(cpu: int) -> Popen:
    """A busy-loop subprocess at nice 0 pinned to `cpu` (stop it with ``stop_process``)."""
    proc = Popen([sys.executable, "-c", HOG_CODE], stdin=DEVNULL)
    try:
        os.sched_setaffinity(proc.pid, {cpu})
        os.setpriority(os.PRIO_PROCESS, proc.pid, 0)  # normal priority, not this process's
    except (AttributeError, OSError) as exc:  # not Linux: an unpinned hog
        print(f"hog not pinned ({exc}); it runs on any CPU", file=sys.stderr)
    return proc


def hog_cpu() -> int:
    """The CPU the hog is pinned to: the last one this process may use."""
    try:
        return max(os.sched_getaffinity(0))
    except AttributeError:
        return 0


def load_average() -> str:
    """The 1-minute load average as text ("n/a" where there is none)."""
    try:
        return f"{os.getloadavg()[0]:.2f}"
    except OSError:
        return "n/a"
