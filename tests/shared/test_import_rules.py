"""The layers' import rules, checked by walking every import of the source tree (ast).

The units: ``shared/`` (the layer below everything); the process services, one folder
``services/<name>/`` per entry of the roster (``shared.roster``); the tools,
``services/tools/<tool>/`` or ``services/tools/<tool>.py``.

1. ``shared/`` imports nothing from ``services/``.
2. A process service imports no other service and no tool: processes meet only on the bus.
3. A tool uses only a process service's public API, the names its
   ``services/<name>/__init__.py`` lists in ``__all__`` (the planner's is
   ``services/planner/__init__.py``): never an inner module such as
   ``services.planner.mpc.planner``.
4. The tools form a one-way chain (``TOOL_ORDER``, top to bottom): a tool imports only tools
   on a lower level, none on its own or a higher one, so no circle among tools can close.
5. Only the bus's session modules (``shared/bus/session*.py``) import zenoh.
6. Every folder under ``services/`` is a process of the roster or ``tools``, and every tool is
   in ``TOOL_ORDER``.

Every violation is named (file:line, what it imports, which rule). ``KNOWN`` lists the ones
that need files owned by others right now, each with the follow-up that removes it; an entry
that no longer occurs fails the test too, so the list only shrinks.
"""

from __future__ import annotations

import ast
import re
from collections.abc import Iterable, Iterator
from dataclasses import dataclass
from pathlib import Path

from shared import roster

ROOT = Path(__file__).resolve().parents[2]
#: Services that run as their own process: the roster's.
PROCESS_SERVICES = frozenset(roster.names())
#: The tools from top to bottom: a tool may import only tools on a later level (rule 4).
TOOL_ORDER: tuple[frozenset[str], ...] = (
    frozenset({"cli"}),
    frozenset({"launcher"}),
    frozenset({"tune"}),
    frozenset({"bench"}),
    frozenset({"sysid"}),
    frozenset({"sysid_drive"}),
    frozenset({"mintime", "report", "track", "certs", "config_reference"}),
)
#: Which modules may import zenoh (rule 5): the bus package's session modules.
ZENOH_MODULES = re.compile(r"shared/bus/session[^/]*\.py")

#: Violations that need files owned by others, as "importer -> imported" (no line numbers,
#: so unrelated edits do not break the list). Remove an entry when its follow-up lands.
KNOWN: frozenset[str] = frozenset()


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


def _unit(rel: Path) -> tuple[str, str] | None:
    """(kind, name) of the unit a file belongs to: ("shared", ""), ("process", name),
    ("tool", name), ("unknown", folder); None for ``services/__init__.py`` and
    ``services/tools/__init__.py``."""
    parts = rel.parts
    if parts[0] == "shared":
        return "shared", ""
    if len(parts) == 2:
        return None if parts[1] == "__init__.py" else ("unknown", parts[1])
    if parts[1] == "tools":
        if len(parts) == 3 and parts[2] == "__init__.py":
            return None
        return "tool", parts[2].removesuffix(".py")
    return ("process" if parts[1] in PROCESS_SERVICES else "unknown"), parts[1]


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


def tool_level(tool: str) -> int | None:
    """The level of `tool` in ``TOOL_ORDER`` (0 = the top), None when it is not listed."""
    return next((i for i, level in enumerate(TOOL_ORDER) if tool in level), None)


def _targets(module: str, names: list[str]) -> Iterator[tuple[str, list[str]]]:
    """(module, names) of what an import reaches in ``services``: ``from services import
    planner`` and ``from services.tools import bench`` reach ``services.planner`` and
    ``services.tools.bench``."""
    if module in ("services", "services.tools") and names:
        for name in names:
            yield f"{module}.{name}", []
    else:
        yield module, names


