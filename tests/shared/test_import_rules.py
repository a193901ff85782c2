"""The layers' import rules, checked by walking every import of the source tree (ast).

1. ``shared/`` imports no service (it is the layer below them all).
2. A service that runs as its own process (simulator, localization_bridge, planner,
   vesc_driver, telemetry, router) imports no other service: they meet only on the bus.
3. The tools that compose services in one process (bench, launcher, tune, cli) use only each
   service's public package API, the names its ``__init__`` lists in ``__all__``: never an
   inner module such as ``services.planner.mpc.planner``.
4. Only ``shared/bus.py`` imports zenoh.

Every violation is named (file:line, what it imports, which rule). ``KNOWN`` lists the ones
that need files owned by others right now, each with the follow-up that removes it; an entry
that no longer occurs fails the test too, so the list only shrinks.
"""

from __future__ import annotations

import ast
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
#: Services that run as their own process.
PROCESS_SERVICES = frozenset(
    {
        "simulator",
        "localization_bridge",
        "planner",
        "vesc_driver",
        "telemetry",
        "router",
        "lidar_driver",
        "ros2_gateway",
    }
)
#: Tools that compose services in one process (``cli`` is ``services/tools/cli.py``).
TOOLS = frozenset({"bench", "launcher", "tune", "cli"})

#: Violations that need files owned by others, as "importer -> imported" (no line numbers,
#: so unrelated edits do not break the list). Remove an entry when its follow-up lands.
KNOWN: frozenset[str] = frozenset()
# (Follow-ups A-D of issue #11 landed: the planner, bench, tune, launcher and telemetry
# packages export what the tools use; services/tools/cli.py starts a service with runpy.)


@dataclass(frozen=True)
class Violation:
    """One import that breaks a rule."""

    path: str  #: importer, relative to the repository
    line: int
    imported: str  #: the module (or module.name) imported
    rule: str

    @property
    def key(self) -> str:
        """The allow-list form: ``importer -> imported`` (no line)."""
        return f"{self.path} -> {self.imported}"

    def __str__(self) -> str:
        return f"{self.path}:{self.line}: imports {self.imported} ({self.rule})"


def _unit(rel: Path) -> str | None:
    """The service or tool a file under services/ belongs to (None: services/__init__)."""
    parts = rel.parts
    if len(parts) == 2:
        return None if parts[1] == "__init__.py" else parts[1].removesuffix(".py")
    return parts[1]


def _package_of(rel: Path) -> list[str]:
    """The package a module file is in, as parts (an ``__init__``'s is its own folder)."""
    return list(rel.parts[:-1])


def _imports(tree: ast.AST, rel: Path) -> Iterator[tuple[int, str, list[str]]]:
    """(line, module, names) of every import; names empty for ``import x``."""
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            for alias in node.names:
                yield node.lineno, alias.name, []
        elif isinstance(node, ast.ImportFrom):
            module = node.module or ""
            if node.level:
                package = _package_of(rel)
                base = package[: len(package) - node.level + 1]
                module = ".".join([*base, module] if module else base)
            yield node.lineno, module, [a.name for a in node.names]
        elif (
            isinstance(node, ast.Call)
            and isinstance(node.func, ast.Attribute)
            and node.func.attr == "import_module"
            and node.args
        ):
            arg = node.args[0]
            text = ""
            if isinstance(arg, ast.Constant) and isinstance(arg.value, str):
                text = arg.value
            elif isinstance(arg, ast.JoinedStr):
                text = "".join(
                    v.value if isinstance(v, ast.Constant) else "<name>" for v in arg.values
                )
            if text.startswith("services."):
                yield node.lineno, f"{text} (importlib)", []


def public_api(package: str) -> frozenset[str]:
    """The names ``services/<package>/__init__.py`` lists in ``__all__`` (empty without)."""
    init = ROOT / "services" / package / "__init__.py"
    if not init.exists():
        return frozenset()
    for node in ast.parse(init.read_text(encoding="utf-8")).body:
        if isinstance(node, ast.Assign) and any(
            isinstance(t, ast.Name) and t.id == "__all__" for t in node.targets
        ):
            value = ast.literal_eval(node.value)
            return frozenset(value)
    return frozenset()


def violations() -> list[Violation]:
    """Every import in services/ and shared/ that breaks a rule of the module docstring."""
    found: list[Violation] = []
    for path in sorted([*ROOT.glob("services/**/*.py"), *ROOT.glob("shared/**/*.py")]):
        rel = path.relative_to(ROOT)
        tree = ast.parse(path.read_text(encoding="utf-8"), filename=str(rel))
        layer = rel.parts[0]
        unit = _unit(rel) if layer == "services" else None
        for line, module, names in _imports(tree, rel):
            head = module.split(".")
            if head[0] == "zenoh" and rel.as_posix() != "shared/bus.py":
                found.append(Violation(rel.as_posix(), line, module, "zenoh outside shared/bus"))
            if head[0] != "services" or len(head) < 2:
                continue
            target = head[1]
            if layer == "shared":
                found.append(Violation(rel.as_posix(), line, module, "shared imports services"))
                continue
            if target == unit or unit is None:
                continue
            if unit in PROCESS_SERVICES:
                rule = "a process service imports another service"
                found.append(Violation(rel.as_posix(), line, module, rule))
            elif unit in TOOLS:
                if len(head) > 2:
                    rule = "a tool imports an inner module"
                    found.append(Violation(rel.as_posix(), line, module, rule))
                    continue
                api = public_api(target)
                for name in names:
                    if name not in api:
                        rule = f"not in services.{target}.__all__"
                        found.append(Violation(rel.as_posix(), line, f"{module}.{name}", rule))
    return found


def test_the_walker_sees_every_kind_of_import() -> None:
    src = (
        "import services.planner.mpc.planner\n"
        "from services.simulator import LapTimer, nothing_public\n"
        "def f():\n"
        "    from services.tools.bench.run import main\n"
        "    importlib.import_module(f'services.{x}.service')\n"
        "from . import sibling\n"
    )
    got = sorted(_imports(ast.parse(src), Path("services/tools/tune/x.py")))
    assert got == [
        (1, "services.planner.mpc.planner", []),
        (2, "services.simulator", ["LapTimer", "nothing_public"]),
        (4, "services.tools.bench.run", ["main"]),
        (5, "services.<name>.service (importlib)", []),
        (6, "services.tools.tune", ["sibling"]),
    ]
    assert "LapTimer" in public_api("simulator")
    assert public_api("no_such_service") == frozenset()  # no __init__: no public API


def test_no_import_breaks_the_layers() -> None:
    found = violations()
    new = [v for v in found if v.key not in KNOWN]
    stale = sorted(KNOWN - {v.key for v in found})
    lines = []
    if new:
        lines.append("imports that break the layers (see docs/architecture.md):")
        lines += [f"  {v}" for v in new]
    if stale:
        lines.append("KNOWN entries that no longer occur (delete them from the list):")
        lines += [f"  {k}" for k in stale]
    assert not lines, "\n".join(lines)


def test_process_services_meet_only_on_the_bus() -> None:
    """No known exception for rule 2: a process service never imports another."""
    rule = "a process service imports another service"
    assert [str(v) for v in violations() if v.rule == rule] == []
