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
