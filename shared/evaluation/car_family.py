"""The family of cars the robustness benchmark races and ``racestack tune`` tunes over.

Each car is a set of configuration tables (``[vehicle]`` and, for a model mismatch,
``[simulator.vehicle]``) laid over a base configuration, and whether the planners are told
the car the simulator races. One definition, read by ``benchmarks/robustness.py`` (its
``--cars``) and ``services/tools/tune`` (its ``--cars``). Plain data: no I/O.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass
from typing import Any


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


class UnknownCarError(ValueError):
    """A car name that is not in ``CARS``."""


def car_names(text: str | Iterable[str]) -> list[str]:
    """The cars of a comma list (or names), in order, each once; UnknownCarError naming
    the wrong ones and the choices."""
    items = text.split(",") if isinstance(text, str) else list(text)
    names = [n.strip() for n in items if n.strip()]
    bad = [n for n in names if n not in CARS]
    if bad or not names:
        raise UnknownCarError(f"unknown car {', '.join(bad) or '(none)'}; choose from "
                              f"{', '.join(CARS)}")
    return list(dict.fromkeys(names))
