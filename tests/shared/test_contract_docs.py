"""The contract tables of the docs agree with the code's declarations.

README.md ("Message contract") and docs/message-contract.md ("Topics") carry the same table.
Each row is checked against ``shared.keys.TOPIC_TYPES`` (the keys), the message registry (the
message, its fields and its QoS) and the ``PORTS`` every service declares
(``shared.service.contract_rows``): a service that publishes or subscribes to a key is named
in that column, and a service named there declares it. Free text beside the names (a
"localiser", "tests", "operator") is allowed; "any service" / "every service" covers all.
"""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from services.launcher.up import Launcher
from services.lidar_driver.service import LidarService
from services.localization_bridge.service import BridgeService
from services.planner.service import PlannerShell
from services.router.service import Router
from services.simulator.service import SimulatorService
from services.telemetry.service import TelemetryService
from services.vesc_driver.service import VescService
from shared.keys import ALIVE, TOPIC_TYPES
from shared.messages import REGISTRY
from shared.service import Service, contract_rows

ROOT = Path(__file__).resolve().parents[2]
#: Everyone on the bus: the six services and the launcher.
PARTICIPANTS: tuple[type[Service], ...] = (
    SimulatorService,
    BridgeService,
    PlannerShell,
    VescService,
    TelemetryService,
    Router,
    Launcher,
    LidarService,
)
ALIVE_ROW = f"{ALIVE}/<service>"
COLUMNS = ("key", "message", "fields", "rate", "qos", "publishers", "subscribers")
_ANYONE = re.compile(r"\b(any|every) service\b")


def contract_table(path: Path, heading: str) -> dict[str, dict[str, str]]:
    """The rows of the first table after `heading` in `path`: key -> column -> cell."""
    text = path.read_text(encoding="utf-8")
    start = text.index(heading)
    rows: dict[str, dict[str, str]] = {}
    for line in text[start:].splitlines():
        if line.startswith("| `"):
            cells = [c.strip() for c in line.strip().strip("|").split("|")]
            assert len(cells) == len(COLUMNS), f"{path.name}: {line}"
            key = cells[0].strip("`")
            rows[key] = dict(zip(COLUMNS, cells, strict=True))
        elif rows and not line.startswith("|"):
            break
    return rows


TABLES = {
    "README.md": contract_table(ROOT / "README.md", "## Message contract"),
    "docs/message-contract.md": contract_table(ROOT / "docs/message-contract.md", "## Topics"),
}


def _named(cell: str, service: str) -> bool:
    """Whether a table cell names `service` ("vesc_driver" reads "VESC driver")."""
    words = service.replace("_", " ")
    return re.search(rf"\b{re.escape(words)}\b", cell, re.IGNORECASE) is not None


def test_both_tables_are_the_same() -> None:
    readme, doc = TABLES.values()
    assert readme == doc


@pytest.mark.parametrize("doc", TABLES)
def test_every_key_has_one_row_with_its_message_fields_and_qos(doc: str) -> None:
    table = TABLES[doc]
    assert set(table) == {*TOPIC_TYPES, ALIVE_ROW}, f"{doc}: rows differ from shared.keys"
    for suffix, tag in TOPIC_TYPES.items():
        row, cls = table[suffix], REGISTRY[tag]
        assert row["message"] == f"`{cls.__name__}`", f"{doc} {suffix}"
        assert row["qos"] == ("BLOCK" if cls.RELIABLE else "DROP"), f"{doc} {suffix}: QoS"
        own = {f.name for f in cls.fields_info()} - {"stamp_s", "seq"}
        listed = set(re.findall(r"`(\w+)`", row["fields"]))
        assert listed <= own, f"{doc} {suffix}: not fields of {cls.__name__}: {listed - own}"
        if "..." not in row["fields"]:
            assert listed == own, f"{doc} {suffix}: fields missing: {own - listed}"


@pytest.mark.parametrize("doc", TABLES)
def test_publishers_and_subscribers_match_the_declared_ports(doc: str) -> None:
    table = TABLES[doc]
    problems = []
    for suffix, declared in contract_rows(PARTICIPANTS).items():
        for column, names in (
            ("publishers", declared.publishers),
            ("subscribers", declared.subscribers),
        ):
            cell = table[suffix][column]
            for name in names:  # declared -> named
                if not (_named(cell, name) or _ANYONE.search(cell)):
                    problems.append(f"{suffix}: {name} declares it but is not in {column}")
            for svc in PARTICIPANTS:  # named -> declared
                if _named(cell, svc.NAME) and svc.NAME not in names:
                    problems.append(f"{suffix}: {column} names {svc.NAME}, not declared there")
    assert not problems, f"{doc}:\n" + "\n".join(problems)


def test_every_port_is_a_key_of_the_contract_with_its_type() -> None:
    for svc in PARTICIPANTS:
        for port in svc.PORTS:
            assert REGISTRY[TOPIC_TYPES[port.suffix]] is port.msg_type, (svc.NAME, port)
