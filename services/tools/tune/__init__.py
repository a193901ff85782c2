"""``racestack tune``: parameter search of a method for the fastest clean laps (Optuna).

What other tools use (``__all__``): the command line (``build_parser``, ``main``, imported
when called: the search imports the bench's closed loop and Optuna). The tuner sits above the
bench: it races trials with the bench's closed loop; the bench's ``cimpcc-tuned`` column
reads a tuned file itself (``services.tools.bench.tuned``).
"""

from __future__ import annotations

import argparse


def build_parser(ap: argparse.ArgumentParser | None = None) -> argparse.ArgumentParser:
    """The ``racestack tune`` arguments (``services.tools.tune.cli.build_parser``)."""
    from services.tools.tune.cli import build_parser as _build_parser

    return _build_parser(ap)


def main(argv: list[str] | None = None, args: argparse.Namespace | None = None) -> int:
    """``racestack tune`` (``services.tools.tune.cli.main``)."""
    from services.tools.tune.cli import main as _main

    return _main(argv, args)


__all__ = ["build_parser", "main"]
