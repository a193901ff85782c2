"""The fake Hokuyo's I/O shell: ``FakeHokuyoModel`` on a pty or on a loopback TCP port.

``FakeHokuyo(transport="pty")`` opens a pty pair (raw mode) and points a stable symlink
(``address``) at the slave, as a USB UTM-30LX appears as ``/dev/ttyACM0``;
``transport="tcp"`` listens on ``127.0.0.1`` (``address`` = ``tcp://127.0.0.1:PORT``) and
serves one client at a time, as the Ethernet models do on port 10940. One daemon thread
reads requests, writes the model's answers and streams its scans when due; every
descriptor is touched on that thread only (requests from others are queued to it).

Faults: ``inject(data)`` writes raw bytes now; ``set(garbage=..., corrupt=..., truncate=...,
silent=...)`` changes the model; ``unplug()`` removes the symlink and closes the pty (TCP:
closes the client and stops listening); ``replug()`` brings it back.

``sent`` lists ``(scan number, time.monotonic() after its last byte was written)`` for the
latency benchmark.
"""

from __future__ import annotations

import contextlib
import os
import select
import socket
import threading
import time
import tty
from collections.abc import Sequence
from pathlib import Path
from typing import Any, Literal

import numpy as np

from shared.fake_thread import FakeDevice, RequestPipe, pty_available  # noqa: F401 (re-exported)
from shared.hokuyo.fake import FakeHokuyoModel

_IDLE_POLL_S = 0.05
#: Longest a write may wait for a slow reader before the rest is dropped [s].
_WRITE_WAIT_S = 0.2




