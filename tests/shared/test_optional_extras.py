"""The optional extras (``shared.extras``, pyproject's ``[tools]`` and ``[ros2]``): the stack
runs without them, and a command that needs one says which in one line (exit code 2).

The subprocess tests put a ``sitecustomize`` on ``PYTHONPATH`` whose meta-path finder makes
``import optuna``, ``matplotlib``, ``skimage`` and ``rosbags`` fail as if they were not
installed; every child process the launcher starts inherits it.
"""

from __future__ import annotations

import os
import re
import subprocess
import sys
import tomllib
from pathlib import Path

import pytest

from shared import roster
from shared.extras import EXTRAS, MissingExtraError, missing_extra, require

ROOT = Path(__file__).resolve().parents[2]
#: The libraries of the extras, by distribution name (as pyproject lists them).
TOOL_ONLY = ("optuna", "matplotlib", "scikit-image", "rosbags", "psycopg2-binary")
BLOCKED = ("optuna", "matplotlib", "skimage", "rosbags")

BLOCKER = f'''
import importlib.abc
import sys

BLOCKED = {BLOCKED!r}


class _Blocker(importlib.abc.MetaPathFinder):
    """Finds the blocked libraries nowhere (as if they were not installed)."""

    def find_spec(self, name, path=None, target=None):
        if name.partition(".")[0] in BLOCKED:
            raise ModuleNotFoundError(f"No module named {{name!r}}", name=name)
        return None


sys.meta_path.insert(0, _Blocker())
'''


def _requirement_names(reqs: list[str]) -> set[str]:
    return {re.split(r"[<>=!~\[; ]", r, maxsplit=1)[0].lower() for r in reqs}


def test_the_core_dependencies_hold_no_tool_only_library() -> None:
    data = tomllib.loads((ROOT / "pyproject.toml").read_text(encoding="utf-8"))
    core = _requirement_names(data["project"]["dependencies"])
    assert not core & set(TOOL_ONLY), core & set(TOOL_ONLY)
    extras = data["project"]["optional-dependencies"]
    # psycopg2-binary: Optuna's PostgreSQL storage for several tuning workers (racestack tune)
    assert _requirement_names(extras["tools"]) == {"optuna", "matplotlib", "scikit-image",
                                                   "psycopg2-binary"}
    assert _requirement_names(extras["ros2"]) == {"rosbags"}
    for library, (distribution, extra) in EXTRAS.items():  # the messages name real extras
        if library != "scipy":  # scipy comes with scikit-image
            assert distribution in _requirement_names(extras[extra]), library
    make = (ROOT / "Makefile").read_text(encoding="utf-8")
    assert "-e '.[dev,tools,ros2]'" in make  # make test installs what the tests import


def test_require_and_missing_extra(monkeypatch: pytest.MonkeyPatch) -> None:
    require("json")  # present: nothing happens
    monkeypatch.setitem(EXTRAS, "no_such_library_xyz", ("no-such-library", "tools"))
    with pytest.raises(MissingExtraError) as exc:
        require("no_such_library_xyz")
    assert str(exc.value) == "needs no-such-library: pip install -e '.[tools]'"
    got = missing_extra(ModuleNotFoundError("No module named 'optuna.trial'", name="optuna.trial"))
    assert got is not None and got.extra == "tools" and got.distribution == "optuna"
    assert missing_extra(ModuleNotFoundError("x", name="numpy")) is None
    assert missing_extra(ValueError("x")) is None


def _blocked_env(tmp_path: Path) -> dict[str, str]:
    """The environment of a child with the blocker installed (its ``sitecustomize`` first on
    ``PYTHONPATH``, then this repository)."""
    site = tmp_path / "site"
    site.mkdir(exist_ok=True)
    (site / "sitecustomize.py").write_text(BLOCKER, encoding="utf-8")
    path = [str(site), str(ROOT), *filter(None, [os.environ.get("PYTHONPATH")])]
    return {**os.environ, "PYTHONPATH": os.pathsep.join(path)}


def _blocked_python(code: str, tmp_path: Path) -> subprocess.CompletedProcess[str]:
    """Run `code` in a fresh interpreter with the blocker installed (cwd: the repository)."""
    return subprocess.run([sys.executable, "-c", code], cwd=ROOT, env=_blocked_env(tmp_path),
                          text=True, capture_output=True, timeout=120.0)


def test_the_blocker_blocks(tmp_path: Path) -> None:
    code = "".join(f"""
try:
    import {lib}
except ModuleNotFoundError as exc:
    print(exc.name)
""" for lib in BLOCKED)
    got = _blocked_python(code, tmp_path)
    assert got.stdout.split() == list(BLOCKED), got.stderr


