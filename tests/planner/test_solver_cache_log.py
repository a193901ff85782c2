"""The planner's log tells the truth about its compiled problem (issue #22): "compiling
... (not in the cache yet ...)" only when it compiles, "... from the cache" when it loads,
and the service's first line claims neither."""

from __future__ import annotations

import inspect
import logging
from pathlib import Path

import pytest

from services.planner import service as planner_service
from services.planner.mpc import solver as solver_mod
from services.planner.mpc.problem import build_problem
from services.planner.mpc.solver import cache_key, compiled_problem_line, make_solver
from shared.config.methods import CIMPCC
from shared.config.planner import PlannerSettings, SolverSettings
from shared.track import load_track


def test_the_line_says_compile_or_cache() -> None:
    lib = Path("/c/cimpcc-x.so")
    hit = compiled_problem_line(lib, hit=True)
    assert hit == f"compiled problem functions from the cache: {lib}"
    miss = compiled_problem_line(lib, hit=False)
    assert miss.startswith(f"compiling the problem functions into {lib}")
    assert "not in the cache yet" in miss and "(once)" not in miss


@pytest.mark.parametrize("hit", [False, True], ids=["miss", "hit"])
def test_make_solver_logs_one_true_line(tmp_path: Path, monkeypatch, caplog, hit: bool) -> None:
    settings = PlannerSettings(
        method=CIMPCC, horizon_steps=5, solver=SolverSettings(compile=True, cache_dir=str(tmp_path))
    )
    problem = build_problem(load_track("gentle"), settings)
    library = tmp_path / f"cimpcc-{cache_key(problem, settings.solver)}.so"
    if hit:
        library.write_bytes(b"not a library")  # loading fails: the uncompiled fallback
    compiled: list[Path] = []

    def no_compiler(_problem, _settings, target: Path) -> None:
        compiled.append(target)
        raise OSError("no compiler in this test")

    monkeypatch.setattr(solver_mod, "_compile", no_compiler)
    with caplog.at_level(logging.INFO, logger=solver_mod.__name__):
        handle = make_solver(problem, settings.solver)
    infos = [r.getMessage() for r in caplog.records if r.levelno == logging.INFO]
    assert infos == [compiled_problem_line(library, hit)]
    assert compiled == ([] if hit else [library]) and not handle.compiled


def test_the_service_does_not_claim_a_cached_problem() -> None:
    source = inspect.getsource(planner_service.run)
    assert "cached" not in source and "building the %s planner on %s" in source
