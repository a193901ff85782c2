"""The figures' files and look (issue #22), on synthetic data: one save helper writing PDF,
SVG and a 300 dpi PNG at the figure's own size, titles without "Fig. N:", legends inside
the figure, Fig. 6's grid without empty cells and its off-track markers, Fig. 7 for one lap,
Fig. 8's axis in planner cycles. No pixel comparison, nothing timed."""

from __future__ import annotations

import argparse

import numpy as np
import pytest

from shared.config.root import RacestackConfig
from shared.curvature import track_profile
from shared.evaluation import LapRecord, MethodRun, ReferenceLine, Trace
from shared.evaluation.figures import (
    DPI,
    FORMATS,
    draw_curvature,
    draw_laps,
    draw_solve_time,
    draw_speed_vs_s,
    draw_trajectories,
    grid_shape,
    parse_formats,
    save_figure,
    zoom_windows,
)
from shared.evaluation.plotting import OFF_TRACK_STYLE, add_figure_formats_argument
from shared.track import Track

pytest.importorskip("matplotlib")
Image = pytest.importorskip("PIL.Image")


def _ellipse(a_m: float = 3.0, b_m: float = 2.0, n: int = 200, wobble: float = 0.0) -> Track:
    t = np.linspace(0.0, 2 * np.pi, n, endpoint=False)
    r = 1.0 + wobble * np.sin(5 * t)
    xy = np.stack([a_m * r * np.cos(t), b_m * r * np.sin(t)], axis=1)
    return Track(name="ellipse", xy=xy, w_right_m=np.full(n, 0.6), w_left_m=np.full(n, 0.6),
                 source="test")


def _run(track: Track, name: str, laps: int = 1, offset_m: float = 0.0,
         off_xy: list[tuple[float, float]] | None = None) -> MethodRun:
    """`laps` timed laps on a line `offset_m` left of the centreline, speed along s."""
    L = track.length_m
    s = np.tile(np.linspace(0.0, L, 120, endpoint=False), laps)
    lap = np.repeat(np.arange(1, laps + 1), 120)
    xy = np.array([track.point_at(v) for v in s])
    h = np.array([track.heading_at(v) for v in s])
    xy = xy + offset_m * np.stack([-np.sin(h), np.cos(h)], axis=1)
    v = 2.0 + 0.5 * np.cos(2 * np.pi * s / L) + offset_m
    tr = Trace(t_s=list(np.arange(s.size) * 0.05), s_m=list(s), x_m=list(xy[:, 0]),
               y_m=list(xy[:, 1]), speed_mps=list(v), cmd_speed_mps=list(v),
               e_con_m=[offset_m] * s.size, beta=[0.5] * s.size, lap=list(lap))
    recs = [LapRecord(L / (2.0 + offset_m + 0.001 * k), 2.0 + offset_m + 0.001 * k,
                      int(bool(off_xy)), 0.1) for k in range(laps)]
    rng = np.random.default_rng(len(name))
    return MethodRun(name, recs, tr, list(rng.gamma(4.0, 0.4, 300)), 0, laps,
                     run_off_track_events=len(off_xy or []), off_track_xy=list(off_xy or []))


def _reference(track: Track) -> ReferenceLine:
    s = np.linspace(0.0, track.length_m, 80, endpoint=False)
    xy = np.array([track.point_at(v) for v in s])
    return ReferenceLine(track.length_m / 2.6, xy[:, 0], xy[:, 1], s, np.full(80, 2.6))


def _all_figures(track: Track, runs: list[MethodRun], reference: ReferenceLine | None):
    profile = track_profile(track, RacestackConfig().curvature)
    return {
        "fig4": draw_curvature(profile),
        "fig5": draw_speed_vs_s(profile, runs, reference),
        "fig6": draw_trajectories(track, runs, reference),
        "fig7": draw_laps(runs, reference, length_m=track.length_m),
        "fig8": draw_solve_time(runs, planner_period_s=0.05),
    }


@pytest.fixture(scope="module")
def figures():
    track = _ellipse()
    runs = [_run(track, "cimpcc", 3), _run(track, "mpcc", 3, 0.1, [(3.0, 0.0)]),
            _run(track, "raceline", 3, 0.02)]
    figs = _all_figures(track, runs, _reference(track))
    for fig in figs.values():
        fig.canvas.draw()
    yield figs
    from matplotlib import pyplot as plt

    for fig in figs.values():
        plt.close(fig)


def test_fig_save_helper_writes_pdf_svg_and_a_300_dpi_png(tmp_path) -> None:
    from matplotlib import pyplot as plt

    fig = plt.figure(figsize=(4.0, 3.0), layout="constrained")
    fig.subplots().plot([0, 1], [1, 0], label="a line")
    fig.legends.clear()
    paths = save_figure(fig, tmp_path / "fig9_test")
    assert FORMATS == ("pdf", "svg", "png") and DPI == 300
    assert [p.name for p in paths] == ["fig9_test.pdf", "fig9_test.svg", "fig9_test.png"]
    assert paths[0].read_bytes()[:5] == b"%PDF-"
    assert b"<svg" in paths[1].read_bytes()[:2000]
    with Image.open(paths[2]) as png:
        assert png.size == (1200, 900)  # the figure's own size x 300 dpi: no tight bbox
        assert png.info["dpi"] == pytest.approx((300, 300), abs=0.1)
    only = save_figure(plt.figure(figsize=(2, 2)), tmp_path / "x.png", formats=("png",))
    assert [p.name for p in only] == ["x.png"]


