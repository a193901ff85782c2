"""The car: geometry, mass, tyres and limits of the dynamic single-track model (``[vehicle]``).

One car for the stack: the planners (the minimum-time lines of ``cimpcc-line`` and of the
raceline, their tyre-slip models, the tracker, the recovery ramp), the minimum-time lap and
the simulator (``services.simulator.dynamics``) assume ``[vehicle]``. The simulator races
another car only when ``[simulator.vehicle]`` overrides it, for model-mismatch experiments
(``shared.config.root``). The paper's MPC methods keep their own kinematic bicycle
(``[planner] wheelbase_m``).

Two named presets (``preset = "..."``; any field given next to it overrides the preset):

``f1tenth_gym`` (default)
    The F1TENTH gym simulator's published values (CommonRoad single-track model, linear tyres,
    load transfer); see ``../shared/docs/vehicle-and-vesc.md``. Racestack adds a friction
    limit on the tyre forces (``tyre_model = "linear_saturated"``); ``"linear"`` is the gym's
    exact model, in which lateral acceleration is unbounded.

``real_car_identified``
    A real F1TENTH car identified by a top team: mass, yaw inertia, lf, lr, CoG height, the
    steering time constant, steering limits and the Pacejka coefficients come from the
    identification. What does NOT come from it (kept at the gym values, not identified):
    ``mu`` (set to 1.0 so that the Pacejka ``D`` is the peak friction coefficient; the
    identified D already holds the friction level), ``v_switch_mps``, ``accel_max_mps2``,
    ``v_min_mps`` / ``v_max_mps``, width and length and the speed-controller gains. The linear
    cornering stiffnesses of this preset are DERIVED as the Pacejka slope at zero slip,
    ``B * C * D`` per unit load (front 6.739, rear 18.54 1/rad), so that switching its tyre
    model to ``"linear_saturated"`` keeps the small-slip behaviour.
"""

from __future__ import annotations

from typing import Annotated, Any, Literal

from pydantic import Field, model_validator

from shared.car import CAR
from shared.config.base import Section

#: Gravitational acceleration [m/s^2] used by the load-transfer check (same as the model).
GRAVITY_MPS2 = 9.81

Positive = Annotated[float, Field(gt=0.0, allow_inf_nan=False)]
#: Pacejka magic-formula coefficients (B stiffness [-], C shape [-], D peak [-], E curvature [-]).
PacejkaCoefficients = tuple[
    Annotated[float, Field(gt=0.0, le=100.0, allow_inf_nan=False)],
    Annotated[float, Field(gt=0.0, le=3.0, allow_inf_nan=False)],
    Annotated[float, Field(gt=0.0, le=3.0, allow_inf_nan=False)],
    Annotated[float, Field(ge=-10.0, le=1.0, allow_inf_nan=False)],
]

VehiclePreset = Literal["f1tenth_gym", "real_car_identified"]
TyreModel = Literal["linear", "linear_saturated", "pacejka"]

#: Values that differ from the field defaults (the defaults ARE the ``f1tenth_gym`` preset).
VEHICLE_PRESETS: dict[str, dict[str, Any]] = {
    "f1tenth_gym": {},
    "real_car_identified": {
        "mu": 1.0,
        "mass_kg": 3.54,
        "yaw_inertia_kgm2": 0.05797,
        "lf_m": 0.162,
        "lr_m": 0.145,
        "cog_height_m": 0.014,
        "steering_time_constant_s": 0.158,
        "steering_min_rad": -0.4189,
        "steering_max_rad": 0.4189,
        "steering_rate_min_radps": -3.2,
        "steering_rate_max_radps": 3.2,
        "tyre_model": "pacejka",
        "pacejka_front": (4.80, 2.16, 0.650, 0.373),
        "pacejka_rear": (20.0, 1.5, 0.618, 0.0),
        # derived: Pacejka slope at zero slip per unit load = B * C * D
        "cornering_stiffness_front_per_rad": 4.80 * 2.16 * 0.650,
        "cornering_stiffness_rear_per_rad": 20.0 * 1.5 * 0.618,
    },
}


