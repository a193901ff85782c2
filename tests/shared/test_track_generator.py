"""The seeded track generator: deterministic, valid, within its spec, with its features."""

from __future__ import annotations

import functools
import itertools
import json
from collections import Counter
from pathlib import Path

import numpy as np
import pytest

from shared.track import Track, TrackError, load_track
from shared.track.builtin_design import TRANSITION_M
from shared.track.generator import (
    DISTANT_ARC_FACTOR,
    FEATURE_KINDS,
    GENERATED_SEEDS,
    TUNING_SEEDS,
    GeneratedTrack,
    GeneratorSpec,
    describe,
    generate,
    generate_track,
    stretch_gap_m,
)
from shared.track.geometry import find_self_crossing

SPEC = GeneratorSpec()
ALL_SEEDS = GENERATED_SEEDS + TUNING_SEEDS


@functools.cache
def generated(seed: int) -> GeneratedTrack:
    """Each seed's track, generated once for the whole module."""
    return generate(seed)


def arc_separation(track: Track) -> np.ndarray:
    """(n, n) arc length between every two points, the shorter way round the loop [m]."""
    ds = np.abs(track.s_m[:, None] - track.s_m[None, :])
    return np.minimum(ds, track.length_m - ds)


# ---------------------------------------------------------------- seeds and determinism
def test_the_seed_lists_are_fixed_and_disjoint() -> None:
    assert len(GENERATED_SEEDS) >= 20 and len(TUNING_SEEDS) >= 8
    assert len(set(GENERATED_SEEDS)) == len(GENERATED_SEEDS)
    assert len(set(TUNING_SEEDS)) == len(TUNING_SEEDS)
    assert not set(GENERATED_SEEDS) & set(TUNING_SEEDS)
    assert all(isinstance(s, int) and s >= 0 for s in ALL_SEEDS)


def test_a_seed_gives_identical_arrays_every_time() -> None:
    a = generated(7).track
    b = generate_track(7)
    assert a is not b and find_self_crossing(b.xy) is None
    for name in ("xy", "w_right_m", "w_left_m"):
        assert np.array_equal(getattr(a, name), getattr(b, name))
    assert (a.name, a.source) == (b.name, b.source) == ("gen-7", "gen:7")


def test_different_seeds_give_different_tracks() -> None:
    tracks = [generated(s).track for s in GENERATED_SEEDS[:6]]
    for i, a in enumerate(tracks):
        for b in tracks[i + 1:]:
            assert a.xy.shape != b.xy.shape or not np.allclose(a.xy, b.xy)


# ---------------------------------------------------------------- every track is drivable
@pytest.mark.parametrize("seed", ALL_SEEDS)
def test_each_track_is_valid_and_within_the_spec(seed: int) -> None:
    gen = generated(seed)
    track = gen.track  # a Track: validate_loop passed (closed, no self-crossing)
    assert isinstance(track, Track) and track.n_points >= 10
    assert SPEC.length_m[0] <= track.length_m <= SPEC.length_m[1]
    width = track.w_left_m + track.w_right_m
    assert SPEC.width_m[0] - 1e-9 <= width.min() and width.max() <= SPEC.width_m[1] + 1e-9
    assert gen.width_range_m == pytest.approx((width.min(), width.max()), abs=1e-3)
    step = np.hypot(*(np.roll(track.xy, -1, axis=0) - track.xy).T)
    # the width is constant or varies smoothly (well under 0.2 m per metre)
    assert np.max(np.abs(np.roll(width, -1) - width) / step) < 0.2
    # every radius is at least the tightest one, which a hairpin reaches, and more than the
    # half width (the inner boundary has no cusp)
    kappa = np.abs(track.signed_curvature())
    r_min = 1.0 / kappa.max()
    assert r_min == pytest.approx(gen.tightest_radius_m, rel=1e-6)
    assert SPEC.tightest_radius_m[0] - 1e-9 <= r_min <= SPEC.tightest_radius_m[1] + 1e-9
    half = np.maximum(track.w_left_m, track.w_right_m)
    assert np.all(half * kappa < 1.0)
    assert half.max() <= r_min - SPEC.inner_radius_m + 1e-9
    # no kinks: the curvature ramps, at most from +1/r to -1/r over a transition
    dk = np.abs(np.roll(track.signed_curvature(), -1) - track.signed_curvature()) / step
    assert dk.max() <= 2.0 / (gen.tightest_radius_m * TRANSITION_M)


