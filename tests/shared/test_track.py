"""Track geometry, loaders, bad files and the built-in tracks."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from shared.curvature import curvature_profile
from shared.track import BUILTIN_TRACKS, Track, TrackError, load_ros_map, load_track
from shared.track.builtin_design import DESIGNS, render_csv, sample_design
from shared.track.io import load_waypoint_triple
from shared.track.occupancy import FREE, MAX_LOCAL_TURN_RAD, OCCUPIED, inside_cells, rasterize_track


def circle_track(radius: float = 5.0, n: int = 500, width: float = 0.6) -> Track:
    t = np.linspace(0, 2 * np.pi, n, endpoint=False)
    xy = radius * np.column_stack([np.cos(t), np.sin(t)])  # counter-clockwise
    return Track("circle", xy, np.full(n, width), np.full(n, width))


def write_csv(path: Path, rows: np.ndarray, header: str = "# x_m, y_m, w_tr_right_m, w_tr_left_m"):
    lines = [header] + [", ".join(f"{v:.6f}" for v in r) for r in rows]
    path.write_text("\n".join(lines) + "\n")
    return path


def circle_rows(n: int = 50, radius: float = 5.0) -> np.ndarray:
    t = np.linspace(0, 2 * np.pi, n, endpoint=False)
    return np.column_stack(
        [radius * np.cos(t), radius * np.sin(t), np.full(n, 0.5), np.full(n, 0.5)]
    )


# ---------------------------------------------------------------- geometry
def test_arc_length_and_periodic_s() -> None:
    tr = circle_track(5.0, 2000)
    assert tr.length_m == pytest.approx(2 * np.pi * 5.0, rel=1e-5)
    assert tr.wrap_s(tr.length_m + 1.0) == pytest.approx(1.0)
    assert tr.wrap_s(-1.0) == pytest.approx(tr.length_m - 1.0)


def test_projection_gives_s_and_signed_contour_error() -> None:
    tr = circle_track(5.0, 2000)
    # counter-clockwise circle: the centre (left) is inside, outside is to the right
    s, e = tr.project(np.array([5.3, 0.0]))
    assert s == pytest.approx(0.0, abs=1e-3) or s == pytest.approx(tr.length_m, abs=1e-3)
    assert e == pytest.approx(0.3, abs=1e-3)
    s, e = tr.project(np.array([0.0, 4.8]))
    assert s == pytest.approx(np.pi / 2 * 5.0, abs=2e-3)
    assert e == pytest.approx(-0.2, abs=1e-3)
    s_many, e_many = tr.project(np.array([[5.3, 0.0], [0.0, 4.8]]))
    assert e_many.shape == (2,)
    s_hint, _ = tr.project(np.array([0.0, 4.8]), s_hint=7.0, window_m=2.0)
    assert s_hint == pytest.approx(s_many[1], abs=1e-9)


def test_boundaries_and_inside() -> None:
    tr = circle_track(5.0, 1000, width=0.6)
    r_left = np.hypot(*tr.left_boundary.T)
    r_right = np.hypot(*tr.right_boundary.T)
    np.testing.assert_allclose(r_left, 4.4, atol=1e-6)
    np.testing.assert_allclose(r_right, 5.6, atol=1e-6)
    assert tr.is_inside(np.array([[5.5, 0.0], [4.5, 0.0]])).all()
    assert not tr.is_inside(np.array([[5.7, 0.0], [4.3, 0.0]])).any()


def test_signed_curvature_of_circle() -> None:
    tr = circle_track(4.0, 800)
    np.testing.assert_allclose(tr.signed_curvature(), 0.25, rtol=1e-3)


# ---------------------------------------------------------------- loaders
def test_f1tenth_centreline_roundtrip(tmp_path: Path) -> None:
    path = write_csv(tmp_path / "Ring_centerline.csv", circle_rows())
    tr = load_track(path)
    assert tr.name == "Ring" and tr.n_points == 50
    assert tr.w_left_m[0] == 0.5
    assert load_track(tmp_path).n_points == 50  # the folder form


def test_waypoint_triple(tmp_path: Path) -> None:
    t = np.linspace(0, 2 * np.pi, 40, endpoint=False)
    c = np.column_stack([5 * np.cos(t), 5 * np.sin(t)])
    left = c * (4.4 / 5.0)  # CCW: inside is left
    right = c * (5.7 / 5.0)
    for name, arr in (("centerline", c), ("left", left), ("right", right)):
        closed = np.vstack([arr, arr[:1]])  # files repeat the first point
        np.savetxt(tmp_path / f"ring_track_{name}_waypoints.csv", closed, delimiter=",")
    tr = load_track(tmp_path)
    assert tr.n_points == 40
    np.testing.assert_allclose(tr.w_left_m, 0.6, atol=0.02)
    np.testing.assert_allclose(tr.w_right_m, 0.7, atol=0.02)
    with pytest.raises(TrackError, match="right of the driving direction"):
        load_waypoint_triple(
            tmp_path / "ring_track_centerline_waypoints.csv",
            tmp_path / "ring_track_right_waypoints.csv",
            tmp_path / "ring_track_left_waypoints.csv",
        )


@pytest.mark.parametrize(
    ("mutate", "message"),
    [
        (lambda r: r[:, :3], "missing column(s) w_tr_left_m"),
        (lambda r: np.where(np.arange(r.size).reshape(r.shape) == 21, np.nan, r), "NaN"),
        (lambda r: r[:8], "at least 10"),
        (lambda r: r[:40], "open loop"),
        (
            lambda r: np.column_stack([r[:, :2], np.zeros(len(r)), r[:, 3]]),
            "zero or negative right width",
        ),
    ],
    ids=["missing-column", "nan", "too-few-points", "open-loop", "zero-width"],
)
def test_bad_track_files_fail_with_one_clear_error(tmp_path: Path, mutate, message) -> None:
    rows = mutate(circle_rows())
    header = (
        "# x_m, y_m, w_tr_right_m"
        if rows.shape[1] == 3
        else "# x_m, y_m, w_tr_right_m, w_tr_left_m"
    )
    path = write_csv(tmp_path / "bad_centerline.csv", rows, header)
    with pytest.raises(TrackError) as info:
        load_track(path)
    text = str(info.value)
    assert str(path) in text
    assert message in text


def test_self_crossing_loop_is_rejected(tmp_path: Path) -> None:
    t = np.linspace(0, 2 * np.pi, 80, endpoint=False)
    figure_eight = np.column_stack(
        [5 * np.sin(t + 0.02), 3 * np.sin(2 * t + 0.04), np.full(80, 0.4), np.full(80, 0.4)]
    )
    path = write_csv(tmp_path / "eight_centerline.csv", figure_eight)
    with pytest.raises(TrackError, match="self-crossing"):
        load_track(path)


def test_the_broad_phase_finds_what_the_all_pairs_scan_finds() -> None:
    from shared.track.geometry import find_self_crossing, find_self_crossing_all_pairs

    rng = np.random.default_rng(5)
    found = 0
    for k in range(300):
        n = int(rng.integers(4, 40))
        if k % 3 == 0:  # random walks: crossings everywhere
            xy = np.cumsum(rng.normal(0.0, 1.0, (n, 2)), axis=0)
        elif k % 3 == 1:  # wobbly circles: mostly simple, some cross
            t = np.linspace(0, 2 * np.pi, n, endpoint=False)
            r = 3.0 + rng.normal(0.0, 0.8, n)
            xy = np.column_stack([r * np.cos(t), r * np.sin(t)])
        else:  # a loop on a lattice: collinear overlaps and vertices on other segments
            xy = rng.integers(0, 4, (n, 2)).astype(float)
            xy = xy[np.r_[True, np.any(np.diff(xy, axis=0) != 0, axis=1)]]
            if xy.shape[0] < 4 or np.array_equal(xy[0], xy[-1]):
                continue
        fast, slow = find_self_crossing(xy), find_self_crossing_all_pairs(xy)
        assert fast == slow, (k, fast, slow)
        found += fast is not None
    assert 100 < found < 280  # both kinds of answer were exercised
    # a fine loop (4000 points, 0.1 m apart) is simple; a nudge into it is found
    t = np.linspace(0, 2 * np.pi, 4000, endpoint=False)
    ring = np.column_stack([64 * np.cos(t), 64 * np.sin(t)])
    assert find_self_crossing(ring) is None
    ring[2000] = ring[10] * 1.001
    hit = find_self_crossing(ring)
    assert hit is not None and hit == find_self_crossing_all_pairs(ring)


def test_missing_and_unknown_specs(tmp_path: Path) -> None:
    with pytest.raises(TrackError, match="not a built-in"):
        load_track("no_such_track")
    with pytest.raises(TrackError, match="unknown built-in"):
        load_track("builtin:nope")
    (tmp_path / "notes.txt").write_text("hello")
    with pytest.raises(TrackError, match="unsupported"):
        load_track(tmp_path / "notes.txt")
    with pytest.raises(TrackError, match="no \\*_centerline"):
        load_track(tmp_path)
    garbage = tmp_path / "junk_centerline.csv"
    garbage.write_bytes(b"\xff\xfe\x00garbage")
    with pytest.raises(TrackError, match=str(garbage.name)):
        load_track(garbage)


# ---------------------------------------------------------------- built-in tracks
def test_builtin_files_match_their_design() -> None:
    for name, design in DESIGNS.items():
        shipped = (
            Path(__file__).resolve().parents[2] / "shared/track/builtin" / f"{name}_centerline.csv"
        )
        assert shipped.read_text() == render_csv(sample_design(design)), name


def test_paperlike_track_is_like_the_papers() -> None:
    tr = load_track("builtin:paperlike")
    assert 30.0 <= tr.length_m <= 60.0
    np.testing.assert_allclose(tr.w_left_m + tr.w_right_m, 1.2)
    prof = curvature_profile(tr.xy, tr.s_m, tr.length_m, 1.2, 5.0)
    sharp = prof.kappa > 1.0 / 1.2  # radius under 1.2 m
    # count separate sharp turns (runs of sharp points, periodic)
    starts = np.sum(sharp & ~np.roll(sharp, 1))
    assert starts >= 4
    # straights between them
    assert np.sum(prof.kappa < 1e-3) * tr.spacing_m > 10.0  # radius > 1 km


def test_gentle_track_is_gentler() -> None:
    gentle = load_track("gentle")
    paper = load_track("paperlike")
    assert np.abs(gentle.signed_curvature()).max() < 0.5 * np.abs(paper.signed_curvature()).max()
    assert set(BUILTIN_TRACKS) == {"paperlike", "gentle"}


def test_rasterised_track_is_free_inside() -> None:
    tr = load_track("gentle")
    grid = rasterize_track(tr, resolution_m=0.1)
    assert not grid.occupied_at(tr.xy[::50]).any()
    outside = tr.xy[::50] - 1.5 * tr.left_normal_unit()[::50]
    assert grid.occupied_at(outside).all()
    assert set(np.unique(grid.cells)) <= {FREE, OCCUPIED}


def _inside_everywhere(tr: Track, step_m: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Grid points around `tr` and ``Track.is_inside`` at each (the all-segments oracle)."""
    lo = np.minimum(tr.left_boundary.min(0), tr.right_boundary.min(0)) - 1.0
    hi = np.maximum(tr.left_boundary.max(0), tr.right_boundary.max(0)) + 1.0
    cx = np.arange(lo[0], hi[0], step_m)
    cy = np.arange(lo[1], hi[1], step_m)
    gx, gy = np.meshgrid(cx, cy)
    oracle = tr.is_inside(np.stack([gx.ravel(), gy.ravel()], axis=1)).reshape(cy.size, cx.size)
    return cx, cy, oracle