def test_fig_formats_are_parsed_and_a_wrong_one_is_an_argument_error() -> None:
    assert parse_formats("PNG, pdf,png") == ("png", "pdf")
    with pytest.raises(ValueError, match="unknown figure format 'jpg'"):
        parse_formats("png,jpg")
    with pytest.raises(ValueError, match="no figure format"):
        parse_formats(" , ")
    ap = argparse.ArgumentParser()
    add_figure_formats_argument(ap)
    assert ap.parse_args([]).figure_formats == FORMATS
    assert ap.parse_args(["--figure-formats", "svg"]).figure_formats == ("svg",)
    with pytest.raises(SystemExit):
        ap.parse_args(["--figure-formats", "bmp"])


def test_fig_no_title_starts_with_fig(figures) -> None:
    for name, fig in figures.items():
        titles = [fig._suptitle.get_text()] + [ax.get_title() for ax in fig.axes]
        assert titles[0], name
        assert not any(t.lstrip().startswith("Fig") for t in titles), (name, titles)


def test_fig_legends_inside_the_figure_and_the_size_kept(figures) -> None:
    sizes = {"fig4": (9, 5.5), "fig5": (10, 6.2), "fig7": (11.5, 5.0), "fig8": (10, 4.8)}
    for name, fig in figures.items():
        if name in sizes:
            assert tuple(fig.get_size_inches()) == pytest.approx(sizes[name]), name
        box = fig.bbox
        legends = [*fig.legends, *(lg for sf in fig.subfigs for lg in sf.legends),
                   *(ax.get_legend() for ax in fig.axes if ax.get_legend())]
        assert legends, name
        for lg in legends:
            ext = lg.get_window_extent()
            assert ext.x0 >= box.x0 - 1 and ext.x1 <= box.x1 + 1, name
            assert ext.y0 >= box.y0 - 1 and ext.y1 <= box.y1 + 1, name
        for lg in (lg for sf in fig.subfigs for lg in sf.legends):  # the rows over no axes
            for ax in fig.axes:
                assert not lg.get_window_extent().overlaps(ax.get_window_extent()), name


def test_fig4_names_its_lower_axis_and_keeps_the_raw_curvature_in_the_back(figures) -> None:
    top, low = figures["fig4"].axes
    assert "[-]" not in low.get_ylabel() and "[1]" in low.get_ylabel()
    assert "NSC" in low.get_ylabel() and "beta" in low.get_ylabel()
    raw, smoothed = top.get_lines()[:2]
    assert raw.get_linewidth() < smoothed.get_linewidth() and raw.get_alpha() < 1
    assert raw.get_zorder() < smoothed.get_zorder()
    assert top.get_ylim()[1] <= 1.4 * float(np.max(smoothed.get_ydata()))


def test_fig5_methods_differ_in_style_and_the_limit_is_drawn_behind(figures) -> None:
    speed, delta = (ax for ax in figures["fig5"].axes)
    lines = [ln for ln in speed.get_lines()]
    limit, methods = lines[0], lines[1:]
    assert limit.get_linewidth() > max(ln.get_linewidth() for ln in methods)
    assert limit.get_zorder() < min(ln.get_zorder() for ln in methods)
    firsts: dict[str, object] = {}
    for ln in methods:  # each method's first lap carries its markers
        firsts.setdefault(ln.get_color(), ln)
    assert len(firsts) == 3
    assert len({ln.get_marker() for ln in firsts.values()}) == 3
    assert len({ln.get_linestyle() for ln in firsts.values()}) > 1
    assert "min-time" in delta.get_ylabel()  # speed minus the limit's: methods part there


def test_fig6_grid_has_no_empty_cell_and_marks_off_track_events(figures) -> None:
    fig = figures["fig6"]
    panels = [ax for ax in fig.axes if ax.get_label() != "<colorbar>"]
    assert len(panels) == 6  # 3 methods + the minimum-time line + 2 zooms on a 2 x 3 grid
    assert all(ax.get_visible() and ax.has_data() for ax in panels)
    assert sum(ax.get_title().startswith("zoom") for ax in panels) == 2
    mpcc = next(ax for ax in panels if ax.get_title().startswith("mpcc"))
    assert "1 off track" in mpcc.get_title()
    crosses = [c for c in mpcc.collections
               if np.allclose(c.get_offsets(), [[3.0, 0.0]]) and
               c.get_facecolor()[0][0] == pytest.approx(1.0)]
    assert crosses and crosses[0].get_zorder() == OFF_TRACK_STYLE["zorder"]
    cimpcc = next(ax for ax in panels if ax.get_title().startswith("cimpcc"))
    assert not any(len(c.get_offsets()) == 1 and c.get_zorder() == OFF_TRACK_STYLE["zorder"]
                   for c in cimpcc.collections)


