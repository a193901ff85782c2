"""Telemetry: record every run to a Rerun ``.rrd`` file and optionally stream it live.

- ``recorder``: the transport-free core (decoded records + key -> Rerun log calls).
- ``inbox``: the hand-over between Zenoh's threads and the one logging thread (bounded,
  drops the oldest data, never drops lap / log events).
- ``blueprint``: the default viewer layout shipped with the recordings.
- ``recording``: one run on disk (folder, ``.rrd``, live stream, stats).
- ``service``: the Zenoh shell (``python -m services.telemetry``).
- ``report``: reads a recording back into the lap table and figures of
  ``shared.evaluation``.
"""

from __future__ import annotations

from collections.abc import Sequence


def report_main(argv: Sequence[str] | None = None) -> int:
    """``racestack report`` (``services.telemetry.report.main``, imported when called: it
    reads recordings with Rerun and draws with matplotlib)."""
    from services.telemetry.report import main

    return int(main(argv))


__all__ = ["report_main"]
