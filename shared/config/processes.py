"""Scheduling of each process (``[processes]``): CPU affinity, nice and real-time priority.

One ``ProcessPriority`` per process of the roster (``[processes.planner]``, ...), applied by
each process to itself at its start (``shared.priority.apply_priority``, from the common
shell), so ``racestack up``, ``racestack run NAME``, the benchmarks and a container all get
them. Every thread the process starts afterwards inherits them (on Linux niceness, affinity
and the scheduling policy are per thread and inherited by new threads).

The defaults work on a 2-core laptop without root: the critical path (simulator, bridge,
planner, VESC driver, lidar driver, and the hub ``services.router`` every message of theirs
passes through) asks for ``SCHED_RR`` priority 10, nice -10 and CPUs that do not sleep
while it runs (``wakeup_latency_us = 0``, a PM QoS request), each where permitted
(``realtime_if_permitted``, ``nice_if_permitted``, ``wakeup_latency_if_permitted``: without
the right it runs at normal priority, said in one info line, no warning), telemetry
(and the Rerun viewer it spawns, which inherits its niceness) and the ROS 2 gateway niced
(10), no CPU pinning (on two cores pinning a service leaves it waiting for its one core
while the other idles). A negative nice or a real-time priority
needs the right (``CAP_SYS_NICE`` or an ``RLIMIT_NICE`` / ``RLIMIT_RTPRIO`` of ``ulimit -e`` /
``-r``); without it a configured one is said in one warning line and the process runs on at
the priority it had.
"""

from __future__ import annotations

from pydantic import Field, field_validator

from shared.config.base import Section


class ProcessPriority(Section):
    """How one process is scheduled.

    Attributes:
        nice: niceness the process sets for itself at start (-20 highest .. 19 lowest;
            0: the normal priority; below 0 needs the right, see the module docstring).
        nice_if_permitted: True: a `nice` the process may not set is no warning (one info
            line; it runs at the niceness it was started with): "higher where permitted".
        cpus: the CPUs the process may run on (``os.sched_setaffinity``; CPU numbers as
            ``nproc`` counts them; empty: all). CPUs the machine does not have are ignored,
            and with none left the process keeps all (one warning line).
        realtime_priority: above 0: the ``SCHED_RR`` real-time priority (1-99) the process
            asks for at start (needs the right; without it one warning line and the nice
            above is kept); 0: normal scheduling.
        realtime_if_permitted: True: a `realtime_priority` the process may not set is no
            warning (one info line; it runs on at `nice`): "real time where permitted".
        wakeup_latency_us: not None: while the process runs it asks the kernel to keep
            every CPU out of idle states that take longer than this to wake from [us]
            (Linux PM QoS: the value written to ``/dev/cpu_dma_latency``, held open for the
            life of the process; the kernel takes the smallest request of all processes).
            0 keeps an idle CPU polling, so a thread woken by a message runs at once
            instead of after the idle state's exit (on a virtual machine a halted vCPU's
            wake-up through the host). Costs power, not CPU time of any process. None: no
            request (the kernel's default).
        wakeup_latency_if_permitted: True: a `wakeup_latency_us` the process may not ask
            for (the device is root's) is no warning (one info line).
    """

    nice: int = Field(0, ge=-20, le=19)
    nice_if_permitted: bool = False
    cpus: tuple[int, ...] = ()
    realtime_priority: int = Field(0, ge=0, le=99)
    realtime_if_permitted: bool = False
    wakeup_latency_us: int | None = Field(None, ge=0, le=2_000_000_000)
    wakeup_latency_if_permitted: bool = False

    @field_validator("cpus")
    @classmethod
    def _cpus_valid(cls, cpus: tuple[int, ...]) -> tuple[int, ...]:
        if any(c < 0 or c > 1023 for c in cpus):
            raise ValueError("cpus: CPU numbers from 0 to 1023")
        if len(set(cpus)) != len(cpus):
            raise ValueError("cpus: each CPU once")
        return cpus


#: ``SCHED_RR`` priority of the critical path (low among 1-99: kernel threads and a
#: system's own real-time tasks keep theirs).
CRITICAL_RT = 10
#: Telemetry and the gateway give way to the critical path.
NICED = ProcessPriority(nice=10)
#: The critical path: real time (``SCHED_RR`` 10) where permitted, else nice -10 where
#: permitted, else normal. Real time is what holds the deadline with the rest of the machine
#: busy: under a CPU hog and a load average of 8-10 the pose-to-command p99 was 18-25 ms at
#: nice -10 and 5.7-6.3 ms with ``SCHED_RR`` (``benchmarks/stack_latency.py``, issue 25).
#: None of these processes spins (each waits on its input or its clock), and Linux keeps 5 %
#: of each CPU for normal processes (``sched_rt_runtime_us``) should one ever do so.
#: It also keeps the CPUs awake while it runs (``wakeup_latency_us = 0`` where permitted):
#: a thread woken by a message then runs at once instead of after the idle CPU's exit. On
#: this project's 2-core virtual machine (idle = a halted vCPU) that cut the pose-to-command
#: p99 from 6.2-21.6 ms to 4.8-7.4 ms on a quiet machine and from 7.2-10.0 to 5.8-6.2 ms with
#: the hog, the Zenoh hop into the next process from 1.3-11.3 to 0.66-2.7 ms p99 (three
#: interleaved runs each, issue 25); the medians barely moved. The price is power (an idle
#: CPU polls), not CPU time of any process, and only while the stack runs.
CRITICAL = ProcessPriority(nice=-10, nice_if_permitted=True, realtime_priority=CRITICAL_RT,
                           realtime_if_permitted=True, wakeup_latency_us=0,
                           wakeup_latency_if_permitted=True)


class ProcessSettings(Section):
    """The ``[processes]`` section: one ``ProcessPriority`` per process of the roster
    (``shared/roster.py``; ``tests/shared/test_priority.py`` checks the two agree)."""

    #: the hub carries every message of the critical path (pose, state, command): at
    #: normal priority a loaded machine held them back 250 ms and more (issue 25: the
    #: stack tests beside a full test suite)
    router: ProcessPriority = CRITICAL
    simulator: ProcessPriority = CRITICAL
    localization_bridge: ProcessPriority = CRITICAL
    planner: ProcessPriority = CRITICAL
    telemetry: ProcessPriority = NICED
    vesc_driver: ProcessPriority = CRITICAL
    lidar_driver: ProcessPriority = CRITICAL
    ros2_gateway: ProcessPriority = NICED

    def of(self, process: str) -> ProcessPriority | None:
        """The settings of `process` (a roster name; None for a name without its own, such
        as a tool)."""
        value = getattr(self, process, None) if process in type(self).model_fields else None
        return value if isinstance(value, ProcessPriority) else None
