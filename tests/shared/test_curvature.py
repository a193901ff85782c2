"""Curvature mapping (paper III) against analytic shapes."""

from __future__ import annotations

import numpy as np
import pytest

from shared.curvature import (
    beta_of,
    curvature_profile,
    kappa,
    normalise,
    smooth,
    window_points,
)


def circle(radius: float, n: int = 400) -> np.ndarray:
    t = np.linspace(0, 2 * np.pi, n, endpoint=False)
    return radius * np.column_stack([np.cos(t), np.sin(t)])


@pytest.mark.parametrize("radius", [0.8, 2.0, 25.0])
def test_circle_has_constant_curvature_one_over_r(radius: float) -> None:
    k = kappa(circle(radius))
    np.testing.assert_allclose(k, 1.0 / radius, rtol=1e-3)


def test_ellipse_curvature_matches_closed_form() -> None:
    a, b = 3.0, 1.5
    errors = []
    for n in (2000, 8000):
        t = np.linspace(0, 2 * np.pi, n, endpoint=False)
        xy = np.column_stack([a * np.cos(t), b * np.sin(t)])
        exact = a * b / (a**2 * np.sin(t) ** 2 + b**2 * np.cos(t) ** 2) ** 1.5
        errors.append(np.max(np.abs(kappa(xy) / exact - 1.0)))
    assert errors[0] < 4e-3  # 1.5 mm spacing-scale points: within 0.4 %
    assert errors[1] < 1e-3
    # the paper's backward differences converge at first order: 4x the points, ~1/4 the error
    assert errors[1] == pytest.approx(errors[0] / 4, rel=0.1)


def test_moving_average_is_centred_and_periodic() -> None:
    v = np.zeros(20)
    v[0] = 5.0
    out = smooth(v, 5)
    expected = np.zeros(20)
    expected[[18, 19, 0, 1, 2]] = 1.0
    np.testing.assert_allclose(out, expected)
    assert out.sum() == pytest.approx(v.sum())
    with pytest.raises(ValueError):
        smooth(v, 4)


def test_window_in_metres_becomes_odd_points() -> None:
    assert window_points(1.2, 0.04) == 31
    assert window_points(1.2, 0.041) == 29
    assert window_points(0.01, 0.04) == 1


def test_nsc_is_in_unit_interval_with_min_zero_max_one() -> None:
    t = np.linspace(0, 2 * np.pi, 1000, endpoint=False)
    xy = np.column_stack([4 * np.cos(t), 1.2 * np.sin(t) + 0.3 * np.sin(3 * t)])
    s = np.concatenate([[0], np.cumsum(np.hypot(*np.diff(xy, axis=0).T))])
    length = s[-1] + np.hypot(*(xy[0] - xy[-1]))
    prof = curvature_profile(xy, s, length, window_m=1.2, alpha=5.0)
    assert prof.nsc.min() == 0.0 and prof.nsc.max() == 1.0
    assert np.all((prof.nsc >= 0) & (prof.nsc <= 1))
    assert prof.beta.max() == pytest.approx(1.0)
    assert prof.beta.min() == pytest.approx(np.exp(-5.0))


def test_constant_curvature_normalises_to_zero() -> None:
    np.testing.assert_array_equal(normalise(np.full(10, 0.5)), np.zeros(10))


def test_mapping_truncation_coefficients() -> None:
    assert beta_of(0.0, 5.0) == 1.0
    assert beta_of(1.0, 5.0) == pytest.approx(np.exp(-5.0))
    ks = np.linspace(0, 1, 11)
    assert np.all(np.diff(beta_of(ks, 2.0)) < 0)


def test_a_sparse_centreline_is_resampled_along_a_spline() -> None:
    """A 0.48 m-spaced ellipse (like the F1TENTH maps' ~0.37 m): the profile comes from a
    4 cm resampling of the periodic cubic spline through the points, read back at the
    points: the raw curvature is within 1 % of the closed form (the polyline's own finite
    differences are off by several %), and the arrays still match the points."""
    a, b = 6.0, 3.0
    th = np.linspace(0, 2 * np.pi, 60, endpoint=False)
    xy = np.column_stack([a * np.cos(th), b * np.sin(th)])
    seg = np.hypot(*(np.roll(xy, -1, axis=0) - xy).T)
    s = np.concatenate([[0.0], np.cumsum(seg)[:-1]])
    prof = curvature_profile(xy, s, float(seg.sum()), window_m=0.2, alpha=5.0)
    true = a * b / (a**2 * np.sin(th) ** 2 + b**2 * np.cos(th) ** 2) ** 1.5
    assert prof.kappa.shape == prof.nsc.shape == prof.beta.shape == (60,)
    assert np.max(np.abs(prof.kappa - true) / true) < 0.01
    assert np.max(np.abs(kappa(xy) - true) / true) > 0.03  # what the sparse points give
    assert prof.window == window_points(0.2, float(seg.sum()) / np.ceil(seg.sum() / 0.04))
    assert 0.0 <= prof.nsc.min() < 0.05 and 0.95 < prof.nsc.max() <= 1.0
