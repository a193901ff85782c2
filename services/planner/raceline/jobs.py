"""Work done a slice at a time, so that no planner tick carries all of it. Pure Python.

A job is a generator that yields the work of its next slice, in node steps (one node of a
pass over a line, one node of a plan made along it), *before* doing it, and returns its
result. ``run_job`` does a job at once; ``SlicedJob`` does as many of its slices as fit in
a budget of work per call (one call per tick: ``grip_profile.GripReplan``). Announcing a
slice's work before doing it lets the budget stop short of a slice that would overrun it.
"""

from __future__ import annotations

from collections.abc import Generator
from typing import Generic, TypeVar

T = TypeVar("T")

#: A job: yields each slice's work [node steps] before doing it, returns its result.
Job = Generator[int, None, T]


def run_job(job: Job[T]) -> T:
    """`job` done at once: its result."""
    while True:
        try:
            next(job)
        except StopIteration as done:
            return done.value


class SlicedJob(Generic[T]):
    """A job done ``advance`` by ``advance``, each within a budget of work (module
    docstring)."""

    def __init__(self, job: Job[T]) -> None:
        self._job = job
        self._next: int | None = None  # the work [node steps] of the job's next slice
        self.done = False
        self.result: T | None = None
        #: node steps done so far, and the ``advance`` calls it took
        self.work_done = 0
        self.ticks = 0

    def advance(self, work: int) -> bool:
        """Do the job's next slices, as many as fit in `work` node steps (at least one: a
        slice larger than `work` is done alone); whether the job is done (its ``result``)."""
        if work < 1:
            raise ValueError(f"the work per call must be at least 1 node step, got {work}")
        spent = 0
        self.ticks += 1
        while not self.done:
            if self._next is not None and spent and spent + self._next > work:
                break
            spent += self._next or 0
            try:  # the slice announced done (none the first time), the next one's work
                self._next = next(self._job)
            except StopIteration as finished:
                self.result = finished.value
                self.done = True
        self.work_done += spent
        return self.done