@pytest.mark.parametrize("seed", ALL_SEEDS)
def test_boundaries_of_distant_stretches_keep_their_gap(seed: int) -> None:
    track = generated(seed).track
    c = track.xy
    d_c = np.hypot(c[:, None, 0] - c[None, :, 0], c[:, None, 1] - c[None, :, 1])
    distant = arc_separation(track) > DISTANT_ARC_FACTOR * d_c
    w_max = float(max(track.w_left_m.max(), track.w_right_m.max()))
    i, j = np.nonzero(distant & (d_c < 2 * w_max + SPEC.min_gap_m + 0.1))  # the others are far
    edges = (track.left_boundary, track.right_boundary)
    for a in edges:
        for b in edges:
            assert np.all(np.hypot(*(a[i] - b[j]).T) >= SPEC.min_gap_m), (seed, len(i))
    assert stretch_gap_m(track.xy, np.maximum(track.w_left_m, track.w_right_m)) >= SPEC.min_gap_m


# ---------------------------------------------------------------- features
@pytest.mark.parametrize("seed", ALL_SEEDS)
def test_the_features_tile_the_track_and_match_their_kind(seed: int) -> None:
    gen = generated(seed)
    track, feats = gen.track, gen.features
    assert {f.kind for f in feats} <= set(FEATURE_KINDS)
    assert feats[0].s_start_m == 0.0 and feats[0].kind == "straight"  # the start straight
    for a, b in itertools.pairwise(feats):
        assert b.s_start_m == pytest.approx(a.s_start_m + a.length_m, abs=1e-9)
    assert feats[-1].s_start_m + feats[-1].length_m == pytest.approx(track.length_m, abs=1e-6)
    assert sum(f.turn_deg for f in feats if f.kind != "chicane") == pytest.approx(360.0)
    kappa = np.abs(track.signed_curvature())
    for f in feats:
        inside = (track.s_m >= f.s_start_m) & (track.s_m <= f.s_start_m + f.length_m)
        if f.kind == "hairpin":
            assert 160.0 <= abs(f.turn_deg) <= 200.0
            assert gen.tightest_radius_m <= f.radius_m <= 1.25 * gen.tightest_radius_m + 0.01
            assert kappa[inside].max() == pytest.approx(1.0 / f.radius_m, rel=1e-3)
        elif f.kind == "fast_bend":
            assert f.radius_m >= SPEC.fast_bend_radius_m[0] and 60 <= abs(f.turn_deg) <= 150
            assert f.length_m >= np.radians(60.0) * SPEC.fast_bend_radius_m[0]
        elif f.kind == "chicane":
            assert 30.0 <= abs(f.turn_deg) <= 65.0
        elif f.kind == "straight":
            assert f.turn_deg == 0.0 and f.length_m > 0.0


def test_every_kind_is_well_represented_over_the_measuring_set() -> None:
    per_track = [Counter(f.kind for f in generated(s).features) for s in GENERATED_SEEDS]
    for kind in ("hairpin", "chicane", "fast_bend"):
        assert sum(1 for c in per_track if c[kind]) >= 0.75 * len(GENERATED_SEEDS), kind
        assert sum(c[kind] for c in per_track) >= len(GENERATED_SEEDS), kind
    both = sum(1 for c in per_track if c["hairpin"] and c["chicane"] and c["fast_bend"])
    assert both >= 0.75 * len(GENERATED_SEEDS)
    lengths = [generated(s).track.length_m for s in GENERATED_SEEDS]
    assert min(lengths) < 40.0 and max(lengths) > 100.0  # short and long tracks
    radii = [generated(s).tightest_radius_m for s in GENERATED_SEEDS]
    assert min(radii) < 0.8 and max(radii) > 1.3
    straights = [f.length_m for s in GENERATED_SEEDS for f in generated(s).features
                 if f.kind == "straight"]
    assert min(straights) < 1.0 and max(straights) > 10.0