def _check(
    rel: Path, line: int, module: str, names: list[str], unit: tuple[str, str]
) -> Iterator[Violation]:
    """The violations of one import `module` (names `names`) by a file of `unit`."""
    path = rel.as_posix()
    kind, own = unit
    head = module.split(".")
    if head[0] == "zenoh" and not ZENOH_MODULES.fullmatch(path):
        yield Violation(path, line, module, "zenoh outside shared/bus/session*.py")
    if head[0] != "services" or len(head) < 2:
        return
    if kind == "shared":
        yield Violation(path, line, module, "shared imports services")
        return
    is_tool = head[1] == "tools"
    if is_tool and len(head) < 3:
        return  # the namespace ``services.tools`` itself (names expanded by _targets)
    target = head[2] if is_tool else head[1]
    if kind == "process":
        if is_tool:
            yield Violation(path, line, module, "a process service imports a tool")
        elif target != own:
            yield Violation(path, line, module, "a process service imports another service")
        else:
            yield from _check_room(path, line, head)
        return
    if kind != "tool":
        return  # an unknown unit is reported once by rule 6
    if not is_tool:
        if len(head) > 2:
            yield Violation(path, line, module, "a tool imports an inner module")
            return
        api = public_api(target)
        for name in names:
            if name not in api:
                yield Violation(path, line, f"{module}.{name}", f"not in services.{target}.__all__")
        return
    if target == own:
        return
    mine, theirs = tool_level(own), tool_level(target)
    if theirs is None:
        yield Violation(path, line, module, f"tool {target} is not in TOOL_ORDER")
    elif mine is not None and theirs <= mine:
        rule = f"tool {own} imports tool {target}, not below it in TOOL_ORDER (one-way chain)"
        yield Violation(path, line, module, rule)


#: The planner's rooms (``services/planner/<room>/``) and the rooms each may import: the
#: minimum-time OCP is the offline optimiser (it imports no other room); the MPC methods and
#: the raceline read its artefact, never each other. Modules at the planner's top level
#: (interface, recovery, reference, cache, registry, service) compose the rooms.
PLANNER_ROOMS: dict[str, frozenset[str]] = {
    "mintime": frozenset(),
    "mpc": frozenset({"mintime"}),
    "raceline": frozenset({"mintime"}),
}
#: Top-level planner modules the rooms may use (the planner-wide types and helpers).
PLANNER_COMMON = frozenset({"interface", "recovery", "reference", "cache", "opponents"})


def _check_room(path: str, line: int, head: list[str]) -> Iterator[Violation]:
    """Rule 7: a planner room imports only the rooms ``PLANNER_ROOMS`` allows it and the
    planner's common modules."""
    parts = path.split("/")
    if parts[:2] != ["services", "planner"] or len(parts) < 4 or head[:2] != [
        "services", "planner"
    ] or len(head) < 3:
        return
    room = parts[2]
    if room not in PLANNER_ROOMS:
        return
    target = head[2]
    if target == room or target in PLANNER_ROOMS[room]:
        return
    if target in PLANNER_COMMON and not (room == "mintime" and target != "cache"):
        return
    yield Violation(path, line, ".".join(head), f"planner room {room} imports {target}")


def source_files() -> list[tuple[Path, str]]:
    """(path relative to the repository, text) of every module in services/ and shared/."""
    paths = sorted([*ROOT.glob("services/**/*.py"), *ROOT.glob("shared/**/*.py")])
    return [(p.relative_to(ROOT), p.read_text(encoding="utf-8")) for p in paths]


def violations(files: Iterable[tuple[Path, str]] | None = None) -> list[Violation]:
    """Every import in `files` (default: services/ and shared/) that breaks a rule of the
    module docstring, plus a unit that is neither a roster process nor a listed tool."""
    found: list[Violation] = []
    unknown: set[str] = set()
    for rel, text in source_files() if files is None else files:
        unit = _unit(rel)
        if unit is None:
            continue
        kind, name = unit
        if kind == "unknown" and name not in unknown:
            unknown.add(name)
            rule = f"services/{name} is no process of shared.roster and no tool"
            found.append(Violation(rel.as_posix(), 0, "", rule))
        if kind == "tool" and tool_level(name) is None and name not in unknown:
            unknown.add(name)
            found.append(Violation(rel.as_posix(), 0, "", f"tool {name} is not in TOOL_ORDER"))
        tree = ast.parse(text, filename=str(rel))
        for line, imported, names in _imports(tree, rel):
            for module, reached in _targets(imported, names):
                found.extend(_check(rel, line, module, reached, unit))
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
    assert "make_planner" in public_api("planner")  # services/planner/__init__.py
    assert public_api("no_such_service") == frozenset()  # no __init__: no public API


