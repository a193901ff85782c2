"""``[processes]``: each process's scheduling settings, validated, and applied (or one warning
line each) by ``shared.priority.apply_priority``, on fake OS calls (the test process keeps
its own scheduling)."""

from __future__ import annotations

import pytest

from shared.config import ConfigError, RacestackConfig, config_from_dict
from shared.config.processes import ProcessPriority, ProcessSettings
from shared.priority import SchedulingCalls, apply_priority
from shared.roster import ROSTER


class FakeOs:
    """Records the calls; `deny` names the ones that raise PermissionError."""

    def __init__(self, nice: int = 0, cpus: set[int] | None = None, deny: tuple = (),
                 realtime: int = 0) -> None:
        self.nice, self.cpus, self.deny = nice, cpus or {0, 1}, deny
        self.realtime = realtime
        self.wakeup_us: list[int] = []  #: the PM QoS requests made

    def calls(self) -> SchedulingCalls:
        def guard(name: str) -> None:
            if name in self.deny:
                raise PermissionError(1, "Operation not permitted")

        def set_nice(n: int) -> None:
            guard("nice")
            self.nice = n

        def set_affinity(c: set[int]) -> None:
            guard("cpus")
            self.cpus = c

        def set_realtime(p: int) -> None:
            guard("realtime")
            self.realtime = p

        def set_normal() -> None:
            guard("normal")
            self.realtime = 0

        def request_wakeup_latency(us: int) -> None:
            if "wakeup_missing" in self.deny:
                raise FileNotFoundError(2, "No such file or directory")
            guard("wakeup")
            self.wakeup_us.append(us)

        return SchedulingCalls(lambda: self.nice, set_nice, lambda: set(self.cpus),
                               set_affinity, set_realtime, lambda: self.realtime > 0,
                               set_normal, request_wakeup_latency)


def test_the_defaults_raise_the_critical_path_where_permitted_and_nice_telemetry() -> None:
    cfg = RacestackConfig()
    for name in ("simulator", "localization_bridge", "planner", "vesc_driver", "router"):
        p = cfg.processes.of(name)
        assert p is not None and p.nice < 0 and p.nice_if_permitted
        assert p.realtime_priority > 0 and p.realtime_if_permitted and not p.cpus
        assert p.wakeup_latency_us == 0 and p.wakeup_latency_if_permitted
    assert cfg.processes.telemetry.nice > 0 and cfg.processes.telemetry.realtime_priority == 0
    # where permitted the critical path runs real time
    fake = FakeOs()
    assert apply_priority(cfg.processes.planner, fake.calls()).warnings == []
    assert fake.realtime == cfg.processes.planner.realtime_priority
    assert fake.wakeup_us == [0]
    assert cfg.processes.telemetry.wakeup_latency_us is None
    # without the right the default is no warning, only a note each, and the process runs on
    fake = FakeOs(deny=("nice", "realtime", "wakeup"))
    report = apply_priority(cfg.processes.planner, fake.calls())
    assert report.warnings == [] and len(report.notes) == 3
    assert (fake.nice, fake.realtime) == (0, 0)
    assert cfg.processes.of("bench") is None  # a tool has none of its own


def test_every_roster_process_has_its_settings() -> None:
    assert {p.name for p in ROSTER} == set(ProcessSettings.model_fields)


@pytest.mark.parametrize("bad", [{"nice": 20}, {"nice": -21}, {"cpus": [-1]}, {"cpus": [0, 0]},
                                 {"realtime_priority": 100}, {"niceness": 3}])
def test_bad_settings_are_configuration_errors(bad: dict) -> None:
    with pytest.raises(ConfigError):
        config_from_dict({"processes": {"planner": bad}})


def test_settings_are_applied_when_permitted() -> None:
    fake = FakeOs()
    report = apply_priority(ProcessPriority(nice=5, cpus=(1, 7), realtime_priority=10),
                            fake.calls())
    assert report.warnings == report.notes == []
    assert (fake.nice, fake.cpus, fake.realtime) == (5, {1}, 10)


def test_what_is_not_permitted_is_one_warning_line_each_and_the_rest_applies() -> None:
    fake = FakeOs(deny=("realtime", "nice"))
    warnings = apply_priority(ProcessPriority(nice=-5, cpus=(0,), realtime_priority=20),
                              fake.calls()).warnings
    assert len(warnings) == 2 and all("\n" not in w for w in warnings)
    assert "real-time priority 20 not permitted" in warnings[0] and "nice -5" in warnings[1]
    assert (fake.nice, fake.cpus, fake.realtime) == (0, {0}, 0)


def test_cpus_the_machine_lacks_leave_the_process_on_all() -> None:
    fake = FakeOs(cpus={0, 1})
    warnings = apply_priority(ProcessPriority(cpus=(4, 5)), fake.calls()).warnings
    assert len(warnings) == 1 and "none of them is available" in warnings[0]
    assert fake.cpus == {0, 1}
    assert apply_priority(None, fake.calls()).warnings == []


