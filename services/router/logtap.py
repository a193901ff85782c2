"""Read this process's stdout, where Zenoh's own log goes, and count access-control denials.

Zenoh's Rust log (``shared.bus.enable_zenoh_log``) is written to file descriptor 1. The tap
replaces fd 1 with a pipe; a thread reads it, hands every access-control line to a
``DenialParser`` (those lines are not passed on: one per routed message), hands the TLS
link's accept lines (one per connection, the certificate's common name) to it too, and writes
every other line, those included, to the original stdout. ``close`` puts the original
stdout back. The pipe is enlarged to 1 MiB so a slow reader does not stall Zenoh's threads
at once.
"""

from __future__ import annotations

import fcntl
import logging
import os
import threading

from services.router.denials import ACL_TARGET, LINK_TARGET, DenialCounter, DenialParser

log = logging.getLogger(__name__)

#: Linux F_SETPIPE_SZ (not in the fcntl module of every Python).
_F_SETPIPE_SZ = 1031
_PIPE_BYTES = 1 << 20


class StdoutTap:
    """Owns fd 1 while open (one per process); ``counter`` holds the denials."""

    def __init__(self, counter: DenialCounter | None = None) -> None:
        self.counter = counter or DenialCounter()
        self.parser = DenialParser()
        self.errors = 0  #: lines the parser failed on (counted, skipped)
        self._orig = os.dup(1)
        r, w = os.pipe()
        try:
            fcntl.fcntl(w, _F_SETPIPE_SZ, _PIPE_BYTES)
        except OSError:  # pragma: no cover - not Linux, or capped by the system
            pass
        os.dup2(w, 1)
        os.close(w)
        self._r = r
        self._thread = threading.Thread(target=self._run, name="zenoh-log-tap", daemon=True)
        self._thread.start()

    def _run(self) -> None:
        buf = b""
        while True:
            try:
                chunk = os.read(self._r, 65536)
            except OSError:
                break
            if not chunk:
                break
            buf += chunk
            *lines, buf = buf.split(b"\n")
            passed = []
            for raw in lines:
                text = raw.decode("utf-8", "replace")
                if LINK_TARGET in text:  # one line per accepted TLS link: read and passed on
                    try:
                        self.parser.feed(text)
                    except Exception:
                        self.errors += 1
                    passed.append(raw + b"\n")
                elif ACL_TARGET in text:
                    try:
                        denial = self.parser.feed(text)
                    except Exception:  # never lose the tap to one odd line
                        self.errors += 1
                        continue
                    if denial is not None:
                        self.counter.add(denial)
                else:
                    passed.append(raw + b"\n")
            if passed:
                try:
                    os.write(self._orig, b"".join(passed))
                except OSError:
                    pass
        os.close(self._r)

    def close(self) -> None:
        """Put the original stdout back; the reader ends once every writer is gone."""
        try:
            os.dup2(self._orig, 1)
        except OSError:  # pragma: no cover
            log.exception("could not restore stdout")
        self._thread.join(1.0)
        os.close(self._orig)
