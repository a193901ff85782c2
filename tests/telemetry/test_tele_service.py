"""The telemetry shell on the in-process bus: its reports on ``events/log``."""

from __future__ import annotations

from shared.bus.fake import FakeBus
from shared.config import RacestackConfig
from shared.keys import EVENTS_LOG
from shared.messages import LogEvent


def test_tele_says_queue_drops_and_reports_rejections_on_events_log() -> None:
    from services.telemetry.service import TelemetryService

    bus = FakeBus()
    svc = TelemetryService(bus, None, RacestackConfig())  # type: ignore[arg-type]
    log_key = bus.keys.key(EVENTS_LOG)
    svc._say_queue_drops({"vehicle/pose": 3, "vehicle/imu": 1})
    svc._say_queue_drops({"vehicle/pose": 3, "vehicle/imu": 1})  # nothing new: said once
    texts = [e.text for e in bus.sent(log_key, LogEvent)]
    assert len(texts) == 1 and "dropped 4 of the oldest data messages" in texts[0]
    bus.drops.record(bus.keys.pose, "not_msgpack", "test")
    assert svc.report()  # the base's DropReporter: rejected payloads on events/log
    events = bus.sent(log_key, LogEvent)
    assert events[-1].source == "telemetry" and "rejected 1 messages" in events[-1].text