def _polygon_track(corners: np.ndarray, per_side: int, width: float) -> Track:
    """A closed loop through `corners` (straight sides, sharp corners), `per_side` points each."""
    pts = []
    for a, b in zip(corners, np.roll(corners, -1, axis=0), strict=True):
        f = np.linspace(0.0, 1.0, per_side, endpoint=False)[:, None]
        pts.append(a + f * (b - a))
    xy = np.concatenate(pts)
    n = xy.shape[0]
    return Track("polygon", xy, np.full(n, width), np.full(n, width))


@pytest.mark.parametrize("spec", ["gen:3", "gen:7", "gen:19", "paperlike"])
def test_inside_cells_is_the_full_projection(spec: str) -> None:
    """The local rasteriser gives exactly ``Track.is_inside`` at every grid point."""
    tr = load_track(spec)
    cx, cy, oracle = _inside_everywhere(tr, 0.13)
    fast = inside_cells(tr, cx, cy)
    assert oracle.sum() > 1000
    np.testing.assert_array_equal(fast, oracle)


@pytest.mark.parametrize("sides", [3, 4, 7])
def test_inside_cells_at_sharp_corners(sides: int) -> None:
    """Corners of 120 / 90 / 51 degrees: beyond ``MAX_LOCAL_TURN_RAD`` the full search, below
    it the local one with its reach grown by 1 / cos(turn); both equal the oracle, also on
    the points outside a corner whose nearest centreline point is the vertex."""
    ang = np.linspace(0.0, 2.0 * np.pi, sides, endpoint=False)
    tr = _polygon_track(6.0 * np.column_stack([np.cos(ang), np.sin(ang)]), 30, 0.8)
    turn = 2.0 * np.pi / sides
    assert (turn > MAX_LOCAL_TURN_RAD) == (sides < 5)
    cx, cy, oracle = _inside_everywhere(tr, 0.07)
    np.testing.assert_array_equal(inside_cells(tr, cx, cy), oracle)


