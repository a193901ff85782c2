"""The NLP solver back-end: fatrop (structure detection) or ipopt, compiled and cached on disk.

Compiling the problem functions (``generate_dependencies`` + ``gcc -O2``) halves the solve time
(``../shared/docs/solver-notes.md``) but takes seconds, so the shared object is cached under a
key hashed from the problem's structure, the back-end and the CasADi version: a second start
loads it at once. With no working compiler the solver falls back to CasADi's virtual machine
(slower, same results) and says so in ``SolverHandle.compiled``.
"""

from __future__ import annotations

import hashlib
import logging
import os
import shutil
import subprocess
import tempfile
from dataclasses import dataclass
from pathlib import Path

import casadi as ca

from services.planner.cache import default_cache_dir
from services.planner.mpc.problem import OcpProblem
from shared.config.planner import SolverSettings

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class SolverHandle:
    """A ready solver and how it was made.

    Attributes:
        solve: the CasADi nlpsol Function (x0, p, lbx, ubx, lbg, ubg -> x, f, g, ...).
        backend: "fatrop" or "ipopt".
        compiled: whether the problem functions run as compiled C.
        library: path of the compiled shared object, if any.
        cache_hit: whether the compiled object came from the cache.
    """

    solve: ca.Function
    backend: str
    compiled: bool
    library: str | None
    cache_hit: bool


def solver_options(problem: OcpProblem, settings: SolverSettings) -> dict:
    """nlpsol options of the chosen back-end (quiet, warm-start friendly)."""
    common = {"print_time": False, "error_on_fail": False}
    push = (
        {} if settings.bound_push is None
        else {"bound_push": settings.bound_push, "bound_frac": settings.bound_push}
    )
    if settings.backend == "fatrop":
        return {
            **common,
            "structure_detection": "auto",
            "equality": list(problem.equality),
            "fatrop": {
                "print_level": 0,
                "max_iter": settings.max_iter,
                "tol": settings.tol,
                "mu_init": settings.mu_init,
                **push,
            },
        }
    return {
        **common,
        "ipopt": {
            "print_level": 0,
            "sb": "yes",
            "max_iter": settings.max_iter,
            "tol": settings.tol,
            "mu_init": settings.mu_init,
            "warm_start_init_point": "yes",
            "linear_solver": "mumps",
            **push,
        },
    }


def cache_key(problem: OcpProblem, settings: SolverSettings) -> str:
    """Hash of everything the compiled object depends on."""
    text = "|".join([problem.signature, settings.backend, ca.__version__, "gcc-O2-v1"])
    return hashlib.sha256(text.encode()).hexdigest()[:24]


def _compile(problem: OcpProblem, settings: SolverSettings, target: Path) -> None:
    """Generate C for the problem functions and compile them into `target` (atomic rename)."""
    if shutil.which(settings.compiler) is None:
        raise FileNotFoundError(f"compiler {settings.compiler!r} not found")
    target.parent.mkdir(parents=True, exist_ok=True)
    opts = solver_options(problem, settings)
    generator = ca.nlpsol("gen", settings.backend, problem.nlp, opts)
    with tempfile.TemporaryDirectory(dir=target.parent) as tmp:
        cwd = os.getcwd()
        try:
            os.chdir(tmp)
            generator.generate_dependencies("nlp.c")
        finally:
            os.chdir(cwd)
        tmp_so = Path(tmp) / "nlp.so"
        subprocess.run(
            [
                settings.compiler,
                "-O2",
                "-fPIC",
                "-shared",
                str(Path(tmp) / "nlp.c"),
                "-o",
                str(tmp_so),
                "-lm",
            ],
            check=True,
            capture_output=True,
            timeout=300,
        )
        os.replace(tmp_so, target)


def compiled_problem_line(library: Path, hit: bool) -> str:
    """The log line of a compiled problem: loaded from the cache (`hit`), or compiled now
    into `library` (once per problem structure and solver settings, then read from there)."""
    if hit:
        return f"compiled problem functions from the cache: {library}"
    return (f"compiling the problem functions into {library} (not in the cache yet; later "
            "starts load it from there)")


def make_solver(problem: OcpProblem, settings: SolverSettings) -> SolverHandle:
    """Create the solver for `problem`; compile (or load from cache) when asked and possible."""
    opts = solver_options(problem, settings)
    if settings.compile:
        cache_dir = Path(settings.cache_dir) if settings.cache_dir else default_cache_dir()
        library = cache_dir / f"cimpcc-{cache_key(problem, settings)}.so"
        hit = library.exists()
        log.info("%s", compiled_problem_line(library, hit))
        try:
            if not hit:
                _compile(problem, settings, library)
            solve = ca.nlpsol("planner", settings.backend, str(library), opts)
            return SolverHandle(solve, settings.backend, True, str(library), hit)
        except (OSError, subprocess.SubprocessError, RuntimeError) as exc:
            log.warning("compiled solver unavailable (%s); using the uncompiled one", exc)
    solve = ca.nlpsol("planner", settings.backend, problem.nlp, {**opts, "expand": True})
    return SolverHandle(solve, settings.backend, False, None, False)
