"""Car-to-car contact (shared/vehicle/contact.py) on crafted poses."""

from __future__ import annotations

import math

import numpy as np
import pytest

from shared.car import CAR
from shared.vehicle.contact import ContactMonitor, box_contact, footprint_corners

L, W = CAR.length_m, CAR.width_m


def test_corners_of_a_car_at_the_origin() -> None:
    c = footprint_corners(np.array([0.0, 0.0, 0.0]))[0]
    np.testing.assert_allclose(c[0], [L / 2, W / 2])
    np.testing.assert_allclose(c[2], [-L / 2, -W / 2])


@pytest.mark.parametrize(
    ("dy", "overlapping", "depth"),
    [(W + 0.10, False, -0.10), (W, False, 0.0), (W - 0.04, True, 0.04)],
)
def test_side_by_side_apart_touching_overlapping(
    dy: float, overlapping: bool, depth: float
) -> None:
    con = box_contact(np.array([1.0, 2.0, 0.0]), np.array([1.0, 2.0 + dy, 0.0]))
    assert bool(con.overlapping[0]) is overlapping
    assert con.depth_m[0] == pytest.approx(depth, abs=1e-9)
    np.testing.assert_allclose(con.normal[0], [0.0, 1.0], atol=1e-12)


def test_nose_to_tail_depth_and_normal_along_the_cars() -> None:
    con = box_contact(np.array([0.0, 0.0, 0.0]), np.array([L - 0.03, 0.01, 0.0]))
    assert con.overlapping[0]
    assert con.depth_m[0] == pytest.approx(0.03)
    np.testing.assert_allclose(con.normal[0], [1.0, 0.0], atol=1e-12)
    apart = box_contact(np.array([0.0, 0.0, 0.0]), np.array([L + 0.05, 0.0, 0.0]))
    assert apart.gap_m[0] == pytest.approx(0.05)


def test_rotated_45_corner_into_a_side() -> None:
    # b rotated 45 deg beside a: its nearest corner reaches W/2 + h below its centre
    h = (L / 2 + W / 2) / math.sqrt(2.0)  # b's half extent on the y axis
    for gap, hit in ((0.02, False), (-0.02, True)):
        y = W / 2 + h + gap
        con = box_contact(np.array([0.0, 0.0, 0.0]), np.array([0.0, y, math.pi / 4]))
        assert bool(con.overlapping[0]) is hit
        assert con.depth_m[0] == pytest.approx(-gap, abs=1e-9)
        np.testing.assert_allclose(con.normal[0], [0.0, 1.0], atol=1e-12)


def test_identical_poses_overlap_by_the_width() -> None:
    con = box_contact(np.array([3.0, -1.0, 0.7]), np.array([3.0, -1.0, 0.7]))
    assert con.overlapping[0]
    assert con.depth_m[0] == pytest.approx(W)
    assert np.linalg.norm(con.normal[0]) == pytest.approx(1.0)


def test_vectorised_matches_pair_by_pair() -> None:
    rng = np.random.default_rng(4)
    a = np.column_stack([rng.uniform(-1, 1, (200, 2)), rng.uniform(-3, 3, 200)])
    b = np.column_stack([rng.uniform(-1, 1, (200, 2)), rng.uniform(-3, 3, 200)])
    all_at_once = box_contact(a, b)
    for k in range(0, 200, 17):
        one = box_contact(a[k], b[k])
        assert one.depth_m[0] == pytest.approx(all_at_once.depth_m[k])
    # symmetric: the same depth, the opposite normal
    back = box_contact(b, a)
    np.testing.assert_allclose(back.depth_m, all_at_once.depth_m, atol=1e-12)
    assert np.all(back.overlapping == all_at_once.overlapping)


def test_overlap_agrees_with_point_sampling() -> None:
    rng = np.random.default_rng(5)
    a = np.column_stack([rng.uniform(-0.5, 0.5, (300, 2)), rng.uniform(-3, 3, 300)])
    b = np.zeros((300, 3))
    con = box_contact(a, b)
    # sample a's footprint densely; any sample inside b means overlap
    u, v = np.meshgrid(np.linspace(-L / 2, L / 2, 41), np.linspace(-W / 2, W / 2, 23))
    u, v = u.ravel(), v.ravel()
    c, s = np.cos(a[:, 2:3]), np.sin(a[:, 2:3])
    x = a[:, :1] + c * u - s * v
    y = a[:, 1:2] + s * u + c * v
    inside = ((np.abs(x) <= L / 2) & (np.abs(y) <= W / 2)).any(axis=1)
    clear = np.abs(con.depth_m) > 0.02  # sampling resolution
    assert np.all(inside[clear] == con.overlapping[clear])


def _drive(mon: ContactMonitor, ys: list[float], xb: float = 0.0) -> list[int]:
    """Car b beside car a at lateral offsets ys, one update each; incidents per update."""
    out = []
    for k, y in enumerate(ys):
        poses = np.array([[0.0, 0.0, 0.0], [xb, y, 0.0]])
        vel = np.array([[2.0, 0.0], [2.0, -0.3]])
        out.append(len(mon.update(0.025 * k, poses, vel)))
    return out


def test_an_episode_counts_once_with_hysteresis() -> None:
    mon = ContactMonitor(n_cars=2)
    # approach, touch, jitter around the touching distance (within leave_gap), leave, touch again
    ys = [W + 0.1, W - 0.01, W + 0.005, W - 0.002, W + 0.01, W + 0.05, W - 0.01, W + 0.1]
    assert _drive(mon, ys) == [0, 1, 0, 0, 0, 0, 1, 0]
    assert mon.count_between(1, 0) == 2
    inc = mon.incidents[0]
    assert inc.striker == 1  # b moved in sideways (closing along the normal), a straight
    assert (inc.car_a, inc.car_b) == (0, 1)


def test_striker_is_the_car_with_its_nose_in_the_other() -> None:
    mon = ContactMonitor(n_cars=3)
    # car 2 rear-ends car 1 (same speed: the rule's first clause decides); car 0 far away
    poses = np.array([[10.0, 5.0, 0.0], [0.0, 0.0, 0.0], [-(L - 0.02), 0.05, 0.0]])
    vel = np.array([[1.0, 0.0], [3.0, 0.0], [3.0, 0.0]])
    new = mon.update(0.0, poses, vel)
    assert len(new) == 1 and (new[0].car_a, new[0].car_b) == (1, 2)
    assert new[0].striker == 2


def test_rear_end_from_behind_by_speed() -> None:
    # exactly aligned nose to tail: both front-corner tests are decided by geometry (car 0's
    # nose in car 1), but also the faster car behind is car 0
    mon = ContactMonitor(n_cars=2)
    poses = np.array([[0.0, 0.0, 0.0], [L - 0.01, 0.0, 0.0]])
    new = mon.update(0.0, poses, np.array([[4.0, 0.0], [2.0, 0.0]]))
    assert new[0].striker == 0


def test_bad_settings_are_refused() -> None:
    with pytest.raises(ValueError):
        ContactMonitor(n_cars=1)
