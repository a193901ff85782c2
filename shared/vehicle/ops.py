"""The few maths functions the vehicle equations use, for plain floats and for CasADi.

The equations in ``shared.vehicle`` take an ``Ops`` so that one definition serves the
simulator's float hot path and the optimiser's symbolic expressions.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any


@dataclass(frozen=True, slots=True)
class Ops:
    """Elementary functions: each takes and returns a float or a CasADi expression."""

    cos: Any
    sin: Any
    tan: Any
    atan: Any
    atan2: Any
    sqrt: Any
    fmin: Any
    fmax: Any
    fabs: Any


def _fmin(a: float, b: float) -> float:
    return a if a < b else b


def _fmax(a: float, b: float) -> float:
    return a if a > b else b


#: Plain Python floats (the simulator).
FLOAT_OPS = Ops(
    cos=math.cos,
    sin=math.sin,
    tan=math.tan,
    atan=math.atan,
    atan2=math.atan2,
    sqrt=math.sqrt,
    fmin=_fmin,
    fmax=_fmax,
    fabs=abs,
)


def _casadi_ops() -> Ops:
    import casadi as ca

    return Ops(
        cos=ca.cos,
        sin=ca.sin,
        tan=ca.tan,
        atan=ca.atan,
        atan2=ca.atan2,
        sqrt=ca.sqrt,
        fmin=ca.fmin,
        fmax=ca.fmax,
        fabs=ca.fabs,
    )


#: CasADi SX/MX expressions (the minimum-time optimal control problem).
CASADI_OPS = _casadi_ops()
