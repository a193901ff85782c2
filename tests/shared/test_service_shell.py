"""The common service shell's worker thread: crashes end the service, shutdown is quiet, a
record of its own that fails validation is counted and the loop goes on."""

from __future__ import annotations

import threading

import pytest

from shared.bus import FaultCounter
from shared.messages import DriveCmd
from shared.service_shell import Worker


def test_a_crashing_worker_sets_stop_and_its_error_reaches_the_main_thread() -> None:
    stop = threading.Event()

    def loop() -> None:
        raise RuntimeError("solver exploded")

    w = Worker("w", loop, stop).start()
    assert stop.wait(5.0)
    with pytest.raises(RuntimeError, match="solver exploded"):
        w.join(5.0)
    with pytest.raises(RuntimeError):
        w.check()


def test_an_error_after_stop_is_only_logged_and_a_clean_end_is_silent() -> None:
    stop = threading.Event()
    release = threading.Event()

    def loop() -> None:
        release.wait(5.0)
        raise OSError("session closed under me")  # what a shutdown can look like

    w = Worker("w", loop, stop).start()
    assert w.alive
    stop.set()
    release.set()
    assert w.join(5.0) is True  # no exception
    w.check()
    clean = Worker("c", lambda: None, threading.Event()).start()
    assert clean.join(5.0) is True


def test_an_invalid_record_of_its_own_is_counted_and_the_loop_goes_on() -> None:
    stop = threading.Event()
    inputs = iter([1.0, float("nan"), 2.0, 99.0, 3.0])  # NaN and 99 m/s: invalid DriveCmds
    sent: list[DriveCmd] = []
    faults = FaultCounter()

    def loop() -> None:  # re-entrant: the input lives outside
        for speed in inputs:
            sent.append(DriveCmd(stamp_s=1.0, speed_mps=speed, steering_rad=0.0))

    w = Worker("w", loop, stop, faults=faults, fault_key="k/cmd").start()
    assert w.join(5.0) is True  # ended normally once the input was exhausted
    assert not stop.is_set()
    assert [c.speed_mps for c in sent] == [1.0, 2.0, 3.0]
    assert faults.snapshot() == {("k/cmd", "not_finite"): 1, ("k/cmd", "out_of_range"): 1}
    assert w.restarts == 2
    assert Worker("d", lambda: None, stop).fault_key == "worker/d"
