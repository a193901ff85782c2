"""``racestack bench``: methods racing the simulated car in one process (no Zenoh).

What other tools, benchmarks and tests use (``__all__``):

- the closed loop: ``race(planner, plant, laps, max_ticks=, on_tick=)`` -> ``RaceResult``,
  against a ``Plant`` (``ModelPlant``: the planner's own kinematic model;
  ``SimulatorPlant``: the dynamic simulator with the bench's timing model);
- ``run_method(name, planner, track, sim_settings, LoopOptions)`` -> ``MethodRun`` (the
  simulator plant, the bench's record);
- localisation in the loop: ``LoopOptions(estimator="ekf" | "lidar")`` runs the
  simulator's sensors through the bridge's filter (``InLoopEstimator``, ``ESTIMATORS``);
- the command line: ``build_parser``, ``main`` (imported when called: the bench's command
  line imports the tuner's column, which imports this package).
"""

from __future__ import annotations

import argparse

from services.tools.bench.closed_loop import (
    LOST_E_CON_M,
    STALL_TIMEOUT_S,
    LoopOptions,
    SimulatorPlant,
    run_method,
)
from services.tools.bench.estimation import ESTIMATORS, InLoopEstimator
from services.tools.bench.race import ModelPlant, Plant, RaceResult, race


def build_parser(ap: argparse.ArgumentParser | None = None) -> argparse.ArgumentParser:
    """The ``racestack bench`` arguments (``services.tools.bench.run.build_parser``)."""
    from services.tools.bench.run import build_parser as _build_parser

    return _build_parser(ap)


def main(argv: list[str] | None = None, args: argparse.Namespace | None = None) -> int:
    """``racestack bench`` (``services.tools.bench.run.main``)."""
    from services.tools.bench.run import main as _main

    return _main(argv, args)


__all__ = [
    "ESTIMATORS",
    "LOST_E_CON_M",
    "STALL_TIMEOUT_S",
    "InLoopEstimator",
    "LoopOptions",
    "ModelPlant",
    "Plant",
    "RaceResult",
    "SimulatorPlant",
    "build_parser",
    "main",
    "race",
    "run_method",
]