class DynamicVehicleParams(Section):
    """Parameters of the dynamic single-track model of the car.

    Tyre lateral force per axle i (front f, rear r), with normal load ``F_zi`` [N] and slip
    angle ``alpha_i`` [rad]:

    - ``linear``: ``F_yi = mu * C_Si * F_zi * alpha_i`` (CommonRoad / F1TENTH gym, unbounded);
    - ``linear_saturated``: the same, clipped to the friction circle
      ``|F_yi| <= sqrt((mu F_zi)^2 - F_xi^2)``;
    - ``pacejka``: ``F_yi = mu * D_i * F_zi * sin(C_i atan(B_i a - E_i (B_i a - atan(B_i a))))``
      scaled by the same friction circle with peak ``mu * D_i * F_zi``.
    """

    preset: VehiclePreset = Field(
        "f1tenth_gym", description="named parameter set that fills every field not given"
    )
    mu: float = Field(1.0489, gt=0.0, le=3.0, description="tyre-road friction coefficient [-]")
    cornering_stiffness_front_per_rad: Positive = Field(
        4.718, description="C_Sf: front cornering stiffness per unit load and friction [1/rad]"
    )
    cornering_stiffness_rear_per_rad: Positive = Field(
        5.4562, description="C_Sr: rear cornering stiffness per unit load and friction [1/rad]"
    )
    lf_m: float = Field(0.15875, gt=0.01, le=2.0, description="CoG to front axle [m]")
    lr_m: float = Field(0.17145, gt=0.01, le=2.0, description="CoG to rear axle [m]")
    cog_height_m: float = Field(0.074, ge=0.0, le=1.0, description="CoG height h [m]")
    mass_kg: float = Field(3.74, gt=0.1, le=1000.0, description="mass m [kg]")
    yaw_inertia_kgm2: float = Field(
        0.04712, gt=1e-4, le=1000.0, description="yaw moment of inertia I_z [kg m^2]"
    )
    steering_min_rad: float = Field(-0.4189, ge=-1.2, lt=0.0, description="road-wheel angle min")
    steering_max_rad: float = Field(0.4189, gt=0.0, le=1.2, description="road-wheel angle max")
    steering_rate_min_radps: float = Field(
        -3.2, ge=-50.0, lt=0.0, description="steering rate min [rad/s]"
    )
    steering_rate_max_radps: float = Field(
        3.2, gt=0.0, le=50.0, description="steering rate max [rad/s]"
    )
    v_switch_mps: Positive = Field(
        7.319, description="above this speed the drive limit is a_max * v_switch / v [m/s]"
    )
    accel_max_mps2: float = Field(
        9.51, gt=0.0, le=50.0, description="a_max: acceleration and braking limit [m/s^2]"
    )
    v_min_mps: float = Field(-5.0, ge=-50.0, lt=0.0, description="slowest (reverse) speed [m/s]")
    v_max_mps: float = Field(20.0, gt=0.0, le=100.0, description="fastest speed [m/s]")
    width_m: float = Field(CAR.width_m, gt=0.0, le=5.0, description="car width (footprint) [m]")
    length_m: float = Field(
        CAR.length_m, gt=0.0, le=10.0, description="car length (footprint) [m]"
    )
    tyre_model: TyreModel = Field(
        "linear_saturated", description="lateral tyre force law (see the class docstring)"
    )
    pacejka_front: PacejkaCoefficients = Field(
        (4.80, 2.16, 0.650, 0.373), description="front (B, C, D, E); used by tyre_model pacejka"
    )
    pacejka_rear: PacejkaCoefficients = Field(
        (20.0, 1.5, 0.618, 0.0), description="rear (B, C, D, E); used by tyre_model pacejka"
    )
    steering_time_constant_s: float = Field(
        0.01,
        gt=0.0,
        le=2.0,
        description="servo P-controller: steering rate = (delta_target - delta) / this [s], "
        "clipped to the rate limits. The gym drives the servo at the rate limit; 0.01 s "
        "gives that for any error above rate_max * 0.01 s = 0.032 rad without chattering",
    )
    speed_gain_accel_per_s: float = Field(
        4.755,
        gt=0.0,
        le=1000.0,
        description="speed P-gain while |v| increases [1/s] (gym: 10 a_max / v_max)",
    )
    speed_gain_brake_per_s: float = Field(
        19.02,
        gt=0.0,
        le=1000.0,
        description="speed P-gain while |v| decreases [1/s] (gym: 10 a_max / -v_min)",
    )

    @model_validator(mode="before")
    @classmethod
    def _fill_from_preset(cls, data: Any) -> Any:
        if isinstance(data, dict):
            name = data.get("preset", "f1tenth_gym")
            if isinstance(name, str) and name in VEHICLE_PRESETS:
                return {**VEHICLE_PRESETS[name], **data}
        return data

    @model_validator(mode="after")
    def _consistent(self) -> DynamicVehicleParams:
        if not self.v_min_mps < 0.0 < self.v_max_mps:
            raise ValueError("v_min_mps must be < 0 < v_max_mps")
        g = GRAVITY_MPS2
        if g * self.lr_m - self.accel_max_mps2 * self.cog_height_m <= 0.0:
            raise ValueError("front axle lifts at accel_max_mps2: lower cog_height_m or a_max")
        if g * self.lf_m - self.accel_max_mps2 * self.cog_height_m <= 0.0:
            raise ValueError("rear axle lifts when braking at accel_max_mps2")
        return self

    @property
    def wheelbase_m(self) -> float:
        """lf + lr [m]."""
        return self.lf_m + self.lr_m


#: The F1TENTH gym's parameter set (the default).
F1TENTH_GYM = DynamicVehicleParams()
#: The identified real car (see the module docstring for what does not map).
REAL_CAR_IDENTIFIED = DynamicVehicleParams(preset="real_car_identified")


def vehicle_preset(name: VehiclePreset, **overrides: Any) -> DynamicVehicleParams:
    """The named preset with optional field overrides (validated)."""
    return DynamicVehicleParams.model_validate({"preset": name, **overrides})
