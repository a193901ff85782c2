"""Lap timing by arc length and off-track detection by the footprint, on scripted paths."""

from __future__ import annotations

import math

import numpy as np
import pytest

from services.simulator.laps import LapTimer, centreline_pose
from shared.track import load_track

DT = 0.01


@pytest.fixture(scope="module")
def track():
    return load_track("paperlike")


def _feed(timer: LapTimer, track, s_values, speed: float, t0: float = 0.0, e_offset: float = 0.0):
    """Poses on the centreline (shifted `e_offset` to the right) at arc lengths `s_values`."""
    events = []
    for k, s in enumerate(s_values):
        p = centreline_pose(track, s)
        x = p.x_m + e_offset * math.sin(p.yaw_rad)
        y = p.y_m - e_offset * math.cos(p.yaw_rad)
        events += timer.update(t0 + k * DT, x, y, p.yaw_rad, speed)
    return events


def test_constant_speed_lap_time_is_length_over_speed(track) -> None:
    L = track.length_m
    v = 4.0
    timer = LapTimer(track)
    s = (L - 1.0) + v * DT * np.arange(int((2 * L + 2.0) / (v * DT)))
    events = _feed(timer, track, s, v)
    kinds = [e.kind for e in events]
    assert kinds == ["start", "lap", "lap"]
    assert events[0].t_s == pytest.approx(1.0 / v, abs=DT)
    for n, e in enumerate(events[1:], start=1):
        assert e.lap == n
        assert e.lap_time_s == pytest.approx(L / v, abs=DT)
        assert e.mean_speed_mps == pytest.approx(v, rel=1e-3)
        assert e.mean_car_speed_mps == pytest.approx(v, rel=1e-9)
        assert e.off_track_events == 0
        assert e.max_abs_e_con_m < 1e-6
    assert timer.laps_completed == 2


def test_start_line_jitter_counts_no_extra_lap(track) -> None:
    L = track.length_m
    timer = LapTimer(track)
    # from 0.1 m behind the line, +-0.3 m back and forth over it six times
    jitter = np.mod(-0.1 + 0.3 * np.sin(np.linspace(0.0, 12 * np.pi, 400)), L)
    events = _feed(timer, track, jitter, 1.0)
    assert [e.kind for e in events] == ["start"]  # the first forward crossing only
    # one full lap forwards, then jitter over the line again: exactly one lap
    lap = 0.3 + 0.02 * np.arange(int(L / 0.02) + 1)
    events = _feed(timer, track, lap, 2.0, t0=10.0)
    events += _feed(timer, track, jitter, 1.0, t0=40.0)
    assert [e.kind for e in events] == ["lap"]


def test_reverse_driving_counts_no_lap(track) -> None:
    L = track.length_m
    timer = LapTimer(track)
    s = np.mod(1.0 - 0.03 * np.arange(int(2.5 * L / 0.03)), L)
    assert _feed(timer, track, s, -3.0) == []
    assert timer.progress_m < -2.0 * L


def test_off_track_by_the_footprint(track) -> None:
    w_r = float(track.w_right_m[0])
    timer = LapTimer(track, width_m=0.31, length_m=0.58)
    s = 5.0 + 0.02 * np.arange(50)
    assert _feed(timer, track, s, 2.0) == []
    # CoG inside, the right corners 0.155 m further right: beyond w_right
    ev = _feed(timer, track, s + 1.0, 2.0, t0=1.0, e_offset=w_r - 0.1)
    assert [e.kind for e in ev] == ["off_track"]
    assert ev[0].t_s == pytest.approx(1.0) and ev[0].s_m == pytest.approx(6.0, abs=1e-6)
    assert timer.off_track
    assert _feed(timer, track, s + 2.0, 2.0, t0=2.0, e_offset=w_r + 0.5) == []
    ev = _feed(timer, track, s + 3.0, 2.0, t0=3.0, e_offset=0.0)
    assert [e.kind for e in ev] == ["back_on_track"]
    assert timer.e_con_m == pytest.approx(0.0, abs=1e-9)
    # left side as well
    ev = _feed(timer, track, s + 4.0, 2.0, t0=4.0, e_offset=-(float(track.w_left_m[0]) - 0.1))
    assert [e.kind for e in ev] == ["off_track"]


def test_lap_reports_off_track_events_and_deviation(track) -> None:
    L = track.length_m
    timer = LapTimer(track)
    _feed(timer, track, [L - 0.2, L - 0.1, 0.05], 2.0)  # start
    s = 0.05 + 0.02 * np.arange(1, 200)
    _feed(timer, track, s, 2.0, t0=1.0, e_offset=0.3)
    _feed(timer, track, s + 4.0, 2.0, t0=3.0, e_offset=0.7)  # out
    ev = _feed(timer, track, np.mod(np.arange(8.1, L + 1.0, 0.02), L), 2.0, t0=5.0)
    laps = [e for e in ev if e.kind == "lap"]
    assert len(laps) == 1
    assert laps[0].off_track_events == 1
    assert laps[0].max_abs_e_con_m == pytest.approx(0.7, abs=1e-6)


def test_local_projection_agrees_with_track_project(track) -> None:
    rng = np.random.default_rng(5)
    timer = LapTimer(track)
    proj = timer._proj
    for s0 in rng.uniform(0.0, track.length_m, 40):
        p = centreline_pose(track, s0)
        pts = np.array([p.x_m, p.y_m]) + rng.normal(0.0, 0.2, (5, 2))
        s_ref, e_ref = track.project(pts, s_hint=s0)
        seg_hint = int(np.searchsorted(track.s_m, s0, side="right") - 1)
        s, e, w_r, w_l, _ = proj.project(pts, seg_hint)
        np.testing.assert_allclose(s, s_ref, atol=1e-9)
        np.testing.assert_allclose(e, e_ref, atol=1e-9)
        wr_ref, wl_ref = track.interp_width(s_ref)
        np.testing.assert_allclose(w_r, wr_ref, atol=1e-9)
        np.testing.assert_allclose(w_l, wl_ref, atol=1e-9)
    # a jump far away falls back to the global search
    timer.update(0.0, *centreline_pose(track, 1.0)[:3], 1.0)
    far = centreline_pose(track, 20.0)
    timer.update(0.01, far.x_m, far.y_m, far.yaw_rad, 1.0)
    assert timer.s_m == pytest.approx(20.0, abs=1e-6)
