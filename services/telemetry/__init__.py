"""Telemetry: record every run to a Rerun ``.rrd`` file and optionally stream it live.

- ``recorder``: the transport-free core (decoded records + key -> Rerun log calls).
- ``inbox``: the hand-over between Zenoh's threads and the one logging thread (bounded,
  drops the oldest data, never drops lap / log events).
- ``blueprint``: the default viewer layout shipped with the recordings.
- ``recording``: one run on disk (folder, ``.rrd``, live stream, stats).
- ``service``: the Zenoh shell (``python -m services.telemetry``).
- ``report``: reads a recording back into the lap table and figures of
  ``shared.evaluation``.
- ``rrd_files``: the files of a recording (segments ``telemetry.0000.rrd``, ... or an old
  single ``telemetry.rrd``) and reading one by streaming, also when cut off by a crash.
"""

from __future__ import annotations

from collections.abc import Sequence

from services.telemetry.rrd_files import find_segments


def report_main(argv: Sequence[str] | None = None) -> int:
    """``racestack report`` (``services.telemetry.report.main``, imported when called: it
    reads recordings with Rerun and draws with matplotlib)."""
    from services.telemetry.report import main

    return int(main(argv))


__all__ = ["find_segments", "report_main"]
