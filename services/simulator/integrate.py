"""Classic 4-stage Runge-Kutta on plain float tuples (the simulator's hot path).

For ``s' = f(s)`` over a step ``h`` [s]::

    k1 = f(s)
    k2 = f(s + h/2 k1)
    k3 = f(s + h/2 k2)
    k4 = f(s + h k3)
    s+ = s + h (k1 + 2 k2 + 2 k3 + k4) / 6

Written out for tuples of floats: on 7 elements, Python floats are several times faster
than numpy arrays.
"""

from __future__ import annotations

from collections.abc import Callable

Vector = tuple[float, ...]


def rk4_step(f: Callable[[Vector], Vector], s: Vector, h: float) -> tuple[Vector, Vector]:
    """One RK4 step of ``s' = f(s)``.

    Args:
        f: time derivative of the state (tuple of floats -> tuple of floats, same length).
        s: state at the start of the step.
        h: step [s].

    Returns:
        (state after the step, mean slope ``(k1 + 2 k2 + 2 k3 + k4) / 6``).
    """
    hh = 0.5 * h
    k1 = f(s)
    k2 = f(tuple([a + hh * b for a, b in zip(s, k1, strict=True)]))
    k3 = f(tuple([a + hh * b for a, b in zip(s, k2, strict=True)]))
    k4 = f(tuple([a + h * b for a, b in zip(s, k3, strict=True)]))
    slope = tuple(
        [(a + 2.0 * b + 2.0 * c + d) / 6.0 for a, b, c, d in zip(k1, k2, k3, k4, strict=True)]
    )
    return tuple([a + h * b for a, b in zip(s, slope, strict=True)]), slope
