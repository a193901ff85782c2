"""Seeded random closed tracks for the robustness benchmark (pure: numpy only, no I/O).

``generate_track(seed)`` builds the same ``Track`` for a seed on every machine; a track spec
``gen:SEED`` (``shared.track.load_track``) names it wherever a track is accepted (``--track
gen:7``, ``[track] source = "gen:7"``). ``GENERATED_SEEDS`` is the fixed set the benchmark
measures on, ``TUNING_SEEDS`` a disjoint set to tune on.

A track is designed like the built-in ones (``shared.track.builtin_design``): a closed
sequence of straights and circular arcs driven counter-clockwise, the curvature ramping over
``builtin_design.TRANSITION_M`` between segments, two straights solved so that the loop
closes. Per seed the generator draws the tightest radius, the width (constant, or varying
smoothly along the track) and a target length within a ``GeneratorSpec``; per attempt it
draws a layout of features in random order with a straight after each:

- hairpin: one arc of 160-200 deg at (1-1.25 x) the tightest radius (the first exactly at it);
- chicane: a left-right (or right-left) pair of 30-65 deg arcs of 1-1.8 x the tightest radius;
- fast bend: one long arc of 60-150 deg with a radius of 3 m or more (taken at top speed);
- corner: arcs of 1-2.5 x the tightest radius that bring the total turn to +360 deg;
- straight: lengths from 0.3 m to well over 10 m, scaled so the lap comes near the target.

An attempt is kept when the closing straights come out at least ``MIN_CLOSING_M`` long, the
lap length is within the spec, no two distant stretches come closer than ``min_gap_m``
between their boundaries (``stretch_gap_m``), every centreline radius is at least the
tightest radius (and so more than the largest half width) and the centreline does not cross
itself (``shared.track.geometry.validate_loop``); otherwise the next attempt draws a new
layout from the sub-seed ``(seed, attempt)``, up to ``max_attempts``. All draws use
``numpy.random.default_rng`` with its plain uniform doubles (``Generator.random``), rounded to
1 cm and 0.5 deg, so a seed gives the same design on every machine (and the same points, up
to the last bits of the platform's floating point).

To look at one: ``racestack mintime --track gen:7 --out DIR`` writes the track with its
minimum-time line (``DIR/mintime_line.png``); ``describe(generate(7))`` lists what was built.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from shared.track.builtin_design import loop_end, sample_design, solve_closure_smooth
from shared.track.errors import TrackError
from shared.track.geometry import Track

#: Seeds of the generated tracks the benchmark measures on (fixed: the same set everywhere).
GENERATED_SEEDS: tuple[int, ...] = tuple(range(1, 21))
#: Seeds of the generated tracks to tune on, disjoint from ``GENERATED_SEEDS``.
TUNING_SEEDS: tuple[int, ...] = tuple(range(1001, 1009))

#: Kinds of the features a generated track is made of.
FEATURE_KINDS = ("hairpin", "chicane", "fast_bend", "corner", "straight")

#: Two centreline points are on distant stretches when the track between them (the shorter
#: way round) is more than this many times as long as the straight line between them.
DISTANT_ARC_FACTOR = 3.0
#: Shortest closing straight [m] (the first one is the start straight).
MIN_CLOSING_M = 1.0
#: A lap may differ from the seed's target length by this share of it.
LENGTH_TOLERANCE = 0.2
#: Point spacing of the quick first check of a layout [m].
COARSE_SPACING_M = 0.2
#: Slack of that quick check [m] (its coarser smoothing moves the loop by a few cm).
COARSE_SLACK_M = 0.05


@dataclass(frozen=True)
class GeneratorSpec:
    """The ranges a generated track is drawn from.

    Attributes:
        length_m: (min, max) lap length of the centreline [m].
        width_m: (min, max) full track width [m]; the largest is also capped by the tightest
            radius (largest half width <= tightest radius - ``inner_radius_m``).
        tightest_radius_m: (min, max) of the tightest centreline radius [m], drawn per seed.
        inner_radius_m: smallest radius of the inner boundary where the centreline is
            tightest [m] (> 0: the inner boundary has no cusp).
        fast_bend_radius_m: (min, max) radius of the fast bends [m] (the longer tracks reach
            the larger ones).
        min_gap_m: smallest gap between the boundaries of two distant stretches [m].
        varying_width_share: probability that a track's width varies along it (smoothly,
            1-3 waves per lap between two drawn widths); else it is constant.
        spacing_m: centreline point spacing [m].
        max_attempts: layouts tried per seed before giving up (``TrackError``).
    """

    length_m: tuple[float, float] = (25.0, 120.0)
    width_m: tuple[float, float] = (0.9, 2.2)
    tightest_radius_m: tuple[float, float] = (0.6, 1.5)
    inner_radius_m: float = 0.1
    fast_bend_radius_m: tuple[float, float] = (3.0, 7.0)
    min_gap_m: float = 0.5
    varying_width_share: float = 0.5
    spacing_m: float = 0.1
    max_attempts: int = 1000

    def __post_init__(self) -> None:
        for name in ("length_m", "width_m", "tightest_radius_m", "fast_bend_radius_m"):
            lo, hi = getattr(self, name)
            if not 0.0 < lo <= hi:
                raise ValueError(f"GeneratorSpec.{name} must be 0 < min <= max, got {(lo, hi)}")
        if not 0.0 < self.inner_radius_m:
            raise ValueError("GeneratorSpec.inner_radius_m must be > 0")
        if self.width_m[0] / 2 + self.inner_radius_m > self.tightest_radius_m[0]:
            raise ValueError(
                "GeneratorSpec: the narrowest width does not fit the tightest radius "
                f"({self.width_m[0]} m wide needs a radius of at least "
                f"{self.width_m[0] / 2 + self.inner_radius_m} m)"
            )
        if self.fast_bend_radius_m[0] < self.tightest_radius_m[1]:
            raise ValueError("GeneratorSpec: fast bends must be wider than the tightest radius")
        if not (0.0 <= self.varying_width_share <= 1.0 and self.min_gap_m >= 0.0):
            raise ValueError("GeneratorSpec: varying_width_share in [0, 1], min_gap_m >= 0")
        if not (0.0 < self.spacing_m <= 0.25 and self.max_attempts >= 1):
            raise ValueError("GeneratorSpec: spacing_m in (0, 0.25], max_attempts >= 1")


DEFAULT_SPEC = GeneratorSpec()


@dataclass(frozen=True)
class Feature:
    """One feature of a generated track, in driving order.

    Attributes:
        kind: one of ``FEATURE_KINDS``.
        s_start_m: arc length where it begins on the track [m] (its ramp-in starts up to
            ``builtin_design.TRANSITION_M`` / 2 before).
        length_m: its length along the centreline [m].
        radius_m: radius of its arcs [m] (inf for a straight).
        turn_deg: its signed turn [deg], left positive; a chicane: its first arc's (the second
            turns back by as much).
    """

    kind: str
    s_start_m: float
    length_m: float
    radius_m: float
    turn_deg: float


@dataclass(frozen=True, eq=False)
class GeneratedTrack:
    """A generated track with what the generator built.

    Attributes:
        seed: the seed.
        attempt: the layout attempt that was kept (0 = the first).
        track: the track.
        design: the design as ``builtin_design.sample_design`` takes it (``half_width_m`` the
            largest half width [m]; two ``"close"`` straights, the first one first).
        closing_m: the solved lengths of the two closing straights [m].
        features: the features in driving order (the closing straights included).
        tightest_radius_m: the drawn tightest radius [m] (a hairpin has exactly it).
        width_range_m: (min, max) full width [m] (equal for a constant width).
        target_length_m: the drawn lap length the layout aimed at [m].
    """

    seed: int
    attempt: int
    track: Track
    design: dict
    closing_m: tuple[float, float]
    features: tuple[Feature, ...]
    tightest_radius_m: float
    width_range_m: tuple[float, float]
    target_length_m: float


@dataclass(frozen=True)
class _SeedParams:
    """What is drawn once per seed."""

    radius_m: float
    width_lo_m: float
    width_hi_m: float
    width_waves: int
    width_phase_rad: float
    target_length_m: float


@dataclass(frozen=True)
class _Piece:
    """A feature's segments (``builtin_design`` format) before the layout is placed."""

    kind: str
    segments: tuple
    radius_m: float
    turn_deg: float


