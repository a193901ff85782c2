"""Raw bytes on arbitrary Zenoh keys through the service's bus session (the shell's I/O).

The contract's publishers and subscriptions (``shared.bus``) carry msgpack records below
``racestack/<car>/``; the ROS 2 keys carry CDR anywhere (``odom``, ``0/odom/...``). This
module uses the open session of the service's ``Bus`` (``bus.session``) for those, without
importing zenoh itself (only ``shared.bus.session`` does): a subscriber callback receives the key
and the payload bytes, a publisher puts bytes with an optional attachment.

Callbacks run on Zenoh's thread: the gateway only enqueues there. An exception in a
callback is caught and counted (``callback_errors``), never raised into Zenoh.
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from typing import Any

log = logging.getLogger(__name__)


class RawSubscriber:
    """A subscriber of raw payloads on a key expression (``close`` undeclares it)."""

    def __init__(self, session: Any, key: str, on_payload: Callable[[str, bytes], None]) -> None:
        """Subscribe ``on_payload(key, payload)`` to ``key`` on ``session``."""
        self.key = key
        self.callback_errors = 0
        self._on_payload = on_payload
        self._sub = session.declare_subscriber(key, self._on_sample)

    def _on_sample(self, sample: Any) -> None:
        try:
            self._on_payload(str(sample.key_expr), sample.payload.to_bytes())
        except Exception as exc:  # never into Zenoh's thread
            self.callback_errors += 1
            log.warning("raw subscriber %s: callback failed: %s", self.key, exc)

    def close(self) -> None:
        """Undeclare (idempotent; a closed session is fine)."""
        try:
            self._sub.undeclare()
        except Exception:
            pass


class RawPublisher:
    """A publisher of raw payloads on one key."""

    def __init__(self, session: Any, key: str) -> None:
        """Declare the publisher of ``key`` on ``session``."""
        self.key = key
        self._pub = session.declare_publisher(key)

    def put(self, payload: bytes, attachment: bytes | None = None) -> None:
        """Publish ``payload`` (with ``attachment`` if given)."""
        if attachment is None:
            self._pub.put(payload)
        else:
            self._pub.put(payload, attachment=attachment)

    def close(self) -> None:
        """Undeclare (idempotent; a closed session is fine)."""
        try:
            self._pub.undeclare()
        except Exception:
            pass


class RawToken:
    """A liveliness token on an arbitrary key (rmw_zenoh's graph; it lives until ``close``
    or the session closes)."""

    def __init__(self, session: Any, key: str) -> None:
        """Declare the token `key` on `session`."""
        self.key = key
        self._token = session.liveliness().declare_token(key)

    def close(self) -> None:
        """Undeclare (idempotent; a closed session is fine)."""
        try:
            self._token.undeclare()
        except Exception:
            pass


def session_zid(session: Any) -> str:
    """The Zenoh session id of `session` as hex (``session.info.zid()``); a random one for a
    session that has none (a test's fake)."""
    try:
        return str(session.info.zid())
    except Exception:
        import os

        return os.urandom(16).hex()
