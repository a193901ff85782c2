"""The optional extras: libraries only some tools need, installed with ``.[tools]`` or
``.[ros2]`` (pyproject.toml), never by a process service of the stack or ``racestack up``.

A command that needs one calls ``require`` before it starts its work; without the library it
raises ``MissingExtraError``, which the ``racestack`` command and the service shell print as one
line (``racestack tune: needs optuna: pip install -e '.[tools]'``) with exit code 2. The
modules that use these libraries import them inside the functions that need them (or live in
a tool), so importing any process service or building the cli's parser works without them.
"""

from __future__ import annotations

import importlib

#: Import name -> (distribution, extra) of each optional library.
EXTRAS: dict[str, tuple[str, str]] = {
    "optuna": ("optuna", "tools"),  # racestack tune
    "matplotlib": ("matplotlib", "tools"),  # the figures of bench, report, mintime, tune, track
    "skimage": ("scikit-image", "tools"),  # racestack track --from-map (brings scipy)
    "scipy": ("scipy", "tools"),  # racestack track --from-map (with scikit-image)
    "rosbags": ("rosbags", "ros2"),  # the ros2_gateway's CDR
}


class MissingExtraError(ImportError):
    """An optional library is not installed; the message names the extra to install."""

    def __init__(self, library: str) -> None:
        distribution, extra = EXTRAS[library]
        self.library, self.distribution, self.extra = library, distribution, extra
        super().__init__(f"needs {distribution}: pip install -e '.[{extra}]'", name=library)


def require(*libraries: str) -> None:
    """Import each of `libraries` (import names, keys of ``EXTRAS``); raise ``MissingExtraError``
    for the first one that is not installed."""
    for library in libraries:
        try:
            importlib.import_module(library)
        except ModuleNotFoundError as exc:
            if (exc.name or "").partition(".")[0] != library:
                raise  # the library is there but lacks one of its own dependencies
            raise MissingExtraError(library) from None


def missing_extra(exc: BaseException) -> MissingExtraError | None:
    """The ``MissingExtraError`` an import error stands for, when it is an optional library's
    (None for any other error)."""
    if isinstance(exc, MissingExtraError):
        return exc
    if isinstance(exc, ModuleNotFoundError):
        top = (exc.name or "").partition(".")[0]
        if top in EXTRAS:
            return MissingExtraError(top)
    return None
