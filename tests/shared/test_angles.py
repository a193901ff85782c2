"""shared.angles: the one convention [-pi, pi), exact, for floats and arrays."""

from __future__ import annotations

import math

import numpy as np
import pytest

from shared.angles import wrap_angle, wrap_angle_shifted

PI = math.pi


def _samples() -> np.ndarray:
    rng = np.random.default_rng(7)
    edges = [PI, -PI, 3 * PI, -3 * PI, math.tau, -math.tau, 0.0, -0.0, 1e300, -1e300,
             5e-324, np.nextafter(-PI, -4.0), np.nextafter(PI, 4.0), np.nextafter(PI, 0.0)]
    return np.concatenate([rng.uniform(-4.0, 4.0, 20000), rng.uniform(-1e3, 1e3, 20000),
                           rng.normal(0.0, 1e9, 5000), rng.normal(0.0, 1e-6, 5000), edges])


def test_exact_pi_and_minus_pi_give_minus_pi() -> None:
    assert wrap_angle(PI) == -PI
    assert wrap_angle(-PI) == -PI
    assert wrap_angle(3 * PI) == -PI and wrap_angle(-3 * PI) == -PI
    assert wrap_angle(math.tau) == 0.0 and wrap_angle(-math.tau) == 0.0
    assert np.array_equal(wrap_angle(np.array([PI, -PI])), [-PI, -PI])
    # just inside the range is left alone, just outside comes round
    below = np.nextafter(PI, 0.0)
    assert wrap_angle(below) == below
    assert wrap_angle(np.nextafter(-PI, -4.0)) == pytest.approx(PI, abs=1e-15)
    assert wrap_angle(np.nextafter(-PI, -4.0)) < PI


def test_range_and_same_angle() -> None:
    x = _samples()
    w = wrap_angle(x)
    assert np.all(w >= -PI) and np.all(w < PI)
    turns = (x - w) / math.tau  # a whole number of turns (up to the rounding of x / tau)
    small = np.abs(x) < 1e6
    assert np.allclose(turns[small], np.round(turns[small]), atol=1e-9)


def test_in_range_angles_come_back_unchanged() -> None:
    x = np.random.default_rng(3).uniform(-PI, PI, 10000)
    assert np.array_equal(wrap_angle(x), x)
    assert all(wrap_angle(float(v)) == v for v in x[:500])
    assert wrap_angle(0.1) == 0.1  # (0.1 + pi) - pi would not be


def test_float_and_array_give_the_same_bits_and_match_math_remainder() -> None:
    x = _samples()
    arr = wrap_angle(x)
    for v, a in zip(x.tolist(), arr.tolist(), strict=True):
        f = wrap_angle(v)
        assert isinstance(f, float)
        assert f == a and math.copysign(1.0, f) == math.copysign(1.0, a), v
        r = math.remainder(v, math.tau)
        assert f == r or (r == PI and f == -PI), v


def test_large_angles() -> None:
    assert wrap_angle(1e6 * math.tau + 0.5) == pytest.approx(0.5, abs=1e-9)
    assert wrap_angle(-1e6 * math.tau - 0.5) == pytest.approx(-0.5, abs=1e-9)
    for v in (1e300, -1e300, 1e16 + 0.25):
        w = wrap_angle(v)
        assert -PI <= w < PI
        assert wrap_angle(np.array([v]))[0] == w


def test_shapes_types_and_non_finite() -> None:
    grid = np.linspace(-10.0, 10.0, 12).reshape(3, 4)
    assert wrap_angle(grid).shape == (3, 4)
    assert isinstance(wrap_angle(7), float) and wrap_angle(7) == pytest.approx(7 - math.tau)
    assert wrap_angle([4.0, -4.0]) == pytest.approx([4.0 - math.tau, math.tau - 4.0])
    assert math.isnan(wrap_angle(math.nan))
    assert np.isnan(wrap_angle(np.array([np.inf, np.nan]))).all()
    with pytest.raises(ValueError):
        wrap_angle(math.inf)


def test_shifted_is_the_same_range_with_the_old_rounding() -> None:
    x = _samples()[np.abs(_samples()) < 1e6]
    old = (x + np.pi) % (2.0 * np.pi) - np.pi  # the formula it keeps, bit for bit
    assert np.array_equal(wrap_angle_shifted(x), old)
    assert [wrap_angle_shifted(v) for v in x[:2000].tolist()] == old[:2000].tolist()
    assert wrap_angle_shifted(PI) == -PI and wrap_angle_shifted(-PI) == -PI
    # the same angle up to the rounding of x + pi (next to +-pi it may land on the other end)
    diff = wrap_angle(wrap_angle_shifted(x) - wrap_angle(x))
    assert np.all(np.abs(diff) <= 2.0 * np.spacing(np.abs(x) + math.tau))  # a rounding of x + pi
    assert wrap_angle_shifted(0.1) != 0.1  # why it is not the convention's function
