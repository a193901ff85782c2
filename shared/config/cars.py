"""Several cars on one track (``[[cars]]``, issue #24): who races, how fast, where it starts.

An empty list (the default) is the single car of ``[bus] car``, exactly as before. With two
or more entries ONE simulator process integrates every car (each with its own keys
``racestack/<name>/...``), and ``racestack up`` starts a bridge and a planner per car::

    [[cars]]
    name = "car0"                  # the leader: starts where a single car starts

    [[cars]]
    name = "car1"
    method = "cimpcc"              # default: [planner] method
    speed_scale = 0.85             # its speed commands are scaled by this in the simulator
    start_gap_m = 1.5              # this far behind the car ahead of it in the list

    [[cars]]
    name = "car2"
    method = "raceline"
    pace = 0.85                    # its planner races 85 % of its line's speeds
"""

from __future__ import annotations

from pydantic import Field, field_validator

from shared.config.base import Section
from shared.keys import check_chunk


class CarEntry(Section):
    """One car of ``[[cars]]``.

    Attributes:
        name: the car's name, the ``<car>`` chunk of its keys (``[A-Za-z0-9_-]+``).
        method: its planner's method (a method of the registry); None: ``[planner] method``.
        speed_scale: the simulator multiplies this car's speed commands by it (a slower car
            with the same planner: 0.85 is an opponent at 85 % of what its planner asks);
            1 = as commanded. Its planner steers for speeds the car never reaches: a
            tracker method cuts its bends that way; use ``pace`` for it.
        pace: its planner races this share of its line's speeds (``[planner.raceline]
            speed_share``: the slower plan keeps the line's path and dynamic steering, a
            clean slower car); only for a method that races a planned line (``raceline``);
            1 = the line's own.
        start_gap_m: it starts this far behind the car before it in the list, along the
            centreline [m] (the first car: behind the single car's start; default 0).
        start_s_m: instead of the gap, its start as arc length from the line [m] (None: by
            the gap).
    """

    name: str
    method: str | None = None
    speed_scale: float = Field(1.0, gt=0.0, le=2.0, allow_inf_nan=False)
    pace: float = Field(1.0, gt=0.1, le=1.0, allow_inf_nan=False)
    start_gap_m: float = Field(0.0, ge=0.0, le=1e3, allow_inf_nan=False)
    start_s_m: float | None = Field(None, ge=-1e4, le=1e4, allow_inf_nan=False)

    @field_validator("name")
    @classmethod
    def _safe_name(cls, v: str) -> str:
        return check_chunk(v, "car name")

    @field_validator("method")
    @classmethod
    def _known_method(cls, v: str | None) -> str | None:
        from shared.config.methods import planner_methods

        if v is not None and v not in planner_methods():
            raise ValueError(f"unknown method {v!r}; known: {', '.join(planner_methods())}")
        return v


def check_cars(cars: tuple[CarEntry, ...], default_method: str | None = None
               ) -> tuple[CarEntry, ...]:
    """`cars` if their names are distinct and each ``pace`` below 1 is a method's that races
    a planned line (ValueError otherwise); `default_method`: ``[planner] method``."""
    from shared.config.methods import METHODS

    names = [c.name for c in cars]
    if len(set(names)) != len(names):
        raise ValueError(f"[[cars]] names repeat: {names}")
    for c in cars:
        method = c.method or default_method
        if c.pace != 1.0 and method is not None and METHODS[method].kind != "tracker":
            raise ValueError(f"[[cars]] {c.name}: pace {c.pace:g} needs a method that races a "
                             f"planned line (raceline), not {method}; speed_scale slows any "
                             "method in the simulator")
    return cars


def start_positions(cars: tuple[CarEntry, ...], lead_s_m: float) -> list[float]:
    """Each car's start arc length [m]: `lead_s_m` for the first (minus its own gap), each
    later one its ``start_gap_m`` behind the one before it; ``start_s_m`` when given."""
    out: list[float] = []
    s = lead_s_m
    for i, c in enumerate(cars):
        s = s - c.start_gap_m if i or c.start_gap_m else s
        if c.start_s_m is not None:
            s = c.start_s_m
        out.append(s)
    return out
