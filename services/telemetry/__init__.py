"""Telemetry: record every run to a Rerun ``.rrd`` file and optionally stream it live.

- ``recorder``: the transport-free core (decoded records + key -> Rerun log calls).
- ``inbox``: the hand-over between Zenoh's threads and the one logging thread (bounded,
  drops the oldest data, never drops lap / log events).
- ``blueprint``: the default viewer layout shipped with the recordings.
- ``recording``: one run on disk (folder, ``.rrd``, live stream, stats).
- ``service``: the Zenoh shell (``python -m services.telemetry``).
- ``rrd_files``: the files of a recording (segments ``telemetry.0000.rrd``, ... or a
  single ``telemetry.rrd``) and reading one by streaming, also when cut off by a crash.

``racestack report`` (``services/tools/report.py``) reads a recording back.
"""

from __future__ import annotations

from services.telemetry.recorder import SIM_TIME, WALL_TIME, Recorder
from services.telemetry.recording import open_segment
from services.telemetry.rrd_files import find_segments, read_store

__all__ = ["SIM_TIME", "WALL_TIME", "Recorder", "find_segments", "open_segment", "read_store"]
