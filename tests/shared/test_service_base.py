"""The one service base (``shared.service``): declared ports, the event log and its rate
limits, drop and fault reports, the watchdog, injectable clocks, the hosted life on Zenoh."""

from __future__ import annotations

import threading
import time

import pytest

from services.localization_bridge.service import BridgeService
from shared.bus import Bus
from shared.bus.fake import FakeBus
from shared.config.bus import BusSettings
from shared.config.localization import LocalizationSettings
from shared.keys import DRIVE_CMD, EVENTS_LOG, IMU, ODOM, POSE, STATE
from shared.messages import DriveCmd, LogEvent, Odom, Pose, State
from shared.net import free_loopback_port
from shared.service import Direction, Port, Service, contract_rows, publishes, subscribes


class Clock:
    """A clock the test moves by hand [s]."""

    def __init__(self, t: float = 100.0) -> None:
        self.t = t

    def __call__(self) -> float:
        return self.t


class Echo(Service):
    """A small service: drive commands in, events out."""

    NAME = "echo"
    PORTS = (subscribes(DRIVE_CMD, DriveCmd), publishes(EVENTS_LOG, LogEvent))
    PERIOD_S = 0.01

    def __init__(self, bus: Bus, **kw: object) -> None:
        super().__init__(bus, **kw)  # type: ignore[arg-type]
        self.ticks = 0
        self.closed_after_bus: bool | None = None

    def tick(self) -> None:
        self.ticks += 1

    def close(self) -> None:
        self.closed_after_bus = self.bus.closed


def _logs(bus: FakeBus) -> list[LogEvent]:
    return bus.sent(bus.keys.events_log, LogEvent)


def test_a_port_names_a_contract_key_with_its_message_type() -> None:
    assert publishes(STATE, State) == Port(STATE, State, Direction.PUBLISH)
    with pytest.raises(ValueError, match="unknown key suffix"):
        subscribes("no/such/key", State)
    with pytest.raises(ValueError, match="carries State"):
        publishes(STATE, Pose)
    with pytest.raises(TypeError, match="twice"):

        class Twice(Service):
            NAME = "twice"
            PORTS = (publishes(STATE, State), publishes(STATE, State))

    with pytest.raises(ValueError, match="service name"):

        class BadName(Service):
            NAME = "bad name"


def test_only_declared_ports_can_be_used() -> None:
    svc = Echo(FakeBus())  # type: ignore[arg-type]
    svc.subscribe(DRIVE_CMD)
    with pytest.raises(ValueError, match="does not declare publish 'state'"):
        svc.publisher(STATE)
    with pytest.raises(ValueError, match="does not declare subscribe 'vehicle/pose'"):
        svc.subscribe(POSE)
    assert svc.publisher(EVENTS_LOG) is svc.log_pub  # one publisher per key


def test_say_logs_and_publishes_with_the_wall_clock_and_rate_limits_by_kind() -> None:
    bus = FakeBus()
    mono, wall = Clock(), Clock(1.7e9)
    svc = Echo(bus, clock=mono, wall_clock=wall, event_interval_s=1.0)  # type: ignore[arg-type]
    assert svc.say("info", "hello")
    said = _logs(bus)[-1]
    assert (said.level, said.source, said.text, said.stamp_s) == ("info", "echo", "hello", 1.7e9)
    assert svc.say("warning", "port lost", limit="port")
    assert not svc.say("warning", "port lost", limit="port")  # within the interval
    assert not svc.say("warning", "port lost", limit="port")
    assert svc.say("warning", "other kind", limit="other")  # kinds are limited apart
    mono.t += 1.0
    assert svc.say("warning", "port lost", limit="port")
    assert _logs(bus)[-1].text == "port lost (2 more since the last report)"
    assert svc.say("error", "x" * 20_000)  # cut to the contract's length, never raised
    assert len(_logs(bus)[-1].text) == 8192
    assert bus.faults.total == 0


