"""Loopback networking helpers shared by the services, the launcher, tests and benchmarks."""

from __future__ import annotations

import socket


def free_loopback_port() -> int:
    """A TCP port on 127.0.0.1 that was free a moment ago (bound to port 0, then released),
    for the endpoints of processes started by tests and benchmarks and for a live stream."""
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def loopback_port_taken(port: int) -> bool:
    """True when something already listens on (or holds) TCP 127.0.0.1:`port`, so a server
    of ours could not bind it."""
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        try:
            s.bind(("127.0.0.1", port))
        except OSError:
            return True
    return False
