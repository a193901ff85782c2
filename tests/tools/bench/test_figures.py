"""The figures' data-level fixes (issue #16), checked on the drawn matplotlib objects: no
pixel comparison."""

from __future__ import annotations

import numpy as np
import pytest

from shared.config.root import RacestackConfig
from shared.curvature import track_profile
from shared.evaluation import LapRecord, MethodRun, ReferenceLine, Trace, write_figures
from shared.evaluation.figures import (
    break_gaps,
    compute_time_axis_ms,
    draw_laps,
    draw_solve_time,
    draw_speed_vs_s,
    draw_trajectories,
    gap_for,
    no_solver,
    plural,
)
from shared.track import Track

pytest.importorskip("matplotlib")


def _circle(radius_m: float = 3.0, n: int = 200) -> Track:
    a = np.linspace(0.0, 2 * np.pi, n, endpoint=False)
    xy = np.stack([radius_m * np.cos(a), radius_m * np.sin(a)], axis=1)
    return Track(name="circle", xy=xy, w_right_m=np.full(n, 0.6), w_left_m=np.full(n, 0.6),
                 source="test")


def _one_lap_run(track: Track, name: str = "cimpcc") -> MethodRun:
    """A recorded one-lap run: lap 1 all round, then lap 2 from s = 0 to 20 % of the lap,
    with one early sample of lap 2 just before the line (s close to L), as a recording has."""
    L = track.length_m
    s1 = np.linspace(0.0, L, 300, endpoint=False)
    s2 = np.concatenate([[L - 0.05], np.linspace(0.0, 0.2 * L, 60)])
    s = np.concatenate([s1, s2])
    lap = np.concatenate([np.ones(s1.size, int), np.full(s2.size, 2)])
    xy = np.array([track.point_at(v) for v in s])
    v = 2.0 + 0.5 * np.sin(2 * np.pi * s / L)
    tr = Trace(t_s=list(np.arange(s.size) * 0.05), s_m=list(s), x_m=list(xy[:, 0]),
               y_m=list(xy[:, 1]), speed_mps=list(v), cmd_speed_mps=list(v),
               e_con_m=[0.0] * s.size, beta=[0.5] * s.size, lap=list(lap))
    laps = [LapRecord(L / 2.2, 2.2, 0, 0.1)]
    return MethodRun(name, laps, tr, [1.0] * 50, 0, 1)


def test_fig_break_gaps_leaves_a_gap_open() -> None:
    s, v = break_gaps(np.array([0.0, 1.0, 2.0, 9.0, 9.5]), np.arange(5.0), gap_m=1.5)
    assert np.isnan(s[3]) and np.isnan(v[3])
    assert np.allclose(s[[0, 1, 2, 4, 5]], [0.0, 1.0, 2.0, 9.0, 9.5])


def test_fig5_one_lap_report_draws_no_diagonal_to_the_lap_end() -> None:
    track = _circle()
    L = track.length_m
    profile = track_profile(track, RacestackConfig().curvature)
    fig = draw_speed_vs_s(profile, [_one_lap_run(track)])
    lines = [ln for ln in fig.axes[0].get_lines() if ln.get_label() != "_nolegend_"]
    assert lines
    for ln in fig.axes[0].get_lines():
        s = np.asarray(ln.get_xdata(), dtype=float)
        finite = np.isfinite(s[:-1]) & np.isfinite(s[1:])
        steps = np.diff(s)[finite]
        assert steps.size == 0 or steps.max() <= gap_for(L) + 1e-9  # no straight join
    lap2 = [ln for ln in fig.axes[0].get_lines() if np.nanmin(ln.get_xdata()) < 1
            and np.nanmax(ln.get_xdata()) > L - 0.1 and np.isnan(ln.get_xdata()).any()]
    assert lap2, "lap 2 (0 .. 20 % and one point at the end) is drawn with its gap open"
    assert min(ln.get_linewidth() for ln in fig.axes[0].get_lines()) >= 1.4  # thick lines
    ax = fig.axes[0]
    fig.canvas.draw()
    (legend,) = fig.subfigs[0].legends  # a row above the axes, over no curve
    assert legend.get_window_extent().y0 >= ax.get_window_extent().y1 - 1
    assert ax.get_ylim()[0] > 1.0  # the speeds set the axis, not the NSC image's 0..1


