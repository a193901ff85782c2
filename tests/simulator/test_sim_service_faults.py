"""The simulator service never dies of its own output (issue 10).

States beyond the message contract (slip 3.3 rad, yaw rate 80 rad/s, NaN) are fed to the
service: no exception escapes, the fault is counted in ``bus.faults`` and reported on
``events/log``, the car is reset where its state left the contract, and everything it
publishes decodes (the decoder validates: a record that decodes is within contract).

Most tests use ``shared.bus.fake.FakeBus`` (the real ``TypedPublisher`` over a recording
stand-in for ``zenoh.Publisher``); the last one runs the service's real-time loop on
a real loopback Zenoh session and watches it from a second session.
"""

from __future__ import annotations

import dataclasses
import faulthandler
import math
import sys
import threading
import time
from collections.abc import Callable, Iterator
from typing import Any

import pytest

from services.simulator import StepResult, centreline_pose, service
from services.simulator.limits import state_fault
from services.simulator.service import STATE_FAULT_KEY, SimulatorService, occupancy_for
from shared.angles import wrap_angle
from shared.bus import Bus
from shared.bus.fake import FakeBus
from shared.config import RacestackConfig, config_from_dict, load_config
from shared.config.bus import BusSettings
from shared.messages import DriveCmd, Imu, LogEvent, SimControl, SimTruth
from shared.net import free_loopback_port
from shared.track import OccupancyGrid, Track, load_track

H = 0.01  # the default integration step [s]


@pytest.fixture(autouse=True)
def _watchdog() -> Iterator[None]:
    """End the run with a traceback dump if one test hangs (threads, Zenoh sessions)."""
    faulthandler.dump_traceback_later(120.0, exit=True, file=sys.stderr)
    try:
        yield
    finally:
        faulthandler.cancel_dump_traceback_later()


@pytest.fixture(scope="module")
def cfg() -> RacestackConfig:
    return load_config(None)


@pytest.fixture(scope="module")
def track(cfg: RacestackConfig) -> Track:
    return load_track(cfg.track.source)


@pytest.fixture(scope="module")
def grid(track: Track) -> OccupancyGrid:
    return occupancy_for(track)  # seconds on a loaded machine: once per module


@pytest.fixture(autouse=True)
def _one_grid(monkeypatch: pytest.MonkeyPatch, grid: OccupancyGrid) -> None:
    monkeypatch.setattr(service, "occupancy_for", lambda _track: grid)


@pytest.fixture
def svc(cfg: RacestackConfig, track: Track) -> SimulatorService:
    return SimulatorService(cfg, FakeBus(), track)  # type: ignore[arg-type]


def _bus(svc: SimulatorService) -> FakeBus:
    return svc.bus  # type: ignore[return-value]


def _drive(svc: SimulatorService, steps: int, speed: float = 3.0) -> None:
    """A few steps with a fresh command each, so the car is rolling."""
    for _ in range(steps):
        svc.sim.set_command(speed, 0.0, svc.sim.t_s)
        res = svc.advance(H)
        assert res is not None
        svc.publish(res)


def _bad_step(svc: SimulatorService, **state_changes: float) -> Callable[..., StepResult]:
    """A stand-in for ``Simulator.step`` returning the true next step with a changed state."""
    real = svc.sim.step

    def step(command: Any = None, dt_s: float | None = None) -> StepResult:
        res = real(command, dt_s)
        return dataclasses.replace(res, state=dataclasses.replace(res.state, **state_changes))

    return step


def _truths(svc: SimulatorService) -> list[SimTruth]:
    return _bus(svc).sent(svc.bus.keys.sim_truth, SimTruth)


def _logs(svc: SimulatorService) -> list[LogEvent]:
    return _bus(svc).sent(svc.bus.keys.events_log, LogEvent)


def _assert_within_contract(t: SimTruth) -> None:
    # decoding validated every field; the angles are also wrapped
    assert -math.pi <= t.slip_rad <= math.pi and -math.pi <= t.yaw_rad <= math.pi
    assert abs(t.yaw_rate_radps) <= 50.0 and abs(t.speed_mps) <= 50.0


