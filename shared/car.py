"""The car's body, defined once: the footprint and the wheelbase of the 1:10 F1TENTH car.

Every setting that describes the car's size takes its default from here: the car's
footprint (``[vehicle] width_m``, ``length_m``; the simulated car's gives the lap timer and
the track limits), the footprint telemetry draws (``[telemetry] car_width_m``,
``car_length_m``), the wheelbase of the VESC driver's odometry yaw rate (``[vesc]
wheelbase_m``) and of the planner's kinematic bicycle (``[planner] wheelbase_m``). A setting
may still differ from it on purpose (model mismatch is configuration); the car's own axle
distances ``lf_m + lr_m`` (0.3302 m, the F1TENTH gym's) are a parameter of the dynamic
model, not of this body.

Plain constants, no imports: configuration and cores alike can read them.
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class CarGeometry:
    """The car's body [m].

    Attributes:
        length_m: length of the footprint rectangle, centred on the position [m].
        width_m: width of the footprint rectangle [m].
        wheelbase_m: distance between the axles, L of the kinematic bicycle [m].
    """

    length_m: float = 0.58
    width_m: float = 0.31
    wheelbase_m: float = 0.324


#: The racestack car (an F1TENTH 1:10 chassis).
CAR = CarGeometry()
