"""A service's own invalid records are counted and reported, never raised (issue 10)."""

from __future__ import annotations

import logging
import math
from typing import Any

import pytest

from shared.bus import DropReporter, FaultCounter
from shared.bus.fake import FakeBus
from shared.messages import LogEvent, SimTruth, State


def _truth(**changes: Any) -> dict[str, Any]:
    fields = {
        "stamp_s": 4.0,
        "x_m": 1.0,
        "y_m": 1.0,
        "yaw_rad": 0.0,
        "speed_mps": 3.0,
        "yaw_rate_radps": 0.2,
        "slip_rad": 0.01,
        "steering_rad": 0.1,
        "s_m": 42.0,
        "e_con_m": 0.1,
        "off_track": False,
        "lap": 2,
    }
    return {**fields, **changes}


def test_try_put_sends_a_valid_record_and_counts_an_invalid_one() -> None:
    bus = FakeBus()
    pub = bus.publisher("k/truth", SimTruth)
    sent = pub.try_put(**_truth())
    assert sent is not None and sent.seq == 0 and len(bus.raws["k/truth"].sent) == 1
    assert pub.try_put(**_truth(slip_rad=3.3)) is None  # the crash of issue 10
    assert pub.try_put(**_truth(yaw_rate_radps=math.nan)) is None
    assert len(bus.raws["k/truth"].sent) == 1  # nothing invalid left
    assert bus.faults.snapshot() == {("k/truth", "out_of_range"): 1, ("k/truth", "not_finite"): 1}
    assert pub.try_put(**_truth()).seq == 1  # no sequence number spent on a refused record
    with pytest.raises(TypeError):  # a misspelt field is a programming error
        pub.try_put(**_truth(), slip=0.0)


def test_guard_counts_a_message_error_and_lets_others_through() -> None:
    faults = FaultCounter()
    with faults.guard("k/state"):
        State(
            stamp_s=1.0, x_m=2e4, y_m=0.0, yaw_rad=0.0, speed_mps=0.0,
            yaw_rate_radps=0.0, steering_rad=0.0, source_stamp_s=1.0, valid=True,
        )  # fmt: skip
        pytest.fail("not reached")
    assert faults.snapshot() == {("k/state", "out_of_range"): 1}
    with pytest.raises(RuntimeError), faults.guard("k/state"):
        raise RuntimeError("not a record fault")
    assert faults.total == 1


def test_fault_logging_is_rate_limited_at_error_level(caplog: pytest.LogCaptureFixture) -> None:
    t = [10.0]
    faults = FaultCounter(summary_interval_s=5.0, clock=lambda: t[0])
    with caplog.at_level(logging.WARNING, logger="racestack.bus"):
        for _ in range(50):
            faults.record("k", "out_of_range", "SimTruth.slip_rad: 3.3")
        assert len(caplog.records) == 1 and caplog.records[0].levelno == logging.ERROR
        assert "own fault on k: out_of_range" in caplog.records[0].getMessage()
        t[0] += 6.0
        faults.record("k", "out_of_range", "again")
        assert len(caplog.records) == 2 and "50 more own faults" in caplog.records[1].getMessage()


def test_drop_reporter_reports_own_faults_apart_from_rejected_messages() -> None:
    bus = FakeBus()
    t = [0.0]
    rep = DropReporter(bus, "simulator", period_s=1.0, clock=lambda: t[0])  # type: ignore[arg-type]
    assert not rep.poll()
    bus.drops.record("racestack/car0/cmd/drive", "not_msgpack")
    bus.faults.record("racestack/car0/sim/truth", "out_of_range", "slip")
    bus.faults.record("racestack/car0/sim/truth", "out_of_range", "slip")
    t[0] += 0.5
    assert not rep.poll()  # not due yet
    t[0] += 0.6
    assert rep.poll()
    logs = bus.sent(bus.keys.events_log, LogEvent)
    assert [m.level for m in logs] == ["warning", "error"] and rep.reports == 2
    assert logs[0].text.startswith("rejected 1 messages")
    assert logs[1].text == (
        "own faults: 2 (total 2), not published: racestack/car0/sim/truth out_of_range x2"
    )
    t[0] += 1.1
    assert not rep.poll()  # nothing new
    bus.faults.record("car state", "yaw_rate_out_of_range", "80 rad/s")
    t[0] += 1.1
    assert rep.poll()
    assert bus.sent(bus.keys.events_log, LogEvent)[-1].text == (
        "own faults: 1 (total 3), not published: car state yaw_rate_out_of_range x1"
    )
