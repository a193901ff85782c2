"""The one check every command with an output folder makes before it starts any work."""

from __future__ import annotations

from pathlib import Path


def writable_dir_problem(path: Path) -> str | None:
    """Create `path` (and its parents) and prove it is writable.

    Returns:
        None when it is usable, else one line saying why not (for the caller's own error).
    """
    try:
        path.mkdir(parents=True, exist_ok=True)
        probe = path / ".write-test"
        probe.write_text("ok")
        probe.unlink()
    except OSError as exc:
        return f"output folder {path} is not writable ({exc.strerror or exc})"
    return None
