"""Low-variance (systematic) resampling and the effective sample size (no I/O)."""

from __future__ import annotations

import numpy as np


def effective_sample_size(weights: np.ndarray) -> float:
    """``n_eff = 1 / sum w_i^2`` of normalised (N,) weights [particles]."""
    return float(1.0 / np.dot(weights, weights))


def low_variance_indices(weights: np.ndarray, count: int, rng: np.random.Generator) -> np.ndarray:
    """Indices of `count` particles drawn by systematic resampling (Thrun et al., Table 4.4).

    One uniform ``u0`` in [0, 1/M); particle i is chosen for every ``(u0 + m) / M`` (m = 0..M-1)
    that falls into its slice of the cumulative weights. Normalised (N,) `weights`; returns
    (M,) int indices, sorted.
    """
    m = int(count)
    cum = np.cumsum(weights)
    cum[-1] = 1.0  # guard against rounding: every position finds a particle
    pos = (rng.random() + np.arange(m)) / m
    return np.minimum(np.searchsorted(cum, pos, side="right"), weights.size - 1)
