"""The family of cars the robustness benchmark races and ``racestack tune`` tunes over.

Each car is a set of configuration tables (``[vehicle]`` and, for a model mismatch,
``[simulator.vehicle]``) laid over a base configuration, and whether the planners are told
the car the simulator races. One definition, read by ``benchmarks/robustness.py`` (its
``--cars``) and ``services/tools/tune`` (its ``--cars``). Plain data: no I/O.

Besides the named cars (``CARS``), ``varied:SEED`` is a seeded variant of the identified car
(``varied_car``): its tyres, servo and speed loop scaled by factors drawn from the seed
within ``VARIED_RANGES``, the planners told it. The same seed gives the same car on every
machine, so a tuning family (seeds 1001-...) and a held-out one (1-...) stay apart, as
the generator's tracks do.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass
from typing import Any

import numpy as np


@dataclass(frozen=True)
class CarSpec:
    """One car of the family: the configuration tables that make it and whether the
    planners are told the car the simulator races.

    Attributes:
        name: the car's name (``--cars``).
        tables: ``[vehicle]`` and, for a mismatch, ``[simulator.vehicle]`` (a config dict).
        knows_car: the planners' ``[vehicle]`` is the simulated car.
        summary: one line for ``--help`` and the tables' legends.
    """

    name: str
    tables: dict[str, Any]
    knows_car: bool
    summary: str


_IDENTIFIED = {"preset": "real_car_identified"}
_DEFAULT = {"preset": "f1tenth_gym"}
#: Every car of the family by name; ``DEFAULT_CARS`` are the robustness matrix's.
CARS: dict[str, CarSpec] = {
    c.name: c
    for c in (
        CarSpec("default", {}, True, "the F1TENTH gym's car, linear_saturated tyres"),
        CarSpec("linear", {"vehicle": {"tyre_model": "linear"}}, True,
                "the gym's linear (unbounded) tyres, the planners told"),
        CarSpec("identified", {"vehicle": _IDENTIFIED}, True,
                "the identified car (Pacejka), the planners told its car"),
        CarSpec("identified-on-default",
                {"vehicle": _DEFAULT, "simulator": {"vehicle": _IDENTIFIED}}, False,
                "the identified car simulated, the planners on the default car"),
        CarSpec("linear-on-default",
                {"vehicle": _DEFAULT, "simulator": {"vehicle": {"tyre_model": "linear"}}},
                False, "linear tyres simulated, the planners on the default car"),
    )
}
#: The robustness matrix's cars.
DEFAULT_CARS = ("default", "linear", "identified", "identified-on-default")


#: The prefix of a seeded variant of the identified car (``varied_car``).
VARIED = "varied:"
#: Each varied factor's range (low, high), drawn uniformly in this order from the seed:
#: the Pacejka B, C and D of each axle (front, then rear), the servo's time constant, its
#: rate limit (both ways) and the speed loop's gains (accelerating and braking alike). The
#: system-identification benchmark's softer and grippier cars lie within them.
VARIED_RANGES: tuple[tuple[str, float, float], ...] = (
    ("front_B", 0.7, 1.3), ("front_C", 0.8, 1.2), ("front_D", 0.75, 1.25),
    ("rear_B", 0.7, 1.3), ("rear_C", 0.8, 1.2), ("rear_D", 0.75, 1.25),
    ("steering_time_constant", 0.6, 1.4), ("steering_rate", 0.7, 1.0),
    ("speed_gain", 0.7, 1.35),
)
#: The identified car's values the factors scale (``shared.config.vehicle``'s preset).
_ID_FRONT = (4.80, 2.16, 0.650, 0.373)
_ID_REAR = (20.0, 1.5, 0.618, 0.0)
_ID_TAU_S, _ID_RATE_RADPS = 0.158, 3.2
_GYM_SPEED_GAINS = (4.755, 19.02)


class UnknownCarError(ValueError):
    """A car name that is not in ``CARS`` (nor ``varied:SEED``)."""


def varied_factors(seed: int) -> dict[str, float]:
    """The factors of ``varied:SEED`` (``VARIED_RANGES``' names), drawn from `seed`."""
    rng = np.random.default_rng([0x7AC3, int(seed)])
    return {name: float(rng.uniform(lo, hi)) for name, lo, hi in VARIED_RANGES}


def varied_car(seed: int) -> CarSpec:
    """``varied:SEED``: the identified car with its tyres, servo and speed loop scaled by
    ``varied_factors(seed)``, the planners told it (the linear cornering stiffnesses kept
    at the Pacejka slope ``B C D``, as the preset's)."""
    if seed < 0:
        raise UnknownCarError(f"{VARIED}{seed}: the seed must be 0 or more")
    f = varied_factors(seed)

    def axle(base: tuple[float, float, float, float], side: str) -> list[float]:
        b, c, d, e = base
        return [b * f[f"{side}_B"], c * f[f"{side}_C"], d * f[f"{side}_D"], e]

    front, rear = axle(_ID_FRONT, "front"), axle(_ID_REAR, "rear")
    rate = _ID_RATE_RADPS * f["steering_rate"]
    vehicle = {
        **_IDENTIFIED,
        "pacejka_front": front, "pacejka_rear": rear,
        "cornering_stiffness_front_per_rad": front[0] * front[1] * front[2],
        "cornering_stiffness_rear_per_rad": rear[0] * rear[1] * rear[2],
        "steering_time_constant_s": _ID_TAU_S * f["steering_time_constant"],
        "steering_rate_max_radps": rate, "steering_rate_min_radps": -rate,
        "speed_gain_accel_per_s": _GYM_SPEED_GAINS[0] * f["speed_gain"],
        "speed_gain_brake_per_s": _GYM_SPEED_GAINS[1] * f["speed_gain"],
    }
    grip = 0.5 * (f["front_D"] + f["rear_D"])
    return CarSpec(f"{VARIED}{seed}", {"vehicle": vehicle}, True,
                   f"the identified car varied by seed {seed} (grip x{grip:.2f}, servo "
                   f"x{f['steering_time_constant']:.2f}), the planners told it")


def car_spec(name: str) -> CarSpec:
    """The car `name`: one of ``CARS`` or ``varied:SEED``; UnknownCarError otherwise."""
    if name in CARS:
        return CARS[name]
    if name.startswith(VARIED):
        seed = name.removeprefix(VARIED)
        if seed.isdigit():
            return varied_car(int(seed))
    raise UnknownCarError(f"unknown car {name!r}; choose from {', '.join(CARS)} or "
                          f"{VARIED}SEED")


def car_names(text: str | Iterable[str]) -> list[str]:
    """The cars of a comma list (or names), in order, each once; UnknownCarError naming
    the wrong ones and the choices (``CARS``, or ``varied:SEED``)."""
    items = text.split(",") if isinstance(text, str) else list(text)
    names = [n.strip() for n in items if n.strip()]
    bad = []
    for n in names:
        try:
            car_spec(n)
        except UnknownCarError:
            bad.append(n)
    if bad or not names:
        raise UnknownCarError(f"unknown car {', '.join(bad) or '(none)'}; choose from "
                              f"{', '.join(CARS)} or {VARIED}SEED")
    return list(dict.fromkeys(names))