class FakeHokuyo(FakeDevice):
    """A Hokuyo stand-in (module docstring); a context manager, or call ``close()``.

    Args:
        scans, intensities, scan_period_s, clock_start_ms, params: see ``FakeHokuyoModel``.
        transport: "pty" or "tcp".
        link_dir: folder of the pty symlink (default: a new temporary folder).
        port: TCP port (default: a free one).
    """

    def __init__(
        self,
        scans: Sequence[np.ndarray],
        *,
        transport: Literal["pty", "tcp"] = "pty",
        intensities: Sequence[np.ndarray] | None = None,
        scan_period_s: float | None = None,
        clock_start_ms: int = 0,
        params: dict[str, object] | None = None,
        link_dir: str | Path | None = None,
        port: int = 0,
    ) -> None:
        self.model = FakeHokuyoModel(
            scans,
            intensities=intensities,
            params=params,
            scan_period_s=scan_period_s,
            clock_start_ms=clock_start_ms,
        )
        self.transport = transport
        self._t0 = time.monotonic()
        self._lock = threading.RLock()
        self.sent: list[tuple[int, float]] = []
        self.bytes_dropped = 0
        self.connections = 0  #: TCP clients accepted / pty plugs
        self.thread_error: BaseException | None = None
        self._master: int | None = None
        self._slave: int | None = None
        self._listen: socket.socket | None = None
        self._client: socket.socket | None = None
        self._port = port
        if transport == "pty":
            self._init_device("the fake Hokuyo", link_dir or None, "fake-hokuyo")
            self.address = str(self._dir / "hokuyo")
        elif transport == "tcp":
            self._init_device("the fake Hokuyo", ".", "fake-hokuyo")
            self.address = ""
        else:
            raise ValueError(f"transport must be 'pty' or 'tcp', not {transport!r}")
        self._plug()
        self._start("fake-hokuyo")

    # -- public API ---------------------------------------------------------------------------
    def now_s(self) -> float:
        """The fake's time [s] (since it was created)."""
        return time.monotonic() - self._t0

    def set(self, **changes: Any) -> None:
        """Set model attributes (``garbage``, ``corrupt``, ``truncate``, ``silent``, ...)."""
        with self._lock:
            for name, value in changes.items():
                if not hasattr(self.model, name):
                    raise AttributeError(name)
                setattr(self.model, name, value)
        self._wake()

    @property
    def scans_sent(self) -> int:
        """Scans sent so far."""
        with self._lock:
            return self.model.scans_sent

    @property
    def requests(self) -> list[bytes]:
        """A copy of the request lines received so far."""
        with self._lock:
            return list(self.model.requests)

    def inject(self, data: bytes) -> None:
        """Write raw bytes to the client now."""
        self._request(lambda: self._write(data))

    def unplug(self) -> None:
        """Pull the cable (pty: symlink removed, pty closed; TCP: client closed, no listener)."""
        self._request(self._unplug)

    def replug(self) -> None:
        """Plug back in (pty: a new pty behind the symlink; TCP: listening again)."""
        self._request(self._plug)

    # -- the thread's side ----------------------------------------------------------------------
    def _plug(self) -> None:
        if self.transport == "pty":
            if self._master is not None:
                return
            master, slave = os.openpty()
            tty.setraw(slave)
            os.set_blocking(master, False)
            self._master, self._slave = master, slave
            tmp = f"{self.address}.tmp"
            with contextlib.suppress(FileNotFoundError):
                os.unlink(tmp)
            os.symlink(os.ttyname(slave), tmp)
            os.replace(tmp, self.address)
            self.connections += 1
        else:
            if self._listen is not None:
                return
            s = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
            s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            s.bind(("127.0.0.1", self._port))
            s.listen(1)
            s.setblocking(False)
            self._port = s.getsockname()[1]
            self._listen = s
            self.address = f"tcp://127.0.0.1:{self._port}"
        with self._lock:
            self.model.reset_link()

    def _unplug(self) -> None:
        if self.transport == "pty":
            with contextlib.suppress(FileNotFoundError):
                os.unlink(self.address)
            for fd in (self._master, self._slave):
                if fd is not None:
                    with contextlib.suppress(OSError):
                        os.close(fd)
            self._master = self._slave = None
        else:
            self._drop_client()
            if self._listen is not None:
                self._listen.close()
                self._listen = None

    def _drop_client(self) -> None:
        if self._client is not None:
            with contextlib.suppress(OSError):
                self._client.close()
            self._client = None

    def _out_fd(self) -> int | None:
        if self.transport == "pty":
            return self._master
        return self._client.fileno() if self._client is not None else None

    def _write(self, data: bytes) -> bool:
        """Write all of ``data`` (waiting up to ``_WRITE_WAIT_S`` for a slow reader)."""
        fd = self._out_fd()
        if fd is None or not data:
            self.bytes_dropped += len(data)
            return False
        view = memoryview(data)
        deadline = time.monotonic() + _WRITE_WAIT_S
        while view:
            try:
                n = os.write(fd, view) if self.transport == "pty" else self._client.send(view)  # type: ignore[union-attr]
            except BlockingIOError:
                n = 0
            except OSError:
                if self.transport == "tcp":
                    self._drop_client()
                self.bytes_dropped += len(view)
                return False
            view = view[n:]
            if view:
                left = deadline - time.monotonic()
                if left <= 0:
                    self.bytes_dropped += len(view)
                    return False
                select.select([], [fd], [], left)
        return True

    def _run(self) -> None:
        try:
            while not self._stop.is_set():
                self._requests.serve()
                self._step()
        except BaseException as exc:  # kept for the tests to see
            self.thread_error = exc

    def _step(self) -> None:
        fds = [self._requests.wake_fd]
        if self.transport == "pty" and self._master is not None:
            fds.append(self._master)
        if self.transport == "tcp":
            if self._listen is not None:
                fds.append(self._listen.fileno())
            if self._client is not None:
                fds.append(self._client.fileno())
        with self._lock:
            due = self.model.next_due_s()
        wait = _IDLE_POLL_S if due is None else max(0.0, min(_IDLE_POLL_S, due - self.now_s()))
        ready, _, _ = select.select(fds, [], [], wait)
        if self._requests.wake_fd in ready:
            self._requests.drain()
        if self._listen is not None and self._listen.fileno() in ready:
            with contextlib.suppress(BlockingIOError):
                conn, _ = self._listen.accept()
                conn.setblocking(False)
                conn.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
                self._drop_client()  # one client at a time, the newest wins
                self._client = conn
                self.connections += 1
                with self._lock:
                    self.model.reset_link()
        fd = self._out_fd()
        if fd is not None and fd in ready:
            data = self._read(fd)
            if data:
                with self._lock:
                    answer = self.model.receive(data, self.now_s())
                self._write(answer)
        with self._lock:
            scan = self.model.due(self.now_s())
            number = self.model.scans_sent
        if scan:
            if self._write(scan):
                self.sent.append((number - 1, time.monotonic()))

    def _read(self, fd: int) -> bytes:
        try:
            if self.transport == "pty":
                return os.read(fd, 4096)
            data = self._client.recv(4096)  # type: ignore[union-attr]
        except BlockingIOError:
            return b""
        except OSError:
            if self.transport == "tcp":
                self._drop_client()
            return b""
        if not data:  # the client hung up
            self._drop_client()
        return data