def test_state_fault_names_what_left_the_contract(svc: SimulatorService) -> None:
    st = svc.sim.state
    assert state_fault(st) is None
    assert state_fault(dataclasses.replace(st, slip_rad=3.3, yaw_rad=1e5)) is None  # angles
    assert state_fault(dataclasses.replace(st, yaw_rate_radps=80.0))[0] == "yaw_rate_out_of_range"
    assert state_fault(dataclasses.replace(st, v_mps=-51.0))[0] == "speed_out_of_range"
    assert state_fault(dataclasses.replace(st, delta_rad=1.2))[0] == "steering_out_of_range"
    assert state_fault(dataclasses.replace(st, x_m=2e4))[0] == "position_out_of_range"
    assert state_fault(dataclasses.replace(st, yaw_rate_radps=math.nan))[0] == "not_finite"
    assert wrap_angle(3.3) == pytest.approx(3.3 - 2 * math.pi)
    assert wrap_angle(-math.pi) == pytest.approx(-math.pi)


def test_slip_beyond_pi_is_published_wrapped_and_counted(
    svc: SimulatorService, monkeypatch: pytest.MonkeyPatch
) -> None:
    _drive(svc, 50)
    monkeypatch.setattr(svc.sim, "step", _bad_step(svc, slip_rad=3.30))
    n_truth = len(_truths(svc))
    for _ in range(10):
        res = svc.advance(H)
        assert res is not None  # an angle: wrapped, the car goes on
        svc.publish(res)
    new = _truths(svc)[n_truth:]
    assert new, "no sim/truth after the fault"
    for t in new:
        _assert_within_contract(t)
        assert t.slip_rad == pytest.approx(3.30 - 2 * math.pi)
    assert svc.faults.count(STATE_FAULT_KEY, "slip_not_canonical") == len(new)
    assert svc.fault_resets == 0
    assert svc.report()
    report = _logs(svc)[-1]
    assert report.level == "error" and report.text.startswith("own faults")
    assert "slip_not_canonical" in report.text


@pytest.mark.parametrize(
    ("change", "reason"),
    [
        ({"yaw_rate_radps": 80.0}, "yaw_rate_out_of_range"),
        ({"v_mps": 60.0}, "speed_out_of_range"),
        ({"x_m": math.nan}, "not_finite"),
    ],
)
def test_a_state_beyond_the_contract_resets_the_car_and_says_so(
    svc: SimulatorService,
    monkeypatch: pytest.MonkeyPatch,
    change: dict[str, float],
    reason: str,
) -> None:
    _drive(svc, 100)
    assert svc.sim.state.v_mps > 1.0
    real_step = svc.sim.step
    with monkeypatch.context() as m:
        m.setattr(svc.sim, "step", _bad_step(svc, **change))
        assert svc.advance(H) is None  # no exception, the step is not published
    assert svc.fault_resets == 1
    assert svc.faults.count(STATE_FAULT_KEY, reason) == 1
    st = svc.sim.state
    assert st.v_mps == 0.0 and state_fault(st) is None  # at rest on the start line
    said = _logs(svc)[-1]
    assert said.level == "error" and "car reset to the start line" in said.text
    assert svc.sim.step == real_step
    n_truth = len(_truths(svc))
    for _ in range(5):
        res = svc.advance(H)
        assert res is not None
        svc.publish(res)
    after = _truths(svc)[n_truth:]
    assert after and all(abs(t.speed_mps) < 0.5 for t in after)
    for t in after:
        _assert_within_contract(t)
    assert svc.report() and reason in _logs(svc)[-1].text


def test_a_non_finite_state_from_the_core_resets_the_car(
    svc: SimulatorService, monkeypatch: pytest.MonkeyPatch
) -> None:
    _drive(svc, 20)

    def exploding_step(command: Any = None, dt_s: float | None = None) -> StepResult:
        raise FloatingPointError("non-finite state after a step: (nan, ...)")

    with monkeypatch.context() as m:
        m.setattr(svc.sim, "step", exploding_step)
        assert svc.advance(H) is None
    assert svc.fault_resets == 1 and svc.faults.count(STATE_FAULT_KEY, "not_finite") == 1
    assert "car reset to the start line" in _logs(svc)[-1].text
    res = svc.advance(H)
    assert res is not None and state_fault(res.state) is None


