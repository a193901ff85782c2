"""Commands as a user can paste them: the hints the tools print (``rerun runs/...``,
``racestack report ...``, ``racestack mintime ...``) name an executable that runs.

After ``make demo`` the console scripts (``racestack``, ``rerun``) are in ``.venv/bin``,
beside the interpreter, and that folder is usually not on ``PATH``: a bare ``rerun`` would
be "command not found". ``runnable(name)`` is the bare name only when the ``name`` found on
``PATH`` is the one beside this interpreter; else the path of the one beside it (relative to
the working folder when inside it, e.g. ``.venv/bin/rerun``, else absolute); a name that is
not beside the interpreter stays bare (installed some other way, or not at all).
"""

from __future__ import annotations

import os
import shutil
import sys
from pathlib import Path

__all__ = ["racestack_command", "runnable"]


def _shown(path: Path, cwd: Path) -> str:
    """`path` relative to `cwd` when inside it (``.venv/bin/rerun``), else absolute."""
    try:
        return str(path.relative_to(cwd))
    except ValueError:
        return str(path)


def runnable(name: str, executable: str | None = None, cwd: Path | None = None) -> str:
    """How to call console script `name` (see the module docstring).

    Args:
        name: the script's name (``rerun``, ``racestack``).
        executable: the interpreter whose folder holds the scripts (None: ``sys.executable``).
        cwd: the working folder paths are shown relative to (None: the current one).
    """
    folder = Path(executable or sys.executable).parent
    beside = folder / name
    if not (beside.is_file() and os.access(beside, os.X_OK)):
        return name
    on_path = shutil.which(name)
    if on_path is not None and Path(on_path).resolve() == beside.resolve():
        return name
    cwd = Path.cwd() if cwd is None else cwd
    return _shown(Path(os.path.abspath(beside)), Path(os.path.abspath(cwd)))


def racestack_command(executable: str | None = None, cwd: Path | None = None) -> str:
    """How to call ``racestack``: ``runnable("racestack")``, or ``PYTHON -m
    services.tools.cli`` when no ``racestack`` script is beside the interpreter."""
    exe = executable or sys.executable
    got = runnable("racestack", exe, cwd)
    if got != "racestack" or (Path(exe).parent / "racestack").is_file():
        return got
    if shutil.which("racestack") is not None:
        return "racestack"
    cwd = Path.cwd() if cwd is None else cwd
    return f"{_shown(Path(os.path.abspath(exe)), Path(os.path.abspath(cwd)))} -m services.tools.cli"