def test_describe_lists_what_was_built() -> None:
    gen = generated(7)
    d = describe(gen)
    assert d["length_m"] == pytest.approx(gen.track.length_m, abs=1e-3)
    assert d["tightest_radius_m"] == pytest.approx(gen.tightest_radius_m, abs=1e-3)
    assert (d["width_min_m"], d["width_max_m"]) == pytest.approx(gen.width_range_m, abs=1e-3)
    kinds = Counter(f.kind for f in gen.features)
    assert (d["hairpins"], d["chicanes"], d["fast_bends"]) == (
        kinds["hairpin"], kinds["chicane"], kinds["fast_bend"]
    )
    assert describe(gen.track) == d  # a plain Track of gen:SEED is regenerated
    json.dumps(d)  # plain values
    t = np.linspace(0.0, 2.0 * np.pi, 200, endpoint=False)
    circle = Track("circle", 3.0 * np.column_stack([np.cos(t), np.sin(t)]),
                   np.full(200, 0.5), np.full(200, 0.5))
    plain = describe(circle)
    assert "hairpins" not in plain and plain["tightest_radius_m"] == pytest.approx(3.0, rel=1e-3)
    assert plain["stretch_gap_m"] is None  # a circle has no distant stretches


# ---------------------------------------------------------------- loading and the spec
def test_load_track_accepts_gen_seed() -> None:
    seed = GENERATED_SEEDS[1]
    track = load_track(f"gen:{seed}")
    assert np.array_equal(track.xy, generated(seed).track.xy)
    assert (track.name, track.source) == (f"gen-{seed}", f"gen:{seed}")
    for bad in ("gen:", "gen:x", "gen:-3", "gen:1.5"):
        with pytest.raises(TrackError, match="gen:SEED"):
            load_track(bad)
    with pytest.raises(TrackError, match="gen:SEED"):
        load_track("no-such-track-anywhere")


def test_a_custom_spec_is_obeyed_and_named_apart() -> None:
    spec = GeneratorSpec(length_m=(30.0, 45.0), width_m=(0.9, 1.0),
                         tightest_radius_m=(0.6, 0.7), varying_width_share=0.0)
    gen = generate(5, spec)
    t = gen.track
    assert 30.0 <= t.length_m <= 45.0 and 0.6 <= gen.tightest_radius_m <= 0.7
    assert np.all(t.w_left_m + t.w_right_m == gen.width_range_m[0])
    assert t.source != "gen:5"  # not what load_track("gen:5") gives
    with pytest.raises(ValueError, match="narrowest width"):
        GeneratorSpec(width_m=(1.5, 2.2), tightest_radius_m=(0.6, 1.5))
    with pytest.raises(TrackError, match="gen:7: no valid track in 1 layouts"):
        generate(7, GeneratorSpec(max_attempts=1))  # seed 7's first layout fails a check
    with pytest.raises(TrackError, match="integer"):
        generate(-1)


# ---------------------------------------------------------------- drivable in the bench
@pytest.mark.slow
@pytest.mark.parametrize("seed", (3, 7, 15))  # tight and narrow; short and wide; varying width
def test_cimpcc_completes_a_lap_on_a_generated_track(seed: int, tmp_path: Path) -> None:
    from services.tools.bench.run import main

    out = tmp_path / "bench"
    rc = main(["--track", f"gen:{seed}", "--laps", "1", "--methods", "cimpcc", "--no-figures",
               "--no-reference", "--out", str(out)])
    assert rc == 0
    doc = json.loads((out / "results.json").read_text())
    assert doc["track"] == f"gen-{seed}"
    assert doc["methods"]["cimpcc"]["completed_laps"] == 1