def test_drops_and_own_faults_are_reported_on_events_log() -> None:
    bus = FakeBus()
    clock = Clock()
    svc = Echo(bus, clock=clock, report_period_s=1.0)  # type: ignore[arg-type]
    assert not svc.report()  # nothing grew
    bus.drops.record("racestack/car0/cmd/drive", "not_msgpack")
    bus.faults.record("racestack/car0/state", "out_of_range")
    assert not svc.report()  # not due yet
    clock.t += 1.0
    assert svc.report()
    texts = [m.text for m in _logs(bus)]
    assert texts[-2].startswith("rejected 1 messages") and "not_msgpack x1" in texts[-2]
    assert texts[-1].startswith("own faults: 1") and "out_of_range x1" in texts[-1]


def test_the_watchdog_ticks_and_a_crashed_worker_ends_the_service() -> None:
    svc = Echo(FakeBus())  # type: ignore[arg-type]
    stop = threading.Event()
    svc.poll()
    assert svc.ticks == 1

    def crash() -> None:
        raise RuntimeError("worker exploded")

    svc.start_worker("crasher", crash, stop)
    with pytest.raises(RuntimeError, match="worker exploded"):
        svc.serve(stop)  # the worker set stop; the error reaches the main thread
    assert stop.is_set()


def test_a_service_without_events_log_only_logs_locally() -> None:
    class Quiet(Service):
        NAME = "quiet"

    bus = FakeBus()
    svc = Quiet(bus)  # type: ignore[arg-type]
    assert svc.log_pub is None and svc.reporter is None
    assert svc.say("info", "here only") and not bus.raws
    assert not svc.report()


def test_contract_rows_gather_the_declarations() -> None:
    rows = contract_rows([Echo, BridgeService])
    assert rows[DRIVE_CMD].subscribers == ("echo",)
    assert rows[STATE].publishers == ("localization_bridge",)
    assert rows[EVENTS_LOG].publishers == ("echo", "localization_bridge")
    assert rows[POSE].msg_type is Pose


def test_the_bridge_takes_its_localization_settings_and_declares_its_inputs() -> None:
    """The bridge publishes at a fixed rate (tests/localization/test_bridge.py); here only
    that the service base hosts it with the [localization] settings and its ports."""
    bus = FakeBus()
    settings = LocalizationSettings(filter="passthrough", max_prediction_s=0.0)
    svc = BridgeService(bus, settings)  # type: ignore[arg-type]
    assert svc.settings is settings
    assert not svc.current_state().valid  # nothing before the first pose
    svc.on_odom(Odom(stamp_s=time.time(), speed_mps=2.0, steering_rad=0.1))
    svc.on_pose(Pose(stamp_s=time.time(), x_m=1.0, y_m=2.0, yaw_rad=0.3))
    st = svc.current_state()
    assert st.valid and (st.x_m, st.speed_mps) == (1.0, 2.0)  # no prediction
    assert {ODOM, POSE, IMU} <= {p.suffix for p in BridgeService.PORTS}


def test_hosted_on_zenoh_it_announces_after_subscribing_and_closes_after_the_bus() -> None:
    settings = BusSettings(car="svcbase", listen=[f"tcp/127.0.0.1:{free_loopback_port()}"])

    class Hub(Echo):
        NAME = "echo_hub"
        LISTEN_DEFAULT = True

    made: list[Hub] = []
    stop = threading.Event()

    def factory(bus: Bus) -> Hub:
        svc = Hub(bus)
        svc.subscribe(DRIVE_CMD)
        made.append(svc)
        return svc

    codes: list[int] = []
    host = threading.Thread(
        target=lambda: codes.append(Hub.host(settings, stop, factory)), daemon=True
    )
    host.start()
    try:
        with Bus(settings, "watcher") as watcher:
            assert watcher.wait_alive(["echo_hub"], timeout_s=10.0)
            pub = watcher.publisher(watcher.keys.drive_cmd, DriveCmd)
            assert pub.wait_matching(10.0)  # subscribed before it was alive
            stop.wait(0.2)  # a few watchdog periods
    finally:
        stop.set()
        host.join(10.0)
    assert not host.is_alive() and codes == [0]
    svc = made[0]
    assert svc.ticks > 0 and svc.closed_after_bus is True
