"""Work done a slice at a time (``services.planner.raceline.jobs``)."""

from __future__ import annotations

import pytest

from services.planner.raceline.jobs import Job, SlicedJob, run_job


def _job(works: list[int], log: list[int]) -> Job[str]:
    """Slices of the given work; each logged as it is done."""
    for w in works:
        yield w
        log.append(w)
    return "done"


def test_run_job_does_every_slice_and_returns_the_result() -> None:
    log: list[int] = []
    assert run_job(_job([3, 4, 5], log)) == "done" and log == [3, 4, 5]


def test_a_sliced_job_stops_short_of_a_slice_that_would_overrun_the_budget() -> None:
    log: list[int] = []
    job = SlicedJob(_job([3, 4, 5, 20, 1], log))
    assert not job.advance(8) and log == [3, 4]  # 3 + 4 + 5 > 8: the 5 waits
    assert not job.advance(8) and log == [3, 4, 5]  # 5 + 20 > 8
    assert not job.advance(8) and log == [3, 4, 5, 20]  # larger than the budget: alone
    assert job.advance(8) and log == [3, 4, 5, 20, 1] and job.result == "done"
    assert job.ticks == 4 and job.work_done == 33
    assert job.advance(8) and job.work_done == 33  # done: nothing more
    with pytest.raises(ValueError):
        SlicedJob(_job([1], [])).advance(0)


def test_an_empty_job_is_done_at_the_first_call() -> None:
    job = SlicedJob(_job([], []))
    assert job.advance(1) and job.result == "done" and job.work_done == 0
