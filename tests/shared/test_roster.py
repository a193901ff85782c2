"""The roster (``shared.roster``) is the one list of process services, and everything that
lists them agrees with it: the folders under ``services/``, each service's ``NAME``, the cli's
``racestack run`` choices, the services ``racestack up`` starts, the secure profile's
identities and ``docker-compose.yml``."""

from __future__ import annotations

import importlib
import json
import re
from pathlib import Path

import yaml

from services.tools import cli
from services.tools.launcher.up import STACK, UpOptions
from shared import roster
from shared.roster import ROSTER, Process
from shared.security.identities import HUB_IDENTITY, IDENTITIES, OTHER_IDENTITIES
from shared.service import Service

ROOT = Path(__file__).resolve().parents[2]


def test_every_process_folder_is_in_the_roster_and_back() -> None:
    """A process service is a folder ``services/<name>/`` with a ``__main__.py``
    (``services/tools/`` holds the tools, not processes)."""
    folders = {
        p.parent.name for p in (ROOT / "services").glob("*/__main__.py") if p.parent.name != "tools"
    }
    assert folders == set(roster.names())
    assert len(set(roster.names())) == len(ROSTER)


def test_each_entry_is_a_service_of_that_name() -> None:
    for p in ROSTER:
        assert p.module == f"services.{p.name}"
        module = importlib.import_module(f"{p.module}.service")
        classes = [
            v for v in vars(module).values()
            if isinstance(v, type) and issubclass(v, Service) and v.NAME == p.name
        ]
        assert len(classes) == 1, p.name
        assert p.identity == classes[0].NAME  # a service's identity is its NAME


def test_the_roster_helpers() -> None:
    assert roster.hub() == roster.process("router") and roster.hub().hub
    assert [p.name for p in ROSTER if p.hub] == ["router"]
    assert not roster.hub().up  # `up` hosts the hub itself (plain) or starts it first (mtls)
    assert roster.up_names() == ("simulator", "localization_bridge", "planner", "telemetry")
    assert Process("x", up=False, identity="y").identity == "y"
    try:
        roster.process("nobody")
    except KeyError as exc:
        assert "nobody" in str(exc)
    else:
        raise AssertionError("no KeyError")


def test_the_cli_the_launcher_and_the_identities_read_the_roster() -> None:
    assert cli.SERVICES == roster.names()
    run = next(a for a in cli.build_parser()._actions if getattr(a, "choices", None)
               and "run" in a.choices)
    choices = next(a for a in run.choices["run"]._actions if a.dest == "service").choices
    assert tuple(choices) == roster.names()
    assert STACK == roster.up_names() and UpOptions(None).services == STACK
    assert IDENTITIES == (*(p.identity for p in ROSTER), *OTHER_IDENTITIES)
    assert HUB_IDENTITY == roster.hub().identity
    assert len(set(IDENTITIES)) == len(IDENTITIES)


# --------------------------------------------------------------------------- docker-compose.yml
def _entrypoint() -> list[str]:
    """The image's ENTRYPOINT (the Dockerfile's exec form)."""
    text = (ROOT / "Dockerfile").read_text(encoding="utf-8")
    (line,) = re.findall(r"^ENTRYPOINT\s+(.*)$", text, re.MULTILINE)
    return json.loads(line)


def compose_problems(compose: dict, entrypoint: list[str]) -> list[str]:
    """What in a parsed compose file disagrees with the roster: a service that does not run
    ``python -m services.<its name>`` of a roster entry, a roster entry ``up`` starts (or the
    hub) that is missing."""
    problems = []
    services = compose.get("services") or {}
    known = set(roster.names())
    for key, svc in services.items():
        argv = [*(svc.get("entrypoint") or entrypoint), *(svc.get("command") or [])]
        if key not in known:
            problems.append(f"{key}: not a process service of the roster ({', '.join(known)})")
            continue
        want = ["python", "-m", roster.process(key).module]
        if argv[:3] != want:
            problems.append(f"{key}: runs {' '.join(argv)!r}, not {' '.join(want)} ...")
    for p in ROSTER:
        if (p.up or p.hub) and p.name not in services:
            problems.append(f"{p.name}: `racestack up` runs it, the compose file does not")
    return problems


def test_docker_compose_runs_the_roster() -> None:
    compose = yaml.safe_load((ROOT / "docker-compose.yml").read_text(encoding="utf-8"))
    assert _entrypoint() == ["python", "-m"]
    assert compose_problems(compose, _entrypoint()) == []
    for p in ROSTER:  # the stack's services all read the mounted configuration
        if p.name in compose["services"]:
            command = compose["services"][p.name]["command"]
            assert command[1:3] == ["--config", "/config/racestack.toml"], p.name


def test_compose_problems_are_named() -> None:
    bad = {
        "services": {
            "router": {"command": ["services.router"]},
            "planner": {"command": ["services.simulator"]},  # the wrong module
            "mapper": {"command": ["services.mapper"]},  # not in the roster
            "telemetry": {"entrypoint": ["sh", "-c"], "command": ["services.telemetry"]},
        }
    }
    got = compose_problems(bad, ["python", "-m"])
    assert any(line.startswith("planner: runs") for line in got)
    assert any(line.startswith("mapper: not a process") for line in got)
    assert any(line.startswith("telemetry: runs") for line in got)
    missing = sorted(line.split(":")[0] for line in got if "the compose file does not" in line)
    assert missing == ["localization_bridge", "simulator"]
