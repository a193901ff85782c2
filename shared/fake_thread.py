"""Plumbing of the fake devices' own threads (the fake VESC, the fake Hokuyo): test tools.

A fake device runs one thread that owns its file descriptors (pty, socket); the test's thread
hands it actions (write bytes, unplug, replug) through ``RequestPipe`` and waits for them.
The thread ``select``s on ``RequestPipe.wake_fd`` beside its device, calls ``drain()`` when it
is readable and ``serve()`` each round; an action's exception is raised in the caller.
"""

from __future__ import annotations

import contextlib
import os
import queue
import shutil
import tempfile
import threading
from collections.abc import Callable
from pathlib import Path
from typing import Self

#: Longest a request to the fake's thread may take before it is reported as failed [s].
REQUEST_TIMEOUT_S = 2.0


def pty_available() -> bool:
    """Whether this machine can open pseudo-terminals (what the pty fakes need)."""
    try:
        m, s = os.openpty()
    except OSError:
        return False
    os.close(m)
    os.close(s)
    return True


class _Reply:
    """Completion of a request handed to the fake's thread."""

    __slots__ = ("done", "error")

    def __init__(self) -> None:
        self.done = threading.Event()
        self.error: BaseException | None = None


class RequestPipe:
    """A queue of actions for a fake's thread plus the pipe that wakes its ``select``.

    Args:
        name: what the errors call the fake ("the fake VESC").
    """

    def __init__(self, name: str) -> None:
        self.name = name
        self._queue: queue.SimpleQueue[tuple[Callable[[], object], _Reply]] = queue.SimpleQueue()
        self._r, self._w = os.pipe()
        os.set_blocking(self._r, False)

    @property
    def wake_fd(self) -> int:
        """The read end: readable when a request (or a wake-up) is waiting."""
        return self._r

    def wake(self) -> None:
        """Make the thread's ``select`` return."""
        with contextlib.suppress(OSError):
            os.write(self._w, b"\x00")

    def drain(self) -> None:
        """Empty the wake pipe (the thread's side, when ``wake_fd`` was readable)."""
        with contextlib.suppress(BlockingIOError, OSError):
            os.read(self._r, 4096)

    def request(self, action: Callable[[], object], alive: bool) -> None:
        """Run `action` on the fake's thread and wait for it (the caller's side).

        Raises:
            RuntimeError: the fake is closed (`alive` False); TimeoutError: no answer
            within ``REQUEST_TIMEOUT_S``; whatever `action` raised.
        """
        if not alive:
            raise RuntimeError(f"{self.name} is closed")
        reply = _Reply()
        self._queue.put((action, reply))
        self.wake()
        if not reply.done.wait(REQUEST_TIMEOUT_S):
            raise TimeoutError(f"{self.name} thread did not answer")
        if reply.error is not None:
            raise reply.error

    def serve(self) -> None:
        """Run every waiting action (the thread's side); errors go to their callers."""
        while True:
            try:
                action, reply = self._queue.get_nowait()
            except queue.Empty:
                return
            try:
                action()
            except BaseException as exc:
                reply.error = exc
            reply.done.set()

    def close(self) -> None:
        """Close the pipe (after the thread has stopped)."""
        for fd in (self._r, self._w):
            with contextlib.suppress(OSError):
                os.close(fd)


class FakeDevice:
    """What the fake devices share around their thread: the request pipe, the stop flag,
    the thread itself and the folder of their stable link (removed on close if theirs).

    A subclass calls ``_init_device`` first in its ``__init__``, plugs its device, then
    ``_start``; it provides ``_run`` (the thread) and ``_unplug`` (release the device).
    """

    _requests: RequestPipe
    _stop: threading.Event
    _thread: threading.Thread
    _dir: Path
    _own_dir: bool

    def _init_device(self, name: str, link_dir: str | Path | None, prefix: str) -> None:
        """The request pipe named `name` and the link folder: `link_dir`, or a new
        temporary one named with `prefix` (removed by ``close``)."""
        self._requests = RequestPipe(name)
        self._stop = threading.Event()
        self._own_dir = link_dir is None
        self._dir = Path(link_dir) if link_dir is not None else Path(tempfile.mkdtemp(prefix))

    def _start(self, thread_name: str) -> None:
        """Start the fake's thread (``_run``)."""
        self._thread = threading.Thread(target=self._run, name=thread_name, daemon=True)
        self._thread.start()

    def _run(self) -> None:  # pragma: no cover - every fake has its own
        raise NotImplementedError

    def _unplug(self) -> None:  # pragma: no cover - every fake has its own
        raise NotImplementedError

    def close(self, timeout_s: float = 2.0) -> None:
        """Stop the thread (joined up to ``timeout_s`` [s]) and release everything: the
        device, the request pipe and (if the fake made it) the link folder."""
        if self._stop.is_set():
            return
        self._stop.set()
        self._wake()
        self._thread.join(timeout_s)
        self._unplug()
        self._requests.close()
        if self._own_dir:
            shutil.rmtree(self._dir, ignore_errors=True)

    def __enter__(self) -> Self:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def _wake(self) -> None:
        self._requests.wake()

    def _request(self, action: Callable[[], object]) -> None:
        """Run `action` on the fake's thread and wait for it (``RequestPipe.request``)."""
        self._requests.request(action, not self._stop.is_set() and self._thread.is_alive())
