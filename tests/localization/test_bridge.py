"""The bridge's shell on the in-process bus: state on each fused pose (and the fallback when
poses stop), fixed-rate state, stamp rejections reported,
malformed scans counted and dropped (lidar pose source), the scan checks themselves."""

from __future__ import annotations

import math
import threading
import time

import numpy as np
import pytest
from msgspec.structs import force_setattr

from services.localization_bridge import LidarPoseSource, ScanLayout, scan_problem, service
from services.localization_bridge.service import BridgeService
from shared.bus.fake import FakeBus
from shared.config.localization import LocalizationSettings
from shared.messages import Imu, LogEvent, Odom, Pose, Scan, State, Teleport
from shared.track import load_track
from shared.track.occupancy import FREE, OCCUPIED, OccupancyGrid


def scan(n: int = 360, inc: float = 2 * math.pi / 360, ranges=None, stamp: float = 1.0) -> Scan:
    r = np.full(n, 2.0, dtype=np.float32) if ranges is None else np.asarray(ranges, np.float32)
    return Scan(stamp_s=stamp, angle_min_rad=-math.pi, angle_increment_rad=inc, ranges_m=r)


def test_scan_checks_name_each_problem() -> None:
    good = scan()
    layout = ScanLayout.of(good)
    assert scan_problem(good, None) is None and scan_problem(good, layout) is None
    assert scan_problem(scan(n=100), layout) == "wrong_length"
    assert scan_problem(scan(inc=-0.01), None) == "angle_increment_not_positive"
    assert scan_problem(scan(n=1000, inc=0.01), None) == "fov_over_2pi"
    assert scan_problem(scan(ranges=np.full(360, np.inf)), None) == "too_few_returns"
    # NaN / negative ranges never pass the bus; a record built around its checks is caught
    bad = scan()
    force_setattr(bad, "ranges_m", np.full(360, np.nan, dtype=np.float32))
    assert scan_problem(bad, None) == "range_nan"
    force_setattr(bad, "ranges_m", np.full(360, -1.0, dtype=np.float32))
    assert scan_problem(bad, None) == "range_negative"


def room() -> OccupancyGrid:
    """A 4 m x 4 m room of 5 cm cells around the origin."""
    cells = np.full((80, 80), OCCUPIED, dtype=np.int8)
    cells[2:-2, 2:-2] = FREE
    return OccupancyGrid(cells=cells, resolution_m=0.05, origin_xy_m=np.array([-2.0, -2.0]))


def small_pf_settings() -> LocalizationSettings:
    pf = LocalizationSettings().particle_filter.model_copy(
        update={"particles": 200, "global_particles": 200, "global_candidates": 1000}
    )
    return LocalizationSettings(pose_source="lidar", particle_filter=pf)


def test_malformed_scans_are_counted_and_dropped_never_a_crash() -> None:
    src = LidarPoseSource(room(), small_pf_settings(), (0.0, 0.0, 0.0))
    good = scan(stamp=1.0)
    src.scan(good)
    bad = scan(stamp=1.1)
    force_setattr(bad, "ranges_m", np.full(360, np.nan, dtype=np.float32))
    assert src.scan(bad) is None
    assert src.scan(scan(n=100, stamp=1.2)) is None
    assert src.scan(scan(inc=-2 * math.pi / 360, stamp=1.3)) is None
    assert src.scan(scan(stamp=0.5)) is None  # older than the last one used
    c = src.counts
    assert c["range_nan"] == 1 and c["wrong_length"] == 1
    assert c["angle_increment_not_positive"] == 1 and c["scan_out_of_order"] == 1


class Clock:
    def __init__(self, t: float) -> None:
        self.t = t

    def __call__(self) -> float:
        return self.t


def test_rejections_are_reported_on_events_log() -> None:
    bus = FakeBus()
    wall = Clock(1000.0)
    svc = BridgeService(bus, LocalizationSettings())
    svc.wall_clock = wall
    svc.on_odom(Odom(stamp_s=1000.0, speed_mps=1.0, steering_rad=0.0))
    svc.on_imu(Imu(stamp_s=1000.0, yaw_rate_radps=0.0, ax_mps2=0.0, ay_mps2=0.0))
    svc.on_pose(Pose(stamp_s=999.99, x_m=1.0, y_m=2.0, yaw_rad=0.0))
    svc.on_pose(Pose(stamp_s=1000.0 + 3600.0, x_m=1.0, y_m=2.0, yaw_rad=0.0))
    svc.on_pose(Pose(stamp_s=900.0, x_m=1.0, y_m=2.0, yaw_rad=0.0))
    st = svc.current_state()
    assert st.valid and st.source_stamp_s == pytest.approx(999.99)
    svc.tick()
    texts = [e.text for e in bus.sent(bus.keys.events_log, LogEvent)]
    assert any("pose_future 1" in t and "pose_stale 1" in t for t in texts), texts


