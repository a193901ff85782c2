"""``racestack tune``: parameter search of a method for the fastest clean laps (Optuna).

What other tools use (``__all__``): the bench's ``cimpcc-tuned`` column (``TunedCimpcc``,
``load_tuned``, ``tuned_planner``) and the command line (``build_parser``, ``main``, imported
when called: the search imports the bench's closed loop and Optuna).
"""

from __future__ import annotations

import argparse

from services.tools.tune.bench_column import NAME as TUNED_COLUMN
from services.tools.tune.bench_column import TunedCimpcc, load_tuned, tuned_planner


def build_parser(ap: argparse.ArgumentParser | None = None) -> argparse.ArgumentParser:
    """The ``racestack tune`` arguments (``services.tools.tune.cli.build_parser``)."""
    from services.tools.tune.cli import build_parser as _build_parser

    return _build_parser(ap)


def main(argv: list[str] | None = None, args: argparse.Namespace | None = None) -> int:
    """``racestack tune`` (``services.tools.tune.cli.main``)."""
    from services.tools.tune.cli import main as _main

    return _main(argv, args)


__all__ = ["TUNED_COLUMN", "TunedCimpcc", "build_parser", "load_tuned", "main", "tuned_planner"]
