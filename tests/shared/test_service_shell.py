"""The common service shell's worker thread: crashes end the service, shutdown is quiet."""

from __future__ import annotations

import threading

import pytest

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
