"""The method registry (``shared/config/methods.py``): the one place the method names are
written, and what derives from it.

- No code outside the registry writes a method's name as a string (docstrings aside): it
  names it by the registry's constant, so a renamed or added method cannot be missed.
- A toy method added in a few lines is accepted by the configuration, built by the planner's
  registry, raced by the bench and offered by the command line.
- ``PlannerPool`` shares one problem and solver between methods of the same structure.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

from services.planner import Planner, PlannerPool, make_planner
from services.planner.mintime.requests import for_pose_source
from services.planner.registry import _problem_key
from services.tools.bench.run import BenchError, parse_methods
from services.tools.cli import build_parser
from shared.config import ConfigError, config_from_dict
from shared.config.methods import (
    CIMPCC,
    CIMPCC_LINE,
    METHODS,
    MPCC,
    MPCC_TUNED,
    RACELINE,
    MethodSpec,
    UnknownMethodError,
    bench_methods,
    method_setup,
    method_spec,
    planner_methods,
)
from shared.config.planner import PlannerSettings, SolverSettings
from shared.messages import PLAN_METHODS
from shared.track import load_track

ROOT = Path(__file__).resolve().parents[2]
REGISTRY = ROOT / "shared" / "config" / "methods.py"


def _docstrings(tree: ast.AST) -> set[int]:
    out = set()
    for node in ast.walk(tree):
        if isinstance(node, (ast.Module, ast.ClassDef, ast.FunctionDef, ast.AsyncFunctionDef)):
            body = node.body
            if body and isinstance(body[0], ast.Expr) and isinstance(body[0].value, ast.Constant):
                out.add(id(body[0].value))
    return out


def method_name_literals(names: set[str]) -> list[str]:
    """Every string constant (not a docstring) equal to a method name in services/, shared/
    and benchmarks/, outside the registry, as ``file:line: name``."""
    found = []
    files = [*ROOT.glob("services/**/*.py"), *ROOT.glob("shared/**/*.py"),
             *ROOT.glob("benchmarks/**/*.py")]
    for path in sorted(files):
        if path == REGISTRY:
            continue
        tree = ast.parse(path.read_text(encoding="utf-8"))
        docs = _docstrings(tree)
        for node in ast.walk(tree):
            if (
                isinstance(node, ast.Constant)
                and isinstance(node.value, str)
                and node.value in names
                and id(node) not in docs
            ):
                found.append(f"{path.relative_to(ROOT)}:{node.lineno}: {node.value!r}")
    return found


def test_method_names_are_written_only_in_the_registry() -> None:
    found = method_name_literals(set(METHODS))
    assert not found, "name methods by shared.config.methods' constants:\n" + "\n".join(found)


def test_the_checker_finds_a_method_name_literal(tmp_path: Path) -> None:
    tree = ast.parse('"""cimpcc in a docstring is fine"""\nx = "cimpcc"\ny = f"{x}"\n')
    docs = _docstrings(tree)
    hits = [n.lineno for n in ast.walk(tree)
            if isinstance(n, ast.Constant) and n.value == CIMPCC and id(n) not in docs]
    assert hits == [2]


def test_every_list_of_methods_derives_from_the_registry() -> None:
    assert planner_methods() == (CIMPCC, MPCC, RACELINE, CIMPCC_LINE)
    assert bench_methods() == tuple(METHODS)
    assert PLAN_METHODS == planner_methods()
    cli = build_parser()
    laps = next(a for a in cli._subparsers._group_actions[0].choices["laps"]._actions
                if a.dest == "method")
    assert tuple(laps.choices) == planner_methods()
    assert parse_methods(",".join(METHODS)) == list(METHODS)
    with pytest.raises(BenchError, match="choose from cimpcc, mpcc"):
        parse_methods("pid")


def test_the_configuration_accepts_only_planner_methods() -> None:
    for name in planner_methods():
        assert config_from_dict({"planner": {"method": name}}).planner.method == name
    with pytest.raises(ConfigError, match="unknown method 'pid'"):
        config_from_dict({"planner": {"method": "pid"}})
    with pytest.raises(ConfigError, match="unknown method 'mpcc-tuned'"):  # a bench variant
        config_from_dict({"planner": {"method": MPCC_TUNED}})
    with pytest.raises(UnknownMethodError):
        method_spec(MPCC_TUNED, in_planner=True)


def test_a_setup_is_what_the_spec_says() -> None:
    settings = PlannerSettings()
    paper = method_setup(settings, CIMPCC)
    assert paper.structure is settings and paper.solver is settings.solver
    assert (paper.model, paper.lead_s, paper.lifted, paper.speed_cap_mps) == (
        "kinematic", 0.0, False, None)
    assert method_setup(settings, MPCC).weights is settings.mpcc
    line = method_setup(settings, CIMPCC_LINE)
    own = settings.cimpcc_line
    assert line.weights is own.weights and line.model == own.model
    assert line.structure.horizon_steps == own.horizon_steps
    assert line.structure.integrator == own.integrator
    assert line.solver.tol == own.solver.tol and line.solver.backend == settings.solver.backend
    assert line.lead_s == own.lead_pose_s and line.speed_cap_mps == own.v_max_mps
    # a variant resolves to its base's settings section
    assert method_setup(settings, MPCC_TUNED).weights is settings.mpcc


UNCOMPILED = PlannerSettings(solver=SolverSettings(compile=False))


def test_a_toy_method_is_one_entry(monkeypatch: pytest.MonkeyPatch) -> None:
    """A new method: one registry entry (here: MPCC's weights on the centreline, under a
    name of its own); the configuration, the planner, the bench and the CLI take it."""
    toy = MethodSpec("mpcc-toy", "mpc", "centreline", "mpcc", "mpcc", summary="a toy")
    monkeypatch.setitem(METHODS, toy.name, toy)
    settings = UNCOMPILED.model_copy(update={"method": toy.name})
    PlannerSettings(method=toy.name)  # validates
    planner = make_planner(load_track("paperlike"), settings)
    assert isinstance(planner, Planner) and planner.method == toy.name
    assert planner.weights is settings.mpcc
    res = planner.step(*load_track("paperlike").xy[0], 0.0)
    assert res.method == toy.name
    assert parse_methods(toy.name) == [toy.name]
    assert toy.name in planner_methods()


def test_the_pool_shares_problems_of_the_same_structure() -> None:
    track = load_track("paperlike")
    pool = PlannerPool(track)
    a = pool.planner(UNCOMPILED, CIMPCC)
    b = pool.planner(UNCOMPILED, MPCC)
    c = pool.planner(UNCOMPILED, MPCC_TUNED)
    assert isinstance(a, Planner) and isinstance(b, Planner) and isinstance(c, Planner)
    assert a.problem is b.problem is c.problem and a.solver is b.solver is c.solver
    assert (a.weights, b.weights, c.method) == (UNCOMPILED.cimpcc, UNCOMPILED.mpcc, MPCC)
    assert pool.built == (1, 1)
    longer = UNCOMPILED.model_copy(update={"horizon_steps": 12})
    d = pool.planner(longer, CIMPCC)
    assert d.problem is not a.problem and pool.built == (2, 2)


def test_a_line_method_shares_its_problem_across_pose_sources() -> None:
    """``cimpcc-line`` for the EKF or the lidar differs from the true pose's only in its
    speed estimate's gain (the planner's own Python): one problem and solver in a pool; a
    field the problem reads (the line's margin) still makes another."""
    base = PlannerSettings()
    keys = {
        pose: _problem_key(method_setup(for_pose_source(base, pose), CIMPCC_LINE), None)
        for pose in ("truth", "ekf", "lidar")
    }
    gains = {for_pose_source(base, p).cimpcc_line.speed_estimate_gain for p in keys}
    assert len(gains) > 1  # the settings do differ ...
    assert keys["truth"] == keys["ekf"] == keys["lidar"]  # ... not in the problem
    wider = base.model_copy(update={"cimpcc_line": base.cimpcc_line.model_copy(
        update={"line_margin_m": base.cimpcc_line.line_margin_m + 0.01})})
    assert _problem_key(method_setup(wider, CIMPCC_LINE), None) != keys["truth"]