def _lerp(lo_hi: tuple[float, float], u: float) -> float:
    return lo_hi[0] + (lo_hi[1] - lo_hi[0]) * u


def _r2(x: float) -> float:
    """Rounded to 1 cm (a readable, platform-independent design)."""
    return round(float(x), 2)


def _deg(x: float) -> float:
    """Rounded to 0.5 deg."""
    return round(2.0 * x) / 2.0


def _seed_params(seed: int, spec: GeneratorSpec) -> _SeedParams:
    """Tightest radius, widths and target length of a seed (``default_rng(seed)``)."""
    u = np.random.default_rng(seed).random(7)
    radius = _r2(_lerp(spec.tightest_radius_m, u[0]))
    cap = min(spec.width_m[1], 2.0 * (radius - spec.inner_radius_m))
    w_a = _r2(_lerp((spec.width_m[0], cap), u[1]))
    varying = u[2] < spec.varying_width_share
    w_b = _r2(_lerp((spec.width_m[0], cap), u[3])) if varying else w_a
    return _SeedParams(
        radius_m=radius,
        width_lo_m=min(w_a, w_b),
        width_hi_m=max(w_a, w_b),
        width_waves=1 + int(3 * u[4]),
        width_phase_rad=2.0 * math.pi * float(u[5]),
        target_length_m=_r2(_lerp(spec.length_m, u[6])),
    )