def test_fig7_whole_lap_ticks_legend_above_and_min_time_line() -> None:
    track = _circle()
    run = _one_lap_run(track)
    two = MethodRun("mpcc", [*run.laps, LapRecord(track.length_m / 2.1, 2.1, 0, 0.1)],
                    run.trace, [1.0], 0, 2)
    ref = ReferenceLine(3.5, np.zeros(3), np.zeros(3), np.zeros(3), np.ones(3))
    fig = draw_laps([run, two], ref)
    a, b = (ax for ax in fig.axes if ax.get_lines())
    fig.canvas.draw()
    ticks = [t for t in b.get_xticks() if b.get_xlim()[0] <= t <= b.get_xlim()[1]]
    assert ticks and all(float(t).is_integer() for t in ticks)
    (legend,) = fig.subfigs[0].legends
    box = legend.get_window_extent()
    assert box.y0 >= a.get_window_extent().y1 - 1  # a row above the plots: covers no point
    assert any(abs(ln.get_ydata()[0] - 3.5) < 1e-9 for ln in a.get_lines())  # min-time line
    assert a.get_title()


def test_fig8_axis_is_not_set_by_one_outlier() -> None:
    rng = np.random.default_rng(0)
    t = [*rng.normal(1.5, 0.2, 2000).clip(0.5), 60.0]
    run = MethodRun("cimpcc", [], Trace(), t, 0, 0)
    assert compute_time_axis_ms([t]) < 5.0
    fig = draw_solve_time([run, MethodRun("raceline", [], Trace(), [0.7] * 100, 0, 0)])
    ax = fig.axes[0]
    assert ax.get_xlim()[1] < 5.0
    texts = fig.subfigs[0]._supxlabel.get_text()
    assert "beyond" in texts and "60.0" in texts  # the outlier is said, not drawn
    labels = [x.get_text() for x in fig.subfigs[0].legends[0].get_texts()]
    assert any("raceline" in lb and "no solver" in lb for lb in labels)
    assert any("p95" in lb for lb in labels)  # p95 in the legend, not over the curves
    assert ax.get_title() and fig._suptitle.get_text()


def test_fig_titles_plural_and_no_solver() -> None:
    assert plural(1, "lap") == "1 lap" and plural(3, "lap") == "3 laps"
    assert no_solver("raceline") and not no_solver("cimpcc")
    track = _circle()
    fig = draw_trajectories(track, [_one_lap_run(track)])
    titles = [ax.get_title() for ax in fig.axes if ax.get_visible()]
    assert "cimpcc: 1 lap" in titles
    assert fig._suptitle is not None and fig._suptitle.get_text()


def test_fig_write_all_five_with_a_reference(tmp_path) -> None:
    track = _circle()
    profile = track_profile(track, RacestackConfig().curvature)
    s = np.linspace(0, track.length_m, 50, endpoint=False)
    xy = np.array([track.point_at(v) for v in s])
    ref = ReferenceLine(4.0, xy[:, 0], xy[:, 1], s, np.full(50, 3.0))
    paths = write_figures(tmp_path, track, profile, [_one_lap_run(track)], reference=ref,
                          formats=("png",))
    assert [p.name for p in paths] == [
        "fig4_curvature.png", "fig5_speed_vs_s.png", "fig6_trajectories.png",
        "fig7_laps.png", "fig8_solve_time.png"]
    assert all(p.stat().st_size > 1000 for p in paths)
    captions = (tmp_path / "captions.md").read_text()
    assert "Fig. 4:" in captions and "`fig8_solve_time.{png}`" in captions