def test_fig6_grid_shape_and_zooms_on_a_long_track() -> None:
    assert grid_shape(5, 1) == (2, 3, 1)
    assert grid_shape(1, 1) == (1, 2, 1)
    assert grid_shape(5, 2) == (2, 4, 3)
    assert grid_shape(3, 1) == (1, 4, 1)
    for n in range(1, 9):
        rows, cols, zooms = grid_shape(n, 2)
        assert rows * cols == n + zooms and zooms >= 2
    long = _ellipse(60.0, 35.0, 600, wobble=0.08)
    windows = zoom_windows(long, 3, 4.0)
    assert len(windows) == 3
    for i, a in enumerate(windows):
        for b in windows[i + 1:]:
            assert np.hypot(a[1] - b[1], a[2] - b[2]) > 8.0  # separate turns
    fig = draw_trajectories(long, [_run(long, "cimpcc"), _run(long, "mpcc", 1, 0.3)])
    zooms = [ax for ax in fig.axes if ax.get_title().startswith("zoom")]
    assert len(zooms) >= 2
    for ax in zooms:  # a zoom is a few metres wide, the track hundreds
        assert np.ptp(ax.get_xlim()) < 0.2 * np.ptp(long.xy[:, 0])
        assert len([ln for ln in ax.get_lines() if ln.get_linestyle() != "None"]) >= 2


def test_fig7_one_lap_says_each_method_and_what_mean_speed_is() -> None:
    track = _ellipse()
    runs = [_run(track, "cimpcc-with-a-long-name"), _run(track, "raceline-long-name", 1, 0.02),
            _run(track, "cimpcc-line-long-name", 1, 0.03), _run(track, "no-lap")]
    runs[-1].laps.clear()  # raced, no lap: no column
    fig = draw_laps(runs, _reference(track), length_m=track.length_m)
    fig.canvas.draw()
    (legend,) = fig.subfigs[0].legends  # long labels: fewer columns, never wider than it
    ext = legend.get_window_extent()
    assert ext.x0 >= 0 and ext.x1 <= fig.bbox.x1
    main = [ax for ax in fig.axes if ax.get_lines() or ax.collections]
    assert len(main) == 1  # one lap: the per-method panel alone
    ax = main[0]
    assert [t.get_text() for t in ax.get_xticklabels()] == [
        "cimpcc-with-a-long-name", "raceline-long-name", "cimpcc-line-long-name"]
    notes = [t.get_text() for t in ax.texts]
    assert len(notes) == 3 and all("vs limit" in t for t in notes)  # close methods apart
    xs = [t.xy[0] for t in ax.texts]
    assert len(set(xs)) == 3
    speed_axis = ax.child_axes  # the secondary axis: the same lap times as mean speed
    assert speed_axis and "centreline length" in speed_axis[0].get_ylabel()
    assert "lap time" in speed_axis[0].get_ylabel()


def test_fig8_counts_planner_cycles_in_step_histograms(figures) -> None:
    fig = figures["fig8"]
    hist, cum = fig.axes[:2]
    for ax in (hist, cum):
        assert "tick" not in ax.get_ylabel().lower() and "tick" not in ax.get_xlabel().lower()
        assert "planner cycle" in ax.get_xlabel() and "[ms]" in ax.get_xlabel()
    assert "one cycle = one planner period, 50 ms" in fig._suptitle.get_text()
    assert "[%]" in hist.get_ylabel()
    assert hist.patches and not any(p.get_fill() for p in hist.patches)  # steps, unfilled


def test_fig6_zooms_go_where_the_paths_part() -> None:
    from shared.evaluation.figure_paths import path_spread

    s = np.linspace(0.0, 100.0, 1000, endpoint=False)
    wide = np.where((s >= 60) & (s < 64), 0.5, 0.0)  # the paths part between 60 and 64 m
    spread = path_spread([(s, np.zeros_like(s)), (s, wide)], 100.0, 4.0)
    assert spread is not None and spread.size == 25
    assert int(np.argmax(spread)) == 15 and spread.max() == pytest.approx(0.5)
    assert path_spread([(s, wide)], 100.0, 4.0) is None  # one path: the sharpest turns
    track = _ellipse(30.0, 20.0, 400)
    L = track.length_m
    far = np.where(np.abs(s / 100.0 * L - 0.3 * L) < 2.0, 0.4, 0.0)
    (win,) = zoom_windows(track, 1, 2.0, [(s / 100.0 * L, np.zeros_like(s)),
                                            (s / 100.0 * L, far)])
    assert abs(win[0] - 0.3 * L) < 4.0


def test_fig_all_five_draw_for_a_method_that_never_completed_a_lap(tmp_path) -> None:
    from shared.evaluation import write_figures

    track = _ellipse()
    lost = MethodRun("mpcc", [], Trace(), [], 0, 3)
    profile = track_profile(track, RacestackConfig().curvature)
    paths = write_figures(tmp_path, track, profile, [lost, _run(track, "cimpcc")],
                          formats=("svg",))
    assert len(paths) == 5 and all(p.suffix == ".svg" for p in paths)
