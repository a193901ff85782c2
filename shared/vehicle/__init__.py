"""The simulated car's tyre and body-force equations, written once for floats and CasADi.

The simulator integrates them (``services.simulator.dynamics``); the minimum-time lap
(``services.planner.mintime.ocp``) optimises over the same expressions. See
``shared.vehicle.single_track`` for the equations and where they come from.
"""

from shared.vehicle.ops import CASADI_OPS, FLOAT_OPS, Ops
from shared.vehicle.single_track import (
    GRAVITY_MPS2,
    AxleForces,
    DynamicDerivatives,
    make_dynamic_derivatives,
    normal_loads,
)
from shared.vehicle.tyres import (
    BRAKE_SIGN_RAMP_MPS,
    PACEJKA_PHI_MAX_RAD,
    axle_peak_friction,
    make_axle_force_law,
)

__all__ = [
    "BRAKE_SIGN_RAMP_MPS",
    "CASADI_OPS",
    "FLOAT_OPS",
    "GRAVITY_MPS2",
    "PACEJKA_PHI_MAX_RAD",
    "AxleForces",
    "DynamicDerivatives",
    "Ops",
    "axle_peak_friction",
    "make_axle_force_law",
    "make_dynamic_derivatives",
    "normal_loads",
]
