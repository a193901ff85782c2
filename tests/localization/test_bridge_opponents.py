"""The bridge publishes ``opponents`` per scan (issue #24): an opponent ahead in the simulated
lidar becomes one confirmed track with its velocity; an empty track gives empty records; no
pose, no record (counted); a teleport forgets the tracks; the cost per scan is in its stats."""

from __future__ import annotations

import math

import numpy as np
import pytest

from services.localization_bridge.opponent_feed import pose_at
from services.localization_bridge.service import BridgeService
from services.simulator.laps import centreline_pose
from services.simulator.lidar import LidarScanner
from shared.bus.fake import FakeBus
from shared.config.localization import LocalizationSettings
from shared.messages import Opponents, Pose, Scan, Teleport
from shared.track import load_track, occupancy_for

T0 = 1_000_000.0


@pytest.fixture(scope="module")
def track():
    return load_track("builtin:paperlike")


@pytest.fixture(scope="module")
def scanner(track):
    return LidarScanner(occupancy_for(track), beams=1080, fov_rad=4.7, range_max_m=30.0)


class Clock:
    def __init__(self, t: float) -> None:
        self.t = t

    def __call__(self) -> float:
        return self.t


def _bridge(track, **opp) -> tuple[BridgeService, FakeBus, Clock]:
    """A bridge with opponents on (as in a race of several cars) unless `opp` says else."""
    bus = FakeBus()
    s = LocalizationSettings()
    s = LocalizationSettings(opponents=s.opponents.model_copy(update={"enabled": True, **opp}))
    svc = BridgeService(bus, s, track)
    wall = Clock(T0)
    svc.wall_clock = wall
    return svc, bus, wall


def _drive(svc, bus, wall, track, scanner, n_scans: int, opponent: bool = True,
           speed: float = 2.0, opp_speed: float = 1.0) -> list[Opponents]:
    """The ego at `speed` [m/s] and an opponent 2.5 m ahead at `opp_speed`, both on the
    centreline; poses at 40 Hz, scans at 20 Hz; the ego's pose is its rear axle, the
    simulator's lidar sits at the CoG (the bridge's default mount: lr ahead)."""
    lr = svc.settings.particle_filter.lidar_x_m
    s_ego, s_opp = 5.0, 7.5
    out = []
    for k in range(2 * n_scans):
        t = T0 + 0.025 * k
        wall.t = t
        ego = centreline_pose(track, s_ego + speed * 0.025 * k)
        rx, ry = ego.x_m - lr * math.cos(ego.yaw_rad), ego.y_m - lr * math.sin(ego.yaw_rad)
        svc.on_pose(Pose(stamp_s=t, x_m=rx, y_m=ry, yaw_rad=ego.yaw_rad))
        if k % 2:
            continue
        opp = centreline_pose(track, s_opp + opp_speed * 0.025 * k)
        boxes = np.array([[opp.x_m, opp.y_m, opp.yaw_rad]]) if opponent else None
        r = scanner.scan(ego.x_m, ego.y_m, ego.yaw_rad, boxes=boxes)
        svc.on_scan_opponents(Scan(stamp_s=t, angle_min_rad=scanner.angle_min_rad,
                                   angle_increment_rad=scanner.angle_increment_rad,
                                   ranges_m=r))
    out = bus.sent(bus.keys.opponents, Opponents)
    return out


def test_an_opponent_ahead_is_one_track_with_its_velocity(track, scanner) -> None:
    svc, bus, wall = _bridge(track)
    got = _drive(svc, bus, wall, track, scanner, 30)
    assert len(got) == 30  # one record per scan
    last = got[-1]
    assert last.frame == "map" and last.source_stamp_s <= last.stamp_s
    assert len(last.tracks) == 1
    tr = last.tracks[0]
    opp = centreline_pose(track, 7.5 + 1.0 * 0.025 * 58)
    assert math.hypot(tr.x_m - opp.x_m, tr.y_m - opp.y_m) < 0.1
    heading = track.heading_at(7.5 + 1.45)
    v_along = tr.vx_mps * math.cos(heading) + tr.vy_mps * math.sin(heading)
    assert v_along == pytest.approx(1.0, abs=0.3)
    assert tr.hits >= 20 and tr.age_s > 1.0 and tr.cov_xx_m2 > 0.0
    assert {t.tracks[0].id for t in got if t.tracks} == {tr.id}  # one id all along
    stats = svc.opponent_stats()
    assert stats["scans"] == 30 and stats["cost_median_ms"] > 0.0


def test_no_opponent_gives_empty_records(track, scanner) -> None:
    svc, bus, wall = _bridge(track)
    got = _drive(svc, bus, wall, track, scanner, 10, opponent=False)
    assert len(got) == 10 and all(not m.tracks for m in got)


def test_no_pose_no_record_and_a_teleport_forgets_the_tracks(track, scanner) -> None:
    svc, bus, wall = _bridge(track)
    wall.t = T0
    r = scanner.scan(0.0, 0.0, 0.0)
    scan = Scan(stamp_s=T0, angle_min_rad=scanner.angle_min_rad,
                angle_increment_rad=scanner.angle_increment_rad, ranges_m=r)
    assert svc.on_scan_opponents(scan) is None
    assert svc.opponent_counts["scans_without_pose"] == 1
    assert not bus.sent(bus.keys.opponents, Opponents)
    _drive(svc, bus, wall, track, scanner, 10)
    assert svc.opponents.tracker.tracks
    p = centreline_pose(track, 1.0)
    wall.t += 0.01
    svc.on_teleport(Teleport(stamp_s=wall.t, x_m=p.x_m, y_m=p.y_m, yaw_rad=p.yaw_rad))
    wall.t += 0.01
    r = scanner.scan(p.x_m, p.y_m, p.yaw_rad)
    svc.on_scan_opponents(Scan(stamp_s=wall.t, angle_min_rad=scanner.angle_min_rad,
                               angle_increment_rad=scanner.angle_increment_rad, ranges_m=r))
    assert not svc.opponents.tracker.tracks


def test_disabled_or_without_a_map_there_is_no_feed(track) -> None:
    assert not _bridge(track, enabled=False)[0].opponents_enabled
    assert not BridgeService(FakeBus(), LocalizationSettings()).opponents_enabled


def test_pose_at_moves_along_the_unicycle() -> None:
    x, y, yaw = pose_at(0.0, 0.0, 0.0, 2.0, 0.0, -0.5)
    assert (x, y, yaw) == pytest.approx((-1.0, 0.0, 0.0))
    x, y, yaw = pose_at(1.0, 1.0, math.pi / 2, 1.0, 1.0, 0.1)
    assert yaw == pytest.approx(math.pi / 2 + 0.1) and y > 1.0


def test_by_default_opponents_are_tracked_only_in_a_race_of_several_cars() -> None:
    """Alone on the track the detector would only cost the bridge CPU on every scan."""
    import argparse

    from shared.config import config_from_dict

    alone = BridgeService.create(config_from_dict({}), argparse.Namespace(), FakeBus())
    assert not alone.opponents_enabled
    two = config_from_dict({"cars": [{"name": "car0"}, {"name": "car1"}]})
    assert BridgeService.create(two, argparse.Namespace(), FakeBus()).opponents_enabled
    forced = config_from_dict({"localization": {"opponents": {"enabled": True}}})
    assert BridgeService.create(forced, argparse.Namespace(), FakeBus()).opponents_enabled