def test_each_fused_pose_publishes_its_state_at_once_and_a_gated_one_does_not() -> None:
    bus = FakeBus()
    wall = Clock(1000.0)
    svc = BridgeService(bus, LocalizationSettings())
    svc.wall_clock = wall
    svc.on_odom(Odom(stamp_s=1000.0, speed_mps=2.0, steering_rad=0.0))
    assert not bus.sent(bus.keys.state, State)  # no pose yet: nothing
    svc.on_pose(Pose(stamp_s=999.99, x_m=1.0, y_m=2.0, yaw_rad=0.0))
    wall.t = 1000.025
    svc.on_pose(Pose(stamp_s=1000.02, x_m=1.04, y_m=2.0, yaw_rad=0.0))
    states = bus.sent(bus.keys.state, State)
    assert [s.source_stamp_s for s in states] == pytest.approx([999.99, 1000.02])
    assert states[-1].stamp_s == 1000.025 and states[-1].valid  # predicted to its arrival
    wall.t = 1000.05
    svc.on_pose(Pose(stamp_s=1000.045, x_m=40.0, y_m=2.0, yaw_rad=0.0))  # gated: no state
    svc.on_pose(Pose(stamp_s=900.0, x_m=1.0, y_m=2.0, yaw_rad=0.0))  # stale: no state
    assert len(bus.sent(bus.keys.state, State)) == 2
    wall.t = 1000.06
    svc.on_teleport(Teleport(stamp_s=1000.055, x_m=5.0, y_m=1.0, yaw_rad=0.5, speed_mps=0.0))
    st = bus.sent(bus.keys.state, State)[-1]  # the teleport's state goes out at once
    assert len(bus.sent(bus.keys.state, State)) == 3
    assert (st.x_m, st.y_m, st.stamp_s) == (pytest.approx(5.0), pytest.approx(1.0), 1000.06)


def test_poses_queued_behind_a_late_worker_are_all_fused_and_only_the_newest_is_sent() -> None:
    """A worker late by three poses (a loaded machine, a garbage flood beside them): each
    pose reaches the filter, in order, and one state goes out, the newest pose's."""
    bus = FakeBus()
    wall = Clock(1000.0)
    svc = BridgeService(bus, LocalizationSettings())
    svc.wall_clock = wall
    svc.on_pose(Pose(stamp_s=999.99, x_m=1.0, y_m=2.0, yaw_rad=0.0))
    wall.t = 1000.08
    channel = bus.channels[bus.keys.pose]
    for k in range(3):
        channel.put(Pose(stamp_s=1000.0 + 0.025 * k, x_m=1.0 + 0.05 * (k + 1), y_m=2.0,
                         yaw_rad=0.0))
    channel.put(None)  # the bus closes: receive() returns once the queue is empty
    applied = svc.core.counts["pose_applied"]
    svc.receive()
    assert svc.core.counts["pose_applied"] == applied + 3
    states = bus.sent(bus.keys.state, State)
    assert [s.source_stamp_s for s in states] == pytest.approx([999.99, 1000.05])


def test_the_closing_summary_names_the_filter_counts() -> None:
    bus = FakeBus()
    svc = BridgeService(bus, LocalizationSettings())
    svc.on_pose(Pose(stamp_s=time.time(), x_m=1.0, y_m=2.0, yaw_rad=0.0))
    assert "pose_initialised 1" in svc.input_summary()  # the fake channel keeps no stats


def test_a_state_older_than_the_one_already_sent_is_dropped_and_counted() -> None:
    """The pose path and the fallback worker both publish: a state computed before the other
    thread's but sent after it would take the planner back in time."""
    bus = FakeBus()
    wall = Clock(1000.0)
    svc = BridgeService(bus, LocalizationSettings())
    svc.wall_clock = wall
    svc.on_pose(Pose(stamp_s=999.99, x_m=1.0, y_m=2.0, yaw_rad=0.0))
    wall.t = 1000.030
    newer = svc.current_state()  # the fallback's state, sent first
    wall.t = 1000.025
    older = svc.current_state()  # computed earlier on the pose path, sent second
    svc._put(newer)
    svc._put(older, fused=True)
    stamps = [s.stamp_s for s in bus.sent(bus.keys.state, State)]
    assert stamps == sorted(stamps) and stamps[-1] == 1000.030
    assert svc.out_of_order == 1