def test_resets_are_said_at_most_once_per_interval(
    svc: SimulatorService, monkeypatch: pytest.MonkeyPatch
) -> None:
    now = [1000.0]
    svc.clock = lambda: now[0]
    monkeypatch.setattr(svc.sim, "step", _bad_step(svc, yaw_rate_radps=80.0))
    n_logs = len(_logs(svc))
    for _ in range(100):  # a state that fails on every step: one line, not a hundred
        assert svc.advance(H) is None
    said = _logs(svc)[n_logs:]
    assert len(said) == 1 and svc.fault_resets == 100
    now[0] += 1.5
    assert svc.advance(H) is None
    said = _logs(svc)[n_logs:]
    assert len(said) == 2 and "99 more since the last report" in said[-1].text
    assert svc.faults.count(STATE_FAULT_KEY) == 101


def test_an_invalid_record_is_counted_not_sent_and_the_rest_goes_out(
    svc: SimulatorService, monkeypatch: pytest.MonkeyPatch
) -> None:
    _drive(svc, 20)
    real = svc.sim.step

    def step(command: Any = None, dt_s: float | None = None) -> StepResult:
        # an acceleration far beyond the contract's 500 m/s^2 (a non-physical artefact)
        return dataclasses.replace(real(command, dt_s), accel_long_mps2=900.0)

    monkeypatch.setattr(svc.sim, "step", step)
    keys = svc.bus.keys
    n_imu, n_truth = len(_bus(svc).sent(keys.imu, Imu)), len(_truths(svc))
    for _ in range(10):
        res = svc.advance(H)
        assert res is not None
        svc.publish(res)  # must not raise
    assert len(_bus(svc).sent(keys.imu, Imu)) == n_imu  # every IMU sample refused
    assert svc.faults.count(keys.imu, "out_of_range") == 10  # the IMU runs at 100 Hz
    assert len(_truths(svc)) > n_truth  # the valid records still go out
    assert svc.report()
    text = _logs(svc)[-1].text
    assert text.startswith("own faults: 10") and f"{keys.imu} out_of_range x10" in text