# ---------------------------------------------------------------- real data in ../shared
def test_map416_both_formats_agree(shared_tracks: Path) -> None:
    triple = load_track(shared_tracks / "map416")
    f1 = load_track(shared_tracks / "map416" / "map416_centerline.csv")
    assert triple.length_m == pytest.approx(32.77, abs=0.05)
    assert f1.length_m == pytest.approx(triple.length_m, abs=0.05)
    np.testing.assert_allclose(triple.w_left_m + triple.w_right_m, 1.2, atol=0.01)
    prof = curvature_profile(triple.xy, triple.s_m, triple.length_m, 1.2, 5.0)
    assert 1.0 / prof.smoothed.max() == pytest.approx(0.9, abs=0.08)
    # clockwise: the total turn is -2 pi
    _, _, _, phi = triple.closed_arrays()
    assert phi[-1] - phi[0] == pytest.approx(-2 * np.pi, abs=1e-6)


@pytest.mark.parametrize(
    "name", ["Spielberg", "Monza", "Silverstone", "Austin", "Oschersleben", "YasMarina"]
)
def test_f1tenth_tracks_load(shared_tracks: Path, name: str) -> None:
    tr = load_track(shared_tracks / "f1tenth" / name)
    expected = {
        "Spielberg": 343,
        "Monza": 446,
        "Silverstone": 458,
        "Austin": 421,
        "Oschersleben": 261,
        "YasMarina": 398,
    }
    assert tr.length_m == pytest.approx(expected[name], rel=0.02)
    np.testing.assert_allclose(tr.w_left_m + tr.w_right_m, 2.2, atol=0.01)