def test_the_fallback_state_goes_out_only_while_no_pose_is_fused() -> None:
    bus = FakeBus()
    svc = BridgeService(bus, LocalizationSettings(fallback_after_s=0.05, publish_rate_hz=100.0))
    stop = threading.Event()
    worker = threading.Thread(target=svc.publish_loop, args=(stop,))
    worker.start()
    try:
        time.sleep(0.2)
        assert not bus.sent(bus.keys.state, State)  # nothing before the first pose
        stamp = time.time()
        svc.on_pose(Pose(stamp_s=stamp, x_m=1.0, y_m=2.0, yaw_rad=0.0))
        time.sleep(0.5)  # the poses stopped: predictions of the same pose follow
    finally:
        stop.set()
        worker.join(timeout=5.0)
    assert not worker.is_alive()
    states = bus.sent(bus.keys.state, State)
    assert len(states) >= 2 and all(s.source_stamp_s == stamp for s in states)
    assert states[1].stamp_s - states[0].stamp_s >= 0.05  # not before fallback_after_s


def test_the_service_publishes_state_at_its_fixed_rate_from_the_first_pose() -> None:
    bus = FakeBus()
    svc = BridgeService(bus, LocalizationSettings(publish_rate_hz=100.0,
                                                  state_output="fixed_rate"))
    stop = threading.Event()
    worker = threading.Thread(target=svc.publish_loop, args=(stop,))
    worker.start()
    time.sleep(0.2)
    assert not bus.sent(bus.keys.state, State)  # nothing before the first pose
    svc.on_pose(Pose(stamp_s=time.time(), x_m=1.0, y_m=2.0, yaw_rad=0.0))
    t0 = time.monotonic()
    time.sleep(1.0)
    stop.set()
    worker.join(timeout=5.0)
    elapsed = time.monotonic() - t0
    assert not worker.is_alive()
    states = bus.sent(bus.keys.state, State)
    rate = len(states) / elapsed
    assert 50.0 < rate < 110.0, rate  # loosely: 100 Hz on a loaded machine
    assert states[0].x_m == pytest.approx(1.0, abs=0.01)


def test_before_the_first_pose_the_state_is_invalid_and_passthrough_keeps_the_old_bridge() -> None:
    bus = FakeBus()
    svc = BridgeService(bus, LocalizationSettings())
    assert not svc.current_state().valid
    svc = BridgeService(bus, LocalizationSettings(filter="passthrough", max_prediction_s=0.0))
    assert not svc.current_state().valid
    svc.on_odom(Odom(stamp_s=time.time(), speed_mps=2.0, steering_rad=0.1))
    svc.on_pose(Pose(stamp_s=time.time(), x_m=1.0, y_m=2.0, yaw_rad=0.3))
    st = svc.current_state()
    assert st.valid and (st.x_m, st.y_m, st.speed_mps) == (1.0, 2.0, 2.0)


def test_the_lidar_bridge_drops_bad_scans_through_its_shell(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    settings = small_pf_settings()
    monkeypatch.setattr(service, "occupancy_for", lambda _track: room())  # no rasterising
    bus = FakeBus()
    svc = BridgeService(bus, settings, load_track("paperlike"))
    assert svc.inputs.key == bus.keys.scan
    svc.on_scan(scan(n=360, stamp=time.time()))
    svc.on_scan(scan(n=100, stamp=time.time()))  # another layout
    svc.on_scan(scan(inc=-2 * math.pi / 360, stamp=time.time()))
    c = svc.counts()
    assert c["scans_used"] == 1 and c["wrong_length"] == 1
    assert c["angle_increment_not_positive"] == 1
    with pytest.raises(ValueError, match="needs the track"):
        BridgeService(FakeBus(), settings)


def test_the_particle_filter_is_placed_at_the_teleport_and_drops_older_scans() -> None:
    src = LidarPoseSource(room(), small_pf_settings(), (0.0, 0.0, 0.0))
    src.place(2.0, 0.5, -0.5, 1.0, 0.0)
    poses = src.pf.poses
    assert np.mean(poses[:, 0]) == pytest.approx(0.5, abs=0.1)
    assert np.mean(poses[:, 1]) == pytest.approx(-0.5, abs=0.1)
    assert src.scan(scan(stamp=1.9)) is None and src.scan(scan(stamp=2.0)) is None
    assert src.counts["scan_before_teleport"] == 2
    src.scan(scan(stamp=2.1))
    assert src.counts["scans_used"] == 1


def test_the_lidar_bridge_places_its_filter_on_the_scan_worker(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    monkeypatch.setattr(service, "occupancy_for", lambda _track: room())
    svc = BridgeService(FakeBus(), small_pf_settings(), load_track("paperlike"))
    svc.wall_clock = lambda: 2.0
    svc.on_teleport(Teleport(stamp_s=1.95, x_m=0.5, y_m=-0.5, yaw_rad=1.0))
    assert svc._place is not None  # waiting for the scan worker (it owns the filter)
    svc.on_scan(scan(stamp=1.9))
    assert svc._place is None and svc.lidar is not None
    assert svc.lidar.counts["scan_before_teleport"] == 1
    assert np.mean(svc.lidar.pf.poses[:, 0]) == pytest.approx(0.5, abs=0.1)