def test_the_real_time_loop_survives_faults_on_zenoh(
    cfg: RacestackConfig, track: Track, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The service's own loop on a real loopback session, watched from a second session."""
    settings = BusSettings(car="faulttest", listen=[f"tcp/127.0.0.1:{free_loopback_port()}"])
    lock = threading.Lock()
    truths: list[SimTruth] = []
    logs: list[LogEvent] = []
    errors: list[BaseException] = []
    stop = threading.Event()
    with (
        Bus(settings, "simulator", listen_default=True) as hub,
        Bus(settings, "watcher") as watcher,
    ):

        def keep(store: list[Any]) -> Callable[[Any], None]:
            def put(m: Any) -> None:
                with lock:
                    store.append(m)

            return put

        watcher.subscribe(watcher.keys.sim_truth, SimTruth, callback=keep(truths))
        watcher.subscribe(watcher.keys.events_log, LogEvent, callback=keep(logs))
        svc = SimulatorService(cfg, hub, track)
        assert svc.pub_truth.wait_matching(10.0) and svc.log_pub.wait_matching(10.0)
        real = svc.sim.step
        faults = {"slip": 30, "yaw_rate": 3, "nan": 3}  # steps of each, in this order

        def step(command: Any = None, dt_s: float | None = None) -> StepResult:
            if svc.sim.t_s < 0.3:
                return real(command, dt_s)
            for kind, left in faults.items():
                if left:
                    faults[kind] -= 1
                    if kind == "nan":
                        raise FloatingPointError("non-finite state (injected)")
                    res = real(command, dt_s)
                    change = {"slip_rad": 3.3} if kind == "slip" else {"yaw_rate_radps": 80.0}
                    return dataclasses.replace(res, state=dataclasses.replace(res.state, **change))
            return real(command, dt_s)

        monkeypatch.setattr(svc.sim, "step", step)

        def body() -> None:
            try:
                svc.run(stop)
            except BaseException as exc:  # must not happen
                errors.append(exc)

        loop = threading.Thread(target=body, name="sim-loop", daemon=True)
        loop.start()
        try:
            deadline = time.monotonic() + 20.0
            while time.monotonic() < deadline and (
                any(faults.values()) or svc.sim.t_s < 1.5 or not loop.is_alive()
            ):
                if not loop.is_alive():
                    break
                time.sleep(0.05)
        finally:
            stop.set()
            loop.join(10.0)
        assert not loop.is_alive(), "the simulator loop did not stop"
        assert not errors, f"an exception escaped the loop: {errors!r}"
        assert not any(faults.values()), f"faults not all injected: {faults}"
        time.sleep(0.3)  # the last messages in flight
    assert svc.fault_resets == 6  # 3 yaw rate + 3 non-finite; the slip was only wrapped
    assert svc.faults.count(STATE_FAULT_KEY, "slip_not_canonical") >= 5
    with lock:
        got_truths, got_logs = list(truths), list(logs)
    assert got_truths, "no sim/truth arrived"
    for t in got_truths:  # decoded by the watcher's bus: each is within contract
        _assert_within_contract(t)
    assert any(t.slip_rad == pytest.approx(3.3 - 2 * math.pi) for t in got_truths)
    assert got_truths[-1].stamp_s > got_truths[0].stamp_s + 1.0  # kept publishing
    texts = [m.text for m in got_logs if m.source == "simulator"]
    assert any("car reset to the start line" in x for x in texts), texts
    own = " ".join(x for x in texts if x.startswith("own faults"))
    assert "slip_not_canonical" in own and "yaw_rate_out_of_range" in own, texts


# --------------------------------------------------------------------------- off-track policy
def _policy_svc(track: Track, policy: str) -> SimulatorService:
    cfg = config_from_dict({"simulator": {"off_track_policy": policy}})
    return SimulatorService(cfg, FakeBus(), track)  # type: ignore[arg-type]


def _put_beside_the_track(svc: SimulatorService, s_m: float = 5.0) -> None:
    """The car rolling at 2 m/s, 1.5 m to the right of the centreline at `s_m` (outside)."""
    x, y, yaw = centreline_pose(svc.track, s_m)
    side = 1.5  # beyond the half width of every built-in track
    svc.sim.reset(
        (x + side * math.sin(yaw), y - side * math.cos(yaw), yaw), speed_mps=2.0, t_s=svc.sim.t_s
    )


def _step(svc: SimulatorService, n: int) -> None:
    for _ in range(n):
        svc.handle_inputs()
        res = svc.advance(H)
        assert res is not None
        svc.publish(res)


def test_off_track_continue_says_so_and_drives_on(track: Track) -> None:
    svc = _policy_svc(track, "continue")
    _put_beside_the_track(svc)
    _step(svc, 3)
    assert svc.off_track_actions == 1 and not svc.stopped
    assert svc.timer.off_track  # still outside: nothing moved the car
    said = _logs(svc)[-1]
    assert said.level == "warning" and said.text.startswith("off track at s = ")


def test_off_track_stop_brakes_the_car_until_resumed(track: Track) -> None:
    svc = _policy_svc(track, "stop")
    bus = _bus(svc)
    _put_beside_the_track(svc)
    _step(svc, 3)
    assert svc.stopped and svc.off_track_actions == 1
    assert "car stopped" in _logs(svc)[-1].text
    for _ in range(100):  # 1 s of fresh commands at 3 m/s: ignored, the timeout brakes
        svc.commands.put(DriveCmd(stamp_s=1.0, speed_mps=3.0, steering_rad=0.0))
        _step(svc, 1)
    assert abs(svc.sim.state.v_mps) < 0.05
    bus.deliver(bus.keys.sim_control, SimControl(stamp_s=1.0, action="resume"))
    for _ in range(30):
        svc.commands.put(DriveCmd(stamp_s=1.0, speed_mps=3.0, steering_rad=0.0))
        _step(svc, 1)
    assert not svc.stopped and svc.sim.state.v_mps > 0.2  # commands act again


def test_off_track_reset_puts_the_car_on_the_centreline_at_rest(track: Track) -> None:
    svc = _policy_svc(track, "reset_to_centreline")
    _put_beside_the_track(svc, s_m=5.0)
    _step(svc, 1)
    assert svc.off_track_actions == 1
    st = svc.sim.state
    x, y, yaw = centreline_pose(track, svc.timer.s_m)
    assert st.v_mps == 0.0
    assert math.hypot(st.x_m - x, st.y_m - y) < 0.05 and abs(wrap_angle(st.yaw_rad - yaw)) < 1e-6
    assert "put back on the centreline" in _logs(svc)[-1].text
    _step(svc, 2)
    assert not svc.timer.off_track  # back on track, timing goes on