def test_the_units_of_the_layout() -> None:
    assert _unit(Path("shared/bus.py")) == ("shared", "")
    assert _unit(Path("services/planner/mpc/planner.py")) == ("process", "planner")
    assert _unit(Path("services/tools/cli.py")) == ("tool", "cli")
    assert _unit(Path("services/tools/bench/run.py")) == ("tool", "bench")
    assert _unit(Path("services/mapper/core.py")) == ("unknown", "mapper")
    assert _unit(Path("services/__init__.py")) is None


def test_crafted_sources_with_a_tool_circle_and_a_process_importing_a_tool() -> None:
    files = [
        # a circle: launcher imports cli (above it), cli imports launcher (below: fine)
        (Path("services/tools/launcher/x.py"), "from services.tools.cli import main\n"),
        (Path("services/tools/cli.py"), "from services.tools.launcher import run_up\n"),
        # a circle within one level: report and track import each other
        (Path("services/tools/report.py"), "import services.tools.track\n"),
        (Path("services/tools/track.py"), "from services.tools import report\n"),
        # a process importing a tool, and another process
        (Path("services/planner/x.py"), "from services.tools.bench import race\n"),
        (Path("services/planner/y.py"), "import services.simulator\n"),
        # a tool reaching inside a process, and a name outside its __all__
        (Path("services/tools/bench/x.py"), "from services.planner.mpc import planner\n"
                                             "from services.simulator import _private\n"),
        # shared importing a service; zenoh outside the bus's session modules
        (Path("shared/x.py"), "from services.planner import Planner\n"),
        (Path("services/router/x.py"), "import zenoh\n"),
        (Path("shared/bus/session_tls.py"), "import zenoh\n"),  # allowed
        (Path("services/mapper/x.py"), "x = 1\n"),  # no roster entry
        (Path("services/tools/newtool.py"), "x = 1\n"),  # not in TOOL_ORDER
    ]
    got = {(v.path, v.imported, v.rule.split(",")[0]) for v in violations(files)}
    assert got == {
        ("services/tools/launcher/x.py", "services.tools.cli",
         "tool launcher imports tool cli"),
        ("services/tools/report.py", "services.tools.track", "tool report imports tool track"),
        ("services/tools/track.py", "services.tools.report", "tool track imports tool report"),
        ("services/planner/x.py", "services.tools.bench", "a process service imports a tool"),
        ("services/planner/y.py", "services.simulator",
         "a process service imports another service"),
        ("services/tools/bench/x.py", "services.planner.mpc", "a tool imports an inner module"),
        ("services/tools/bench/x.py", "services.simulator._private",
         "not in services.simulator.__all__"),
        ("shared/x.py", "services.planner", "shared imports services"),
        ("services/router/x.py", "zenoh", "zenoh outside shared/bus/session*.py"),
        ("services/mapper/x.py", "", "services/mapper is no process of shared.roster and no tool"),
        ("services/tools/newtool.py", "", "tool newtool is not in TOOL_ORDER"),
    }


def test_every_tool_on_disk_is_in_the_order_once() -> None:
    tools = {
        p.name.removesuffix(".py")
        for p in (ROOT / "services" / "tools").iterdir()
        if (p.suffix == ".py" and p.name != "__init__.py") or (p / "__init__.py").is_file()
    }
    listed = [t for level in TOOL_ORDER for t in level]
    assert len(listed) == len(set(listed))
    assert tools == set(listed)


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
    """No known exception for rule 2: a process service never imports another or a tool."""
    rules = ("a process service imports another service", "a process service imports a tool")
    assert [str(v) for v in violations() if v.rule in rules] == []


def test_planner_rooms_keep_to_themselves() -> None:
    """Rule 7 on crafted sources: the offline OCP imports no online room; the MPC and the
    raceline read the OCP's artefact but not each other."""
    files = [
        (Path("services/planner/mintime/x.py"), "from services.planner.mpc import planner\n"),
        (Path("services/planner/mpc/x.py"), "import services.planner.raceline.tracker\n"),
        (Path("services/planner/raceline/x.py"), "from services.planner.mintime.store import f\n"),
        (Path("services/planner/mpc/y.py"), "from services.planner.interface import SOLVED\n"),
    ]
    rules = sorted(v.rule for v in violations(files))
    assert rules == ["planner room mintime imports mpc", "planner room mpc imports raceline"]
