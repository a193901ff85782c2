"""A process's own scheduling at start: nice, CPU affinity, real-time priority, and how
fast an idle CPU must wake for it (PM QoS).

``apply_priority(settings)`` (the common shell calls it after loading the configuration,
before the bus and the workers start, so every thread inherits it) sets what
``[processes.<name>]`` asks for and returns a ``PriorityReport``: one warning line per thing
it could not set (no right, no such CPU, not Linux), or an info line for a nice or a
real-time priority asked for only where permitted (``nice_if_permitted``,
``realtime_if_permitted``), never raising: a process that may not raise
its priority runs on at the one it has. A process asking for no real-time priority drops one
it inherited (a service started by ``racestack up``, whose launcher hosts the hub at the
hub's priority), and sets its niceness even when it inherited another. A
``wakeup_latency_us`` is a PM QoS request held open for the life of the process.
``SchedulingCalls`` holds the OS calls, so the rules are tested without changing the test
process.
"""

from __future__ import annotations

import os
import struct
from collections.abc import Callable
from dataclasses import dataclass, field

from shared.config.processes import ProcessPriority


def _threads() -> list[int]:
    """This process's threads (Linux: niceness, affinity and policy are per thread, and a
    library may have started one at import, before the shell runs); [0]: this one only."""
    try:
        return [int(t) for t in os.listdir("/proc/self/task")]
    except (OSError, ValueError):
        return [0]


def _setpriority(nice: int) -> None:
    for tid in _threads():
        os.setpriority(os.PRIO_PROCESS, tid, nice)


def _getpriority() -> int:
    return os.getpriority(os.PRIO_PROCESS, 0)


def _available_cpus() -> set[int]:
    return set(os.sched_getaffinity(0))


def _setaffinity(cpus: set[int]) -> None:
    for tid in _threads():
        os.sched_setaffinity(tid, cpus)


def _set_realtime(priority: int) -> None:
    for tid in _threads():
        os.sched_setscheduler(tid, os.SCHED_RR, os.sched_param(priority))


def _is_realtime() -> bool:
    return os.sched_getscheduler(0) in (os.SCHED_RR, os.SCHED_FIFO)


def _set_normal() -> None:
    for tid in _threads():  # giving up a real-time policy needs no right
        os.sched_setscheduler(tid, os.SCHED_OTHER, os.sched_param(0))


#: The PM QoS requests this process holds (open ``/dev/cpu_dma_latency`` descriptors): a
#: request lasts while its descriptor is open, so they stay open until the process ends.
_WAKEUP_REQUESTS: list[int] = []
#: Linux's CPU wake-up latency request device (PM QoS).
CPU_LATENCY_DEVICE = "/dev/cpu_dma_latency"


def _request_wakeup_latency(us: int) -> None:
    fd = os.open(CPU_LATENCY_DEVICE, os.O_WRONLY | os.O_CLOEXEC)
    try:
        os.write(fd, struct.pack("=i", us))  # a 32-bit integer [us]
    except BaseException:
        os.close(fd)
        raise
    _WAKEUP_REQUESTS.append(fd)


@dataclass(frozen=True)
class SchedulingCalls:
    """The OS calls ``apply_priority`` makes (Linux's, by default)."""

    get_nice: Callable[[], int] = _getpriority
    set_nice: Callable[[int], None] = _setpriority
    available_cpus: Callable[[], set[int]] = _available_cpus
    set_affinity: Callable[[set[int]], None] = _setaffinity
    set_realtime: Callable[[int], None] = _set_realtime
    is_realtime: Callable[[], bool] = _is_realtime
    set_normal: Callable[[], None] = _set_normal
    request_wakeup_latency: Callable[[int], None] = _request_wakeup_latency


@dataclass
class PriorityReport:
    """What ``apply_priority`` could not set: `warnings` (said as warnings) and `notes`
    (a nice asked for only where permitted: said as info)."""

    warnings: list[str] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)


def apply_priority(
    settings: ProcessPriority | None, calls: SchedulingCalls | None = None
) -> PriorityReport:
    """Set this process's niceness, CPUs and real-time priority from `settings` (None:
    nothing); returns the lines of what could not be set (none: all set)."""
    report = PriorityReport()
    if settings is None:
        return report
    os_calls = calls or SchedulingCalls()
    warnings = report.warnings
    if settings.realtime_priority > 0:
        try:
            os_calls.set_realtime(settings.realtime_priority)
        except (AttributeError, OSError) as exc:  # no right (EPERM), not Linux
            line = (f"real-time priority {settings.realtime_priority} not permitted "
                    f"({_reason(exc)}): normal scheduling at nice {settings.nice}")
            (report.notes if settings.realtime_if_permitted else warnings).append(line)
    else:  # normal scheduling, even when started by a real-time parent (the launcher's hub)
        try:
            if os_calls.is_realtime():
                os_calls.set_normal()
        except (AttributeError, OSError) as exc:
            warnings.append(f"real-time policy inherited and not dropped ({_reason(exc)})")
    try:
        if os_calls.get_nice() != settings.nice or settings.nice != 0:
            os_calls.set_nice(settings.nice)  # every thread (one a library started too)
    except (AttributeError, OSError) as exc:
        line = (f"nice {settings.nice} not permitted ({_reason(exc)}): running at the "
                "niceness it was started with")
        (report.notes if settings.nice_if_permitted else warnings).append(line)
    if settings.cpus:
        try:
            have = os_calls.available_cpus()
            want = set(settings.cpus) & have
            if want:
                if want != have:
                    os_calls.set_affinity(want)
            else:
                warnings.append(f"cpus {list(settings.cpus)}: none of them is available "
                                f"({sorted(have)}): running on all")
        except (AttributeError, OSError) as exc:
            warnings.append(f"cpus {list(settings.cpus)} not set ({_reason(exc)}): running "
                            "on all")
    if settings.wakeup_latency_us is not None:
        try:
            os_calls.request_wakeup_latency(settings.wakeup_latency_us)
        except (AttributeError, OSError) as exc:  # not root, no such device (not Linux)
            line = (f"CPU wake-up latency limit {settings.wakeup_latency_us} us not "
                    f"permitted ({_wakeup_reason(exc)}): the kernel's idle states")
            (report.notes if settings.wakeup_latency_if_permitted else warnings).append(line)
    return report


def _wakeup_reason(exc: BaseException) -> str:
    if isinstance(exc, PermissionError):
        return f"no permission to write {CPU_LATENCY_DEVICE}: needs root"
    if isinstance(exc, FileNotFoundError | AttributeError):
        return f"not supported on this system (no {CPU_LATENCY_DEVICE})"
    return str(exc) or type(exc).__name__


def _reason(exc: BaseException) -> str:
    if isinstance(exc, PermissionError):
        return "no permission: needs CAP_SYS_NICE or a raised ulimit -e / -r"
    if isinstance(exc, AttributeError):
        return "not supported on this system"
    return str(exc) or type(exc).__name__
