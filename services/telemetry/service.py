"""The telemetry service: every key of the car in, a Rerun recording (and live stream) out.

``python -m services.telemetry --config FILE [--out DIR] [--serve PORT] [--viewer]``

* Records to ``DIR/telemetry.0000.rrd``, ``telemetry.0001.rrd``, ... (default
  ``<[telemetry] runs_dir>/<YYYYmmdd-HHMMSS>/``; never overwritten: ``telemetry-2.0000.rrd``
  ...), one segment per ``segment_interval_s``, each closed with its footer and holding the
  default layout (also saved as ``telemetry.rbl``); at exit the counters in
  ``telemetry_stats.json`` (``services.telemetry.recording``).
* ``--serve PORT`` also serves the stream live on ``[telemetry] serve_bind_ip`` (loopback by
  default) and prints the ``rerun --connect ...`` line; ``--viewer`` spawns a viewer
  connected to it, only when a display exists.
* One subscription per key hands decoded records to an ``Inbox`` without waiting (Zenoh's
  threads are never blocked); this thread is the only one that logs. When it cannot keep up
  the oldest data messages are dropped and counted per key; lap and log events never are.
* The recording is flushed every ``flush_interval_s``; SIGINT / SIGTERM close it cleanly.
  Garbage on any key is dropped by the bus, noted in the recording and, like every
  service, reported on ``events/log`` (the base's ``DropReporter``: rejected payloads and
  own faults, at most once per ``REPORT_PERIOD_S``).
"""

from __future__ import annotations

import argparse
import functools
import threading

from services.telemetry.inbox import Inbox
from services.telemetry.recording import RunRecording, start_recording
from shared.bus import Bus
from shared.config import RacestackConfig
from shared.keys import EVENTS_LOG, TOPIC_TYPES
from shared.messages import REGISTRY, LogEvent, LogLevelName
from shared.service import Service, publishes, subscribes

#: How often the drop / queue counters are noted in the recording [s].
STATS_INTERVAL_S = 1.0
#: Period of the logging loop [s]: messages are handled in batches this often.
LOOP_PERIOD_S = 0.02


class TelemetryService(Service):
    """Subscribes to every key of the car and logs what arrives into one recording."""

    NAME = "telemetry"
    PORTS = (
        *(subscribes(suffix, REGISTRY[tag]) for suffix, tag in TOPIC_TYPES.items()),
        publishes(EVENTS_LOG, LogEvent),
    )
    PERIOD_S = LOOP_PERIOD_S

    def __init__(self, bus: Bus, recording: RunRecording, cfg: RacestackConfig) -> None:
        super().__init__(bus)
        self.recording = recording
        self.settings = cfg.telemetry
        self.inbox = Inbox(self.settings.queue_size, self.settings.event_queue_max,
                           max_age_s=self.settings.max_queue_age_s)
        self._dropped_said = 0  # inbox drops already said on events/log
        self.subs = {
            suffix: self.subscribe(suffix, functools.partial(self.inbox.put, suffix))
            for suffix in TOPIC_TYPES
        }

    def seq_gaps(self) -> dict[str, int]:
        """Records missed per key suffix, by sequence numbers."""
        return {s: sub.seq_gaps for s, sub in self.subs.items()}

    def serve(self, stop: threading.Event) -> int:
        """Log what arrives in batches every ``period_s`` until `stop`; note the counters
        every ``STATS_INTERVAL_S`` (and report rejections on ``events/log``), flush every
        ``flush_interval_s``, start a new segment every ``segment_interval_s``."""
        recording, inbox = self.recording, self.inbox
        self.log.info("recording %s/** on %s", self.keys.prefix, recording.rrd)
        next_stats = next_flush = self.clock()
        next_segment = next_stats + self.settings.segment_interval_s
        while not stop.is_set():
            tick = self.clock()
            recorder = recording.recorder
            for item in inbox.get_batch(timeout_s=self.period_s):
                recorder.handle(item.suffix, item.msg, item.recv_wall_s)
            recorder.periodic()
            self.report()
            now = self.clock()
            if now >= next_segment:
                next_segment = now + self.settings.segment_interval_s
                closed = recording.rotate()
                self.log.info("segment %s closed; recording on %s", closed.name, recording.rrd)
            if now >= next_stats:
                next_stats = now + STATS_INTERVAL_S
                recorder.note_rejected(self.bus.drops.snapshot())
                dropped = inbox.dropped()
                recorder.note_queue(len(inbox), dropped, self.seq_gaps())
                self._say_queue_drops(dropped)
            if now >= next_flush:
                next_flush = now + self.settings.flush_interval_s
                recorder.flush()
                recording.flush()
            rest = self.period_s - (self.clock() - tick)
            if rest > 0.0:  # work in batches: fewer wake-ups, cheaper per message
                stop.wait(rest)
        return 0

    def _say_queue_drops(self, dropped: dict[str, int]) -> None:
        """Say on ``events/log`` (at most once per ``event_interval_s``) that the inbox
        dropped data messages since the last time (it could not keep up)."""
        total = sum(dropped.values())
        if total > self._dropped_said and self.say(
            LogLevelName.WARNING,
            f"overloaded: dropped {total - self._dropped_said} of the oldest data messages "
            f"(total {total}): " + ", ".join(f"{k} x{n}" for k, n in sorted(dropped.items())),
            limit="queue_drop",
        ):
            self._dropped_said = total

    def close(self) -> None:
        """The bus is closed, nothing arrives any more: log what is queued, write the stats."""
        self.recording.finish(self.inbox, self.bus.drops.snapshot(), self.seq_gaps())

    @classmethod
    def body(cls, cfg: RacestackConfig, args: argparse.Namespace, stop: threading.Event) -> int:
        """Open the recording (a port that cannot be served is an error before the bus
        opens), host the service, flush and disconnect the recording whatever happens."""
        run = start_recording(cfg, args.out, args.serve, args.viewer)
        try:
            return cls.host(cfg.bus, stop, lambda bus: cls(bus, run, cfg))
        finally:
            run.close()

    @staticmethod
    def add_args(ap: argparse.ArgumentParser) -> None:
        """``--out``, ``--serve``, ``--viewer``."""
        ap.add_argument("--out", metavar="DIR",
                        help="run folder to record into (default: <runs_dir>/<timestamp>)")
        ap.add_argument("--serve", metavar="PORT", type=int,
                        help="also serve the live stream on this port ([telemetry] serve_bind_ip)")
        ap.add_argument("--viewer", action="store_true",
                        help="spawn a Rerun viewer on the live stream (only with a display)")


main = TelemetryService.main
