"""The one check every command with an output folder makes before it starts any work, and
the clean-up of the folders it made when it then cannot start."""

from __future__ import annotations

from pathlib import Path


def writable_dir_problem(path: Path) -> str | None:
    """Create `path` (and its parents) and prove it is writable.

    Returns:
        None when it is usable, else one line saying why not (for the caller's own error).
    """
    try:
        if path.exists() and not path.is_dir():
            return f"output folder {path} is a file, not a folder"
        path.mkdir(parents=True, exist_ok=True)
        probe = path / ".write-test"
        probe.write_text("ok")
        probe.unlink()
    except OSError as exc:
        return f"output folder {path} is not writable ({exc.strerror or exc})"
    return None


def missing_dirs(path: Path) -> list[Path]:
    """`path` and those of its parents that do not exist yet, deepest first: what
    ``writable_dir_problem`` (``mkdir(parents=True)``) would create."""
    out: list[Path] = []
    p = Path(path)
    while True:
        try:
            if p.exists():
                break
        except OSError:
            break
        out.append(p)
        if p.parent == p:
            break
        p = p.parent
    return out


def remove_empty_dirs(dirs: list[Path]) -> None:
    """Remove the folders of `dirs` (deepest first, as ``missing_dirs`` lists them) that
    exist and are empty; anything else is left alone (never raises)."""
    for d in dirs:
        try:
            d.rmdir()  # only an empty folder goes
        except OSError:
            return  # not empty (or not ours to remove): its parents are not empty either