def _count(u: float, lo: int, hi: int) -> int:
    """An integer in [lo, hi] from a uniform u in [0, 1)."""
    return lo + int((hi - lo + 1) * u)


def _draw_pieces(rng: np.random.Generator, p: _SeedParams, spec: GeneratorSpec) -> list[_Piece]:
    """The features of one layout (no straights yet), in random order."""
    r, L = p.radius_m, p.target_length_m
    u = rng.random
    pieces: list[_Piece] = []
    for i in range(_count(u(), 1, 1 + int(L // 50))):
        radius = r if i == 0 else _r2(r * _lerp((1.0, 1.25), u()))
        sign = 1.0 if i == 0 or u() < 0.6 else -1.0
        turn = sign * _deg(_lerp((160.0, 200.0), u()))
        pieces.append(_Piece("hairpin", (("arc", radius, turn),), radius, turn))
    for _ in range(_count(u(), 0 if u() < 0.15 else 1, 1 + int(L // 50))):
        radius = _r2(r * _lerp((1.0, 1.8), u()))
        turn = (1.0 if u() < 0.5 else -1.0) * _deg(_lerp((30.0, 65.0), u()))
        gap = _r2(_lerp((0.0, 0.8), u()))
        between = (("straight", gap),) if gap > 0 else ()
        segs = (("arc", radius, turn), *between, ("arc", radius, -turn))
        pieces.append(_Piece("chicane", segs, radius, turn))
    fast_hi = min(spec.fast_bend_radius_m[1], spec.fast_bend_radius_m[0] + L / 30.0)
    for _ in range(_count(u(), 0 if u() < 0.15 else 1, 1 + int(L // 60))):
        radius = _r2(_lerp((spec.fast_bend_radius_m[0], fast_hi), u()))
        turn = (1.0 if u() < 0.75 else -1.0) * _deg(_lerp((60.0, 150.0), u()))
        pieces.append(_Piece("fast_bend", (("arc", radius, turn),), radius, turn))
    # corners bring the total turn to +360 deg (the last one takes the rounding remainder)
    rest = 360.0 - sum(seg[2] for pc in pieces for seg in pc.segments if seg[0] == "arc")
    if abs(rest) < 0.25:
        rest = 0.0
    n = 0 if rest == 0.0 else max(1, math.ceil(abs(rest) / 120.0), _count(u(), 0, 1 + int(L // 40)))
    n = min(n, max(1, int(abs(rest) // 20.0)))  # no corner under ~20 deg unless it is alone
    if n == 0:
        return _shuffled(rng, pieces)
    weights = [_lerp((0.5, 1.0), u()) for _ in range(n)]
    turns = [_deg(rest * w / sum(weights)) for w in weights[:-1]]
    turns.append(rest - sum(turns))
    for turn in turns:
        radius = _r2(r * _lerp((1.0, 2.5), u()))
        pieces.append(_Piece("corner", (("arc", radius, turn),), radius, turn))
    return _shuffled(rng, pieces)


def _shuffled(rng: np.random.Generator, pieces: list[_Piece]) -> list[_Piece]:
    """`pieces` in a random order (by sorting uniform draws: the same on every machine)."""
    order = np.argsort(rng.random(len(pieces)), kind="stable")
    return [pieces[k] for k in order]


def _piece_length(pc: _Piece) -> float:
    return sum(abs(math.radians(s[2])) * s[1] if s[0] == "arc" else s[1] for s in pc.segments)


def _draw_straights(rng: np.random.Generator, n: int, budget_m: float) -> list[float]:
    """`n` straight lengths [m] of varied size adding up to about `budget_m`."""
    u = rng.random
    weights = []
    for _ in range(n):
        v = u()
        weights.append(_lerp((0.1, 0.6), u()) if v < 0.4 else
                       _lerp((0.6, 1.5), u()) if v < 0.75 else _lerp((1.5, 4.0), u()))
    total = sum(weights)
    return [_r2(min(max(budget_m * w / total, 0.3), 25.0)) for w in weights]


def _closing_pair(segments: list, straights: list[int]) -> tuple[int, int, float, float] | None:
    """The two straights that close the exact-arc loop with the least change of their drawn
    lengths, as (index a, index b, length a, length b) [m]; None when no pair gives both at
    least ``MIN_CLOSING_M`` (and at most 25 m)."""
    end, _ = loop_end(segments, (0.0, 0.0))
    heading = np.cumsum([math.radians(s[2]) if s[0] == "arc" else 0.0 for s in segments])
    best = None
    for i, a in enumerate(straights):
        ha = heading[a]
        for b in straights[i + 1:]:
            hb = heading[b]
            det = math.sin(hb - ha)
            if abs(det) < 0.5:  # nearly parallel: a badly conditioned closure
                continue
            # d_a (cos ha, sin ha) + d_b (cos hb, sin hb) = -end
            d_a = (-end[0] * math.sin(hb) + end[1] * math.cos(hb)) / det
            d_b = (end[0] * math.sin(ha) - end[1] * math.cos(ha)) / det
            la, lb = segments[a][1] + d_a, segments[b][1] + d_b
            if not (MIN_CLOSING_M <= la <= 25.0 and MIN_CLOSING_M <= lb <= 25.0):
                continue
            cost = abs(d_a) + abs(d_b)
            if best is None or cost < best[0]:
                best = (cost, a, b, la, lb)
    return None if best is None else best[1:]


def _layout(rng: np.random.Generator, p: _SeedParams, spec: GeneratorSpec
            ) -> tuple[list, list[tuple[str, float, float, int, int]]] | None:
    """One attempt's design segments (two ``"close"`` straights, the start one first) and the
    (kind, radius, turn, first segment, number of segments) of each feature; None when no
    pair of straights closes it."""
    pieces = _draw_pieces(rng, p, spec)
    feat_len = sum(_piece_length(pc) for pc in pieces)
    straights = _draw_straights(rng, len(pieces), max(p.target_length_m - feat_len, 0.0))
    segments: list = []
    spans: list[tuple[str, float, float, int, int]] = []  # kind, radius, turn, first, stop
    straight_idx: list[int] = []
    for pc, length in zip(pieces, straights, strict=True):
        spans.append((pc.kind, pc.radius_m, pc.turn_deg, len(segments),
                      len(segments) + len(pc.segments)))
        segments.extend(pc.segments)
        straight_idx.append(len(segments))
        spans.append(("straight", math.inf, 0.0, len(segments), len(segments) + 1))
        segments.append(("straight", length))
    pair = _closing_pair(segments, straight_idx)
    if pair is None:
        return None
    a, b, la, lb = pair
    start = a if la >= lb else b
    segments[a] = segments[b] = ("straight", "close")
    segments = segments[start:] + segments[:start]
    spans = [sp for sp in spans if sp[3] >= start] + [sp for sp in spans if sp[3] < start]
    meta = [(k, rad, turn, (first - start) % len(segments), stop - first)
            for k, rad, turn, first, stop in spans]
    return segments, meta


def _half_widths(s_m: np.ndarray, length_m: float, p: _SeedParams) -> np.ndarray:
    """(n,) half width [m] at arc lengths `s_m`: constant, or a smooth wave between the two
    drawn widths."""
    wave = 0.5 - 0.5 * np.cos(2.0 * np.pi * p.width_waves * s_m / length_m + p.width_phase_rad)
    return 0.5 * (p.width_lo_m + (p.width_hi_m - p.width_lo_m) * wave)


def stretch_gap_m(xy: np.ndarray, half_width_m: np.ndarray) -> float:
    """Smallest gap [m] between the track surfaces of two distant stretches of a closed loop.

    `xy` (n, 2) are the centreline points [m] (the loop closed implicitly), `half_width_m`
    (n,) the half width at each [m] (for an asymmetric track, the larger side). Two points
    are on distant stretches when the track between them, the shorter way round, is more
    than ``DISTANT_ARC_FACTOR`` times their distance (the two legs of a hairpin near its apex
    are one stretch; further on, or where a loop folds back, they are two). The gap of a
    pair is their distance minus both half widths (the surfaces' cross-sections fit in discs
    of those radii); inf when no pair is distant. Evaluated at the points.
    """
    xy = np.asarray(xy, dtype=float)
    hw = np.asarray(half_width_m, dtype=float)
    step = np.hypot(*(np.roll(xy, -1, axis=0) - xy).T)
    s = np.concatenate([[0.0], np.cumsum(step)[:-1]])
    length = float(step.sum())
    best = math.inf
    for lo in range(0, len(xy), 256):  # rows lo..lo+255 against the columns from lo on
        hi = lo + 256
        d = np.hypot(xy[lo:hi, None, 0] - xy[None, lo:, 0], xy[lo:hi, None, 1] - xy[None, lo:, 1])
        ds = np.abs(s[lo:hi, None] - s[None, lo:])
        ds = np.minimum(ds, length - ds)
        distant = ds > DISTANT_ARC_FACTOR * d
        if np.any(distant):
            gap = d - hw[lo:hi, None] - hw[None, lo:]
            best = min(best, float(gap[distant].min()))
    return best


def tightest_radius_m(track: Track) -> float:
    """Smallest centreline radius of `track` [m] (from its signed curvature)."""
    return 1.0 / max(float(np.abs(track.signed_curvature()).max()), 1e-12)


def _attempt(seed: int, attempt: int, p: _SeedParams, spec: GeneratorSpec
             ) -> GeneratedTrack | None:
    """One layout attempt of `seed`, checked; None when it fails a check."""
    rng = np.random.default_rng([seed, attempt])
    laid = _layout(rng, p, spec)
    if laid is None:
        return None
    segments, meta = laid
    design = {"half_width_m": 0.5 * p.width_hi_m, "segments": segments}
    # quick check on a coarse loop, then the real one
    for spacing, slack in ((COARSE_SPACING_M, COARSE_SLACK_M), (spec.spacing_m, 0.0)):
        closing = solve_closure_smooth(segments, spacing)
        if min(closing) < MIN_CLOSING_M:
            return None
        rows = sample_design(design, spacing)
        xy = rows[:, :2]
        step = np.hypot(*(np.roll(xy, -1, axis=0) - xy).T)
        length = float(step.sum())
        lo = max(spec.length_m[0], (1.0 - LENGTH_TOLERANCE) * p.target_length_m)
        hi = min(spec.length_m[1], (1.0 + LENGTH_TOLERANCE) * p.target_length_m)
        if not lo - slack <= length <= hi + slack:
            return None
        s = np.concatenate([[0.0], np.cumsum(step)[:-1]])
        hw = _half_widths(s, length, p)
        if stretch_gap_m(xy, hw) < spec.min_gap_m - slack:
            return None
    default = spec == DEFAULT_SPEC
    try:
        track = Track(
            name=f"gen-{seed}",
            xy=xy,
            w_right_m=hw,
            w_left_m=hw.copy(),
            source=f"gen:{seed}" if default else f"generated:{seed} (custom GeneratorSpec)",
        )
    except TrackError:
        return None
    if tightest_radius_m(track) < p.radius_m * (1.0 - 1e-6):
        raise AssertionError(f"gen:{seed}: a radius under the tightest one (design bug)")
    return GeneratedTrack(
        seed=seed,
        attempt=attempt,
        track=track,
        design=design,
        closing_m=closing,
        features=_features(segments, closing, meta),
        tightest_radius_m=p.radius_m,
        width_range_m=(p.width_lo_m, p.width_hi_m),
        target_length_m=p.target_length_m,
    )


def _features(segments: list, closing: tuple[float, float], meta: list) -> tuple[Feature, ...]:
    """The features with their place on the track."""
    lengths, k = [], 0
    for seg in segments:
        if seg[0] == "arc":
            lengths.append(abs(math.radians(seg[2])) * seg[1])
        elif seg[1] == "close":
            lengths.append(closing[k])
            k += 1
        else:
            lengths.append(seg[1])
    s_start = np.concatenate([[0.0], np.cumsum(lengths)])
    out = [
        Feature(kind, float(s_start[first]), float(sum(lengths[first:first + n])), rad, turn)
        for kind, rad, turn, first, n in meta
    ]
    return tuple(sorted(out, key=lambda f: f.s_start_m))


def generate(seed: int, spec: GeneratorSpec | None = None) -> GeneratedTrack:
    """The generated track of `seed` with its design and features (module docstring).

    Deterministic for (seed, spec). Raises TrackError naming ``gen:SEED`` when no layout of
    ``spec.max_attempts`` passes the checks.
    """
    spec = spec or DEFAULT_SPEC
    if isinstance(seed, bool) or not isinstance(seed, int | np.integer) or seed < 0:
        raise TrackError(f"gen:{seed}", "the seed must be an integer >= 0")
    seed = int(seed)
    params = _seed_params(seed, spec)
    for attempt in range(spec.max_attempts):
        got = _attempt(seed, attempt, params, spec)
        if got is not None:
            return got
    raise TrackError(
        f"gen:{seed}",
        f"no valid track in {spec.max_attempts} layouts (tightest radius {params.radius_m} m, "
        f"width {params.width_lo_m}-{params.width_hi_m} m, target {params.target_length_m} m)",
    )


def generate_track(seed: int, spec: GeneratorSpec | None = None) -> Track:
    """The generated ``Track`` of `seed` (name ``gen-SEED``, source ``gen:SEED``)."""
    return generate(seed, spec).track


def describe(item: GeneratedTrack | Track) -> dict:
    """What a generated track is: lap length [m], width range [m], tightest radius [m]
    (measured), the smallest gap between distant stretches [m] (None: no distant stretches)
    and the number of each kind of feature. A plain ``Track`` from ``gen:SEED`` is
    regenerated to know its features; another ``Track`` gets the measured values only."""
    if isinstance(item, Track):
        seed = item.source.removeprefix("gen:")
        if item.source.startswith("gen:") and seed.isdigit():
            item = generate(int(seed))
    track = item.track if isinstance(item, GeneratedTrack) else item
    width = track.w_left_m + track.w_right_m
    gap = stretch_gap_m(track.xy, np.maximum(track.w_left_m, track.w_right_m))
    out: dict = {
        "name": track.name,
        "source": track.source,
        "length_m": round(track.length_m, 3),
        "width_min_m": round(float(width.min()), 3),
        "width_max_m": round(float(width.max()), 3),
        "tightest_radius_m": round(tightest_radius_m(track), 3),
        "stretch_gap_m": None if math.isinf(gap) else round(gap, 3),
    }
    if isinstance(item, GeneratedTrack):
        kinds = [f.kind for f in item.features]
        straights = [f.length_m for f in item.features if f.kind == "straight"]
        out |= {
            "seed": item.seed,
            "attempt": item.attempt,
            "target_length_m": item.target_length_m,
            "hairpins": kinds.count("hairpin"),
            "chicanes": kinds.count("chicane"),
            "fast_bends": kinds.count("fast_bend"),
            "corners": kinds.count("corner"),
            "straights": kinds.count("straight"),
            "longest_straight_m": round(max(straights), 2),
        }
    return out


__all__ = [
    "DISTANT_ARC_FACTOR",
    "FEATURE_KINDS",
    "GENERATED_SEEDS",
    "TUNING_SEEDS",
    "Feature",
    "GeneratedTrack",
    "GeneratorSpec",
    "describe",
    "generate",
    "generate_track",
    "stretch_gap_m",
    "tightest_radius_m",
]