def test_ros_map_loads_as_occupancy_grid(shared_tracks: Path) -> None:
    grid = load_ros_map(shared_tracks / "map416" / "map416.yaml")
    assert grid.shape == (422, 381)
    assert grid.resolution_m == 0.05
    tr = load_track(shared_tracks / "map416")
    # the centreline runs through free space of the real map
    assert np.mean(grid.occupied_at(tr.xy)) < 0.02
    png = load_ros_map(shared_tracks / "f1tenth" / "Monza" / "Monza_map.yaml")
    monza = load_track(shared_tracks / "f1tenth" / "Monza")
    assert np.mean(png.occupied_at(monza.xy)) < 0.02


def test_bad_map_yaml(tmp_path: Path) -> None:
    (tmp_path / "m.yaml").write_text("image: missing.pgm\nresolution: 0.05\norigin: [0, 0, 0]\n")
    with pytest.raises(TrackError, match=r"missing\.pgm"):
        load_ros_map(tmp_path / "m.yaml")
    (tmp_path / "n.yaml").write_text("resolution: 0.05\n")
    with pytest.raises(TrackError, match="no 'image'"):
        load_ros_map(tmp_path / "n.yaml")


@pytest.mark.parametrize("name", ["paperlike", "gentle"])
def test_windowed_single_point_projection_matches_the_full_search(name: str) -> None:
    """The per-tick path (one point, a window around a hint, also across the start line)
    gives exactly what the full vectorised search gives."""
    tr = load_track(name)
    rng = np.random.default_rng(7)
    s_true = np.concatenate([rng.uniform(0, tr.length_m, 400), [0.0, 1e-9, tr.length_m - 1e-9]])
    pts = tr.point_at(s_true) + rng.normal(0.0, 0.3, (len(s_true), 2))
    s_all, e_all = tr.project(pts)
    L = tr.length_m
    for i, p in enumerate(pts):
        hint = float((s_true[i] + rng.normal(0.0, 1.0)) % L)
        s1, e1 = tr.project(p, s_hint=hint, window_m=5.0)
        s0, e0 = tr.project(p)
        assert np.ndim(s1) == 0 and np.ndim(e1) == 0
        assert e1 == pytest.approx(e_all[i], abs=1e-12) and e0 == pytest.approx(e1, abs=1e-12)
        ds = (s1 - s_all[i] + L / 2) % L - L / 2
        assert abs(ds) < 1e-9 and abs((s0 - s1 + L / 2) % L - L / 2) < 1e-9


