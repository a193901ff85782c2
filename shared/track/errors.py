"""The one error a bad track file or track specification raises."""

from __future__ import annotations


class TrackError(ValueError):
    """A track could not be loaded: names the file (or track spec) and the problem."""

    def __init__(self, source: str, problem: str) -> None:
        super().__init__(f"{source}: {problem}")
        self.source = source
        self.problem = problem
