"""Curvature of the centreline mapped to a reference-velocity weight (paper section III).

The offline part of CiMPCC:
1. ``kappa``: curvature by the paper's finite differences (eq. kappa, III-A),
2. ``smooth``: moving-average filter of odd window ``w`` points (MAF, III-B),
3. ``normalise``: min-max normalisation to the normalised smooth curvature NSC in [0, 1] (III-B),
4. ``beta_of``: the mapping ``g(K_n) = exp(-alpha * K_n^2)`` (III-C), the weight of the
   upper-velocity pull in ``J_Ci`` (and ``1 - beta`` of the lower one).

All functions are pure numpy over a CLOSED loop of points (indices wrap around).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from shared.config.planner import CurvatureSettings
    from shared.track import Track


def kappa(xy: np.ndarray) -> np.ndarray:
    """Unsigned curvature [1/m] of a closed polyline by the paper's finite differences.

    ``kappa_i = |dx_i * d2y_i - d2x_i * dy_i| / (dx_i^2 + dy_i^2)^(3/2)`` with the backward
    differences ``dx_i = x_i - x_{i-1}``, ``d2x_i = dx_i - dx_{i-1}`` (paper eq. 6-7). The
    stencil of the paper's ``kappa_i`` spans points i-2, i-1, i and so estimates the curvature
    at point i-1; the result is shifted by one index so that element i belongs to point i.
    Exact for uniformly sampled circles; for other uniformly sampled curves the error is first
    order in the spacing (the first difference sits half a step from the second one).

    Args:
        xy: (n, 2) points of a closed loop [m] (first point not repeated).

    Returns:
        (n,) curvature [1/m].
    """
    p = np.asarray(xy, dtype=float)
    d = p - np.roll(p, 1, axis=0)  # dx_i, dy_i
    d2 = d - np.roll(d, 1, axis=0)  # d2x_i, d2y_i
    num = np.abs(d[:, 0] * d2[:, 1] - d2[:, 0] * d[:, 1])
    den = np.power(d[:, 0] ** 2 + d[:, 1] ** 2, 1.5)
    k_paper = num / np.maximum(den, 1e-300)
    return np.roll(k_paper, -1)


def window_points(window_m: float, spacing_m: float) -> int:
    """The odd moving-average window [points] closest to `window_m` of arc at `spacing_m`."""
    w = max(1, round(window_m / spacing_m))
    return w if w % 2 == 1 else w + 1


def smooth(values: np.ndarray, window: int) -> np.ndarray:
    """Centred moving average of odd width `window` over a periodic sequence (paper MAF).

    ``K_i = (1/w) * sum_{m=i-(w-1)/2}^{i+(w-1)/2} kappa_m`` with indices wrapping around.
    """
    if window < 1 or window % 2 == 0:
        raise ValueError(f"window must be a positive odd number of points, got {window}")
    v = np.asarray(values, dtype=float)
    n = v.size
    if window >= n:
        return np.full(n, v.mean())
    half = (window - 1) // 2
    padded = np.concatenate([v[-half:], v, v[:half]]) if half else v
    c = np.concatenate([[0.0], np.cumsum(padded)])
    return (c[window:] - c[:-window]) / window


def normalise(values: np.ndarray) -> np.ndarray:
    """Min-max normalisation to [0, 1]: ``(K - K_min) / (K_max - K_min)`` (paper eq. 9).

    A constant input (a circle) has no spread: it maps to all zeros (a straight-like NSC).
    """
    v = np.asarray(values, dtype=float)
    lo, hi = float(v.min()), float(v.max())
    if hi - lo <= 1e-12 * max(1.0, abs(hi)):
        return np.zeros_like(v)
    return (v - lo) / (hi - lo)


def beta_of(nsc: np.ndarray | float, alpha: float) -> np.ndarray | float:
    """The paper's mapping ``g(K_n) = exp(-alpha * K_n^2)``, alpha > 0 (eq. 10).

    g(0) = 1 (upper truncation coefficient, straights), g(1) = exp(-alpha) (lower one).
    """
    return np.exp(-alpha * np.square(nsc))


@dataclass(frozen=True, eq=False)
class CurvatureProfile:
    """The offline CiMPCC curvature profile of a track, per centreline point.

    Attributes:
        s_m: (n,) arc length of each point [m].
        kappa: (n,) raw curvature [1/m].
        smoothed: (n,) moving-average curvature K [1/m].
        nsc: (n,) normalised smooth curvature K_n in [0, 1].
        beta: (n,) g(K_n) in [exp(-alpha), 1].
        window: moving-average window [points] (of the resampled centreline, if resampled).
        alpha: mapping sensitivity.
        length_m: lap length [m].
    """

    s_m: np.ndarray
    kappa: np.ndarray
    smoothed: np.ndarray
    nsc: np.ndarray
    beta: np.ndarray
    window: int
    alpha: float
    length_m: float

    def nsc_at(self, s: np.ndarray | float) -> np.ndarray:
        """NSC at arc length(s) `s` [m] (periodic, linear interpolation)."""
        s_cl, nsc_cl = self._closed
        return np.interp(np.mod(s, self.length_m), s_cl, nsc_cl)

    @property
    def _closed(self) -> tuple[np.ndarray, np.ndarray]:
        cached = self.__dict__.get("_closed_cache")
        if cached is None:
            cached = (np.append(self.s_m, self.length_m), np.append(self.nsc, self.nsc[0]))
            object.__setattr__(self, "_closed_cache", cached)
        return cached

    def beta_at(self, s: np.ndarray | float) -> np.ndarray:
        """beta = g(NSC(s)) at arc length(s) `s` [m]."""
        return beta_of(self.nsc_at(s), self.alpha)


#: Centrelines sparser than this [m] are resampled before the finite differences ...
MAX_SPACING_M = 0.08
#: ... to this spacing [m] (the authors' data: about 4 cm), along a periodic cubic spline.
RESAMPLE_SPACING_M = 0.04


def periodic_spline(xy: np.ndarray, t: np.ndarray, period: float, t_out: np.ndarray) -> np.ndarray:
    """The closed interpolating cubic spline through `xy` at parameters `t`, at `t_out`.

    Args:
        xy: (n, 2) points; t: (n,) increasing parameters in [0, period) (arc length [m]);
        period: the parameter length of the loop; t_out: (m,) parameters to evaluate.

    Returns:
        (m, 2) points on the spline (C2 everywhere, the loop included).
    """
    p = np.asarray(xy, dtype=float)
    n = len(p)
    h = np.diff(np.append(t, t[0] + period))  # h_i = t_(i+1) - t_i
    h_prev = np.roll(h, 1)
    slope = (np.roll(p, -1, axis=0) - p) / h[:, None]
    rhs = 6.0 * (slope - np.roll(slope, 1, axis=0))
    # cyclic tridiagonal system h_(i-1) M_(i-1) + 2 (h_(i-1) + h_i) M_i + h_i M_(i+1) = rhs_i
    a = np.zeros((n, n))
    idx = np.arange(n)
    a[idx, idx] = 2.0 * (h_prev + h)
    a[idx, (idx - 1) % n] += h_prev
    a[idx, (idx + 1) % n] += h
    m = np.linalg.solve(a, rhs)
    tt = np.mod(t_out, period)
    i = np.clip(np.searchsorted(t, tt, side="right") - 1, 0, n - 1)
    j = (i + 1) % n
    hi = h[i][:, None]
    u = (tt - t[i])[:, None]
    v = hi - u
    return (m[i] * v**3 + m[j] * u**3) / (6 * hi) + (p[i] / hi - m[i] * hi / 6) * v + (
        p[j] / hi - m[j] * hi / 6
    ) * u


def curvature_profile(
    xy: np.ndarray, s_m: np.ndarray, length_m: float, window_m: float, alpha: float
) -> CurvatureProfile:
    """Build the CiMPCC curvature profile of a closed centreline (paper III-A to III-C).

    The paper's differences assume a dense centreline (the authors': about 4 cm). A sparser
    one (spacing over ``MAX_SPACING_M``, e.g. the F1TENTH maps' ~0.37 m) is first resampled
    every ``RESAMPLE_SPACING_M`` along a periodic cubic spline through its points; the
    profile is computed there and read back at the given points (so the arrays still match
    `xy`). Without this, a 1.2 m window is 3 points of a polyline whose curvature sits in
    its corners.

    Args:
        xy: (n, 2) centreline points [m].
        s_m: (n,) their arc lengths [m].
        length_m: lap length [m].
        window_m: moving-average window as arc length [m] (authors' code: 30 points ~ 1.2 m).
        alpha: sensitivity of the mapping g (authors' code: 5).
    """
    if alpha <= 0:
        raise ValueError(f"alpha must be > 0, got {alpha}")
    s_m = np.asarray(s_m, dtype=float)
    spacing = length_m / len(xy)
    if spacing > MAX_SPACING_M:
        n_dense = int(np.ceil(length_m / RESAMPLE_SPACING_M))
        s_dense = np.arange(n_dense) * length_m / n_dense
        dense = periodic_spline(xy, s_m, length_m, s_dense)
        k_d = kappa(dense)
        w_d = window_points(window_m, length_m / n_dense)
        ks_d = smooth(k_d, w_d)
        nsc_d = normalise(ks_d)
        s_cl = np.append(s_dense, length_m)

        def back(v: np.ndarray) -> np.ndarray:
            return np.interp(s_m, s_cl, np.append(v, v[0]))

        k, ks, nsc, w = back(k_d), back(ks_d), back(nsc_d), w_d
    else:
        k = kappa(xy)
        w = window_points(window_m, spacing)
        ks = smooth(k, w)
        nsc = normalise(ks)
    return CurvatureProfile(
        s_m=s_m,
        kappa=k,
        smoothed=ks,
        nsc=nsc,
        beta=np.asarray(beta_of(nsc, alpha)),
        window=w,
        alpha=alpha,
        length_m=float(length_m),
    )


def track_profile(track: Track, settings: CurvatureSettings) -> CurvatureProfile:
    """``curvature_profile`` of `track`'s centreline with the ``[curvature]`` settings."""
    return curvature_profile(
        track.xy, track.s_m, track.length_m, settings.window_m, settings.alpha
    )
