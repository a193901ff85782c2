"""Angle wrapping: the one convention of the stack, ``[-pi, pi)``.

``wrap_angle(a)`` is the angle in ``[-pi, pi)`` that differs from ``a`` by a whole number of
turns: the exact IEEE remainder of ``a`` modulo ``math.tau`` (no rounding at all), except
that the tie ``+pi`` is returned as ``-pi``. It takes a float or a numpy array (any shape)
and gives the same bits for both; it is idempotent (an angle already in range comes back
unchanged). ``math.remainder(a, math.tau)`` gives the same result everywhere but at the tie,
where it returns ``+pi`` for ``pi``, ``3 pi``, ... (its range is ``[-pi, pi]``).

``wrap_angle_shifted(a)`` is the same range computed as ``(a + pi) mod 2 pi - pi``: the
addition and the subtraction round, so it differs from ``wrap_angle`` by an ulp or so for
most inputs (``0.1`` comes back as ``0.10000000000000009``) and gives ``+pi`` for an angle
within half an ulp below ``-pi``. It is kept, beside the exact one, for the two callers whose
results must not move by that rounding: the simulator's pose sensor (its measured yaw) and
the particle filter's poses. New code uses ``wrap_angle``.

There is no CasADi version: the symbolic problems keep their angles continuous (unwrapped).
"""

from __future__ import annotations

import math
from typing import overload

import numpy as np

__all__ = ["wrap_angle", "wrap_angle_shifted"]

_PI = math.pi
_TAU = math.tau  # exactly 2 * math.pi


@overload
def wrap_angle(a: float) -> float: ...


@overload
def wrap_angle(a: np.ndarray) -> np.ndarray: ...


def wrap_angle(a: float | np.ndarray) -> float | np.ndarray:
    """Angle(s) `a` [rad] wrapped into ``[-pi, pi)``, exactly (module docstring).

    A Python float (or int) gives a float, anything else a numpy array of float64. A float
    infinity raises ``ValueError`` (as ``math.remainder`` does); in an array it gives NaN.
    """
    if isinstance(a, float | int):
        r = math.remainder(a, _TAU)  # exact, in [-pi, pi]
        return -_PI if r == _PI else r
    x = np.asarray(a, dtype=float)
    with np.errstate(invalid="ignore"):
        r = np.fmod(x, _TAU)  # exact, in (-2 pi, 2 pi) with the sign of x
    # r -+ 2 pi is exact here (Sterbenz: |r| is within a factor 2 of 2 pi)
    r = np.where(r >= _PI, r - _TAU, r)
    return np.where(r < -_PI, r + _TAU, r)


@overload
def wrap_angle_shifted(a: float) -> float: ...


@overload
def wrap_angle_shifted(a: np.ndarray) -> np.ndarray: ...


def wrap_angle_shifted(a: float | np.ndarray) -> float | np.ndarray:
    """Angle(s) `a` [rad] wrapped into ``[-pi, pi)`` as ``(a + pi) mod 2 pi - pi`` (rounds:
    see the module docstring). A Python float gives a float, anything else a numpy array."""
    if isinstance(a, float | int):
        return (a + _PI) % (2.0 * _PI) - _PI
    return (np.asarray(a) + np.pi) % (2.0 * np.pi) - np.pi