@pytest.mark.parametrize("name", ["paperlike", "gentle"])
def test_project_near_gives_what_project_gives(name: str) -> None:
    """The planner's per-tick projection (plain Python, +-1 m around the hint) equals the
    windowed numpy one: near hints, across the start line, and with far hints (fallback)."""
    tr = load_track(name)
    L = tr.length_m
    rng = np.random.default_rng(3)
    s_true = np.concatenate([rng.uniform(0, L, 500), [0.0, 1e-9, L - 1e-9, L - 0.3, 0.3]])
    pts = tr.point_at(s_true) + rng.normal(0.0, 0.3, (len(s_true), 2))
    for i, p in enumerate(pts):
        for spread in (0.2, 3.0):  # 3 m: often past the +-1 m search, so the fallback runs
            hint = float((s_true[i] + rng.normal(0.0, spread)) % L)
            s1, e1 = tr.project_near(float(p[0]), float(p[1]), hint)
            s0, e0 = tr.project(p, s_hint=hint, window_m=5.0)
            assert isinstance(s1, float) and isinstance(e1, float)
            assert e1 == pytest.approx(float(e0), abs=1e-12)
            assert abs((s1 - float(s0) + L / 2) % L - L / 2) < 1e-9
    s_nan, e_nan = tr.project_near(1.0, 2.0, float("nan"))  # no usable hint: full search
    s_all, e_all = tr.project(np.array([1.0, 2.0]))
    assert (s_nan, e_nan) == (float(s_all), float(e_all))