def test_a_process_asking_for_no_real_time_drops_the_one_it_inherited() -> None:
    """A service started by ``racestack up`` (whose launcher runs at the hub's real-time
    priority): telemetry asks for nice 10 and no real time, and gets exactly that."""
    fake = FakeOs(nice=-10, realtime=10)
    report = apply_priority(ProcessPriority(nice=10), fake.calls())
    assert report.warnings == report.notes == []
    assert (fake.nice, fake.realtime) == (10, 0)
    fake = FakeOs(nice=-10, realtime=10)
    apply_priority(ProcessPriority(), fake.calls())  # nice 0 asked for: 0, not the -10
    assert (fake.nice, fake.realtime) == (0, 0)
    fake = FakeOs(realtime=10, deny=("normal",))
    warnings = apply_priority(ProcessPriority(), fake.calls()).warnings
    assert len(warnings) == 1 and "inherited" in warnings[0]


def test_a_wakeup_latency_is_one_request_and_without_the_right_one_line() -> None:
    fake = FakeOs()
    assert apply_priority(ProcessPriority(wakeup_latency_us=0), fake.calls()).warnings == []
    assert fake.wakeup_us == [0]
    assert apply_priority(ProcessPriority(), fake.calls()).warnings == []
    assert fake.wakeup_us == [0]  # None: no request
    for deny, why in (("wakeup", "needs root"), ("wakeup_missing", "not supported")):
        fake = FakeOs(deny=(deny,))
        report = apply_priority(ProcessPriority(wakeup_latency_us=5), fake.calls())
        assert len(report.warnings) == 1 and why in report.warnings[0], report.warnings
        assert "wake-up latency limit 5 us not permitted" in report.warnings[0]
        report = apply_priority(
            ProcessPriority(wakeup_latency_us=5, wakeup_latency_if_permitted=True),
            fake.calls())
        assert report.warnings == [] and len(report.notes) == 1
    with pytest.raises(ConfigError):
        config_from_dict({"processes": {"planner": {"wakeup_latency_us": -1}}})


WAKEUP = """
import os, struct, sys
from shared.config.processes import ProcessPriority
from shared.priority import CPU_LATENCY_DEVICE, apply_priority
report = apply_priority(ProcessPriority(wakeup_latency_us=7))
if report.warnings:
    print("not permitted")
    sys.exit(0)
with open(CPU_LATENCY_DEVICE, "rb") as dev:  # the kernel's target: the smallest request
    print("held", struct.unpack("=i", dev.read(4))[0])
"""


def test_a_wakeup_latency_request_is_held_by_the_process_that_asked() -> None:
    """On the machine's own kernel, in a throw-away process: the request is made and held
    (the kernel then reports at most the smallest request of all processes)."""
    import subprocess
    import sys
    from pathlib import Path

    root = Path(__file__).resolve().parents[2]
    done = subprocess.run([sys.executable, "-c", WAKEUP], capture_output=True, text=True,
                          timeout=60, cwd=root)
    assert done.returncode == 0, done.stderr
    if done.stdout.strip() == "not permitted":
        pytest.skip("no PM QoS device this process may write (needs root and Linux)")
    word, value = done.stdout.split()
    assert word == "held" and int(value) <= 7, done.stdout


CHILD = """
import os, sys
from shared.config.processes import NICED
from shared.priority import apply_priority
apply_priority(NICED)
print(os.sched_getscheduler(0) == os.SCHED_OTHER, os.getpriority(os.PRIO_PROCESS, 0))
"""

PARENT = """
import os, subprocess, sys
from shared.config.processes import CRITICAL
from shared.priority import apply_priority
report = apply_priority(CRITICAL)
if report.notes or report.warnings:
    print("not permitted")
    sys.exit(0)
print(os.sched_getscheduler(0) == os.SCHED_RR)
out = subprocess.run([sys.executable, "-c", sys.argv[1]], capture_output=True, text=True,
                     timeout=60).stdout
print(out.strip())
"""


def test_a_real_time_parent_s_niced_child_runs_at_normal_scheduling() -> None:
    """On the machine's own scheduler, in two throw-away processes (the test process keeps
    its scheduling): a parent at the critical path's priority starts a child that applies
    telemetry's settings; the child is ``SCHED_OTHER`` at nice 10."""
    import subprocess
    import sys
    from pathlib import Path

    root = Path(__file__).resolve().parents[2]
    done = subprocess.run([sys.executable, "-c", PARENT, CHILD], capture_output=True,
                          text=True, timeout=120, cwd=root)
    assert done.returncode == 0, done.stderr
    lines = done.stdout.split("\n")
    if lines[0] == "not permitted":
        pytest.skip("real-time priority not permitted here (needs CAP_SYS_NICE or ulimit -r)")
    assert lines[0] == "True", done.stdout
    assert lines[1] == "True 10", done.stdout