def test_every_process_the_cli_and_the_launcher_import_without_the_extras(
    tmp_path: Path,
) -> None:
    modules = [f"{p.module}.service" for p in roster.ROSTER]
    code = f"""
import importlib, sys
for name in {modules!r} + ["services.tools.cli", "services.tools.launcher",
                           "services.tools.launcher.up", "services.tools.launcher.secure"]:
    importlib.import_module(name)
from services.tools import cli
cli.build_parser()
leaked = sorted(m for m in sys.modules if m.partition(".")[0] in {BLOCKED!r})
print("ok", leaked)
"""
    got = _blocked_python(code, tmp_path)
    assert got.returncode == 0 and got.stdout.strip() == "ok []", got.stderr


#: racestack commands that need an extra, and the one line each prints without it.
COMMANDS = {
    "tune": (["tune", "--method", "cimpcc", "--track", "paperlike", "--trials", "1",
              "--out", "{tmp}/tune"], "racestack tune: needs optuna: pip install -e '.[tools]'"),
    "bench": (["bench", "--out", "{tmp}/bench"],
              "racestack bench: needs matplotlib: pip install -e '.[tools]'"),
    "mintime": (["mintime", "--track", "paperlike", "--out", "{tmp}/mintime"],
                "racestack mintime: needs matplotlib: pip install -e '.[tools]'"),
    "track": (["track", "--from-map", "{tmp}/map.yaml", "--out", "{tmp}/track"],
              "racestack track: needs scikit-image: pip install -e '.[tools]'"),
    "report": (["report", "{tmp}/run.rrd"],
               "racestack report: needs matplotlib: pip install -e '.[tools]'"),
}


def test_each_command_that_needs_an_extra_says_which_in_one_line(tmp_path: Path) -> None:
    calls = {name: [a.format(tmp=tmp_path) for a in argv] for name, (argv, _) in COMMANDS.items()}
    code = f"""
import contextlib, io, json
from services.tools import cli
out = {{}}
for name, argv in {calls!r}.items():
    err = io.StringIO()
    with contextlib.redirect_stderr(err), contextlib.redirect_stdout(err):
        code = cli.main(argv)
    out[name] = [code, err.getvalue()]
print(json.dumps(out))
"""
    got = _blocked_python(code, tmp_path)
    assert got.returncode == 0, got.stderr
    import json

    results = json.loads(got.stdout.strip().splitlines()[-1])
    for name, (_, line) in COMMANDS.items():
        code, text = results[name]
        assert (code, text) == (2, line + "\n"), name
    assert not (tmp_path / "tune").exists()  # nothing started, no folder made


def test_the_ros2_gateway_without_rosbags_says_so_in_one_line(tmp_path: Path) -> None:
    line = "ros2_gateway: error: needs rosbags: pip install -e '.[ros2]'"
    for code in (
        "import sys\nfrom services.ros2_gateway.service import main\nsys.exit(main([]))\n",
        "import sys\nfrom services.tools.cli import main\n"
        "sys.exit(main(['run', 'ros2_gateway']))\n",
    ):
        got = _blocked_python(code, tmp_path)
        assert got.returncode == 2, got.stderr
        assert got.stderr == line + "\n" and got.stdout == "", got.stderr


@pytest.mark.slow
def test_racestack_up_races_without_the_extras(tmp_path: Path) -> None:
    """``racestack up`` (the demo) and every child it starts, with the extras blocked."""
    from services.tools.launcher.supervisor import stop_process
    from shared.net import free_loopback_port

    cfg = tmp_path / "up.toml"
    cfg.write_text(f'[bus]\nlisten = ["tcp/127.0.0.1:{free_loopback_port()}"]\n')
    xdg = str(tmp_path / "xdg")
    env = {**_blocked_env(tmp_path), "XDG_CONFIG_HOME": xdg, "XDG_DATA_HOME": xdg}
    argv = ["up", "--laps", "1", "--config", str(cfg), "--run-dir", str(tmp_path / "run")]
    proc = subprocess.Popen([sys.executable, "-m", "services.tools.cli", *argv], cwd=ROOT,
                            env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    try:
        out, _ = proc.communicate(timeout=240)
    finally:
        stop_process(proc, grace_s=20.0)
    assert proc.returncode == 0, out
    assert "completed laps         1/1" in out, out
    for p in roster.ROSTER:
        if p.up:
            log = (tmp_path / "run" / "logs" / f"{p.name}.log").read_text(errors="replace")
            assert "ModuleNotFoundError" not in log, p.name
