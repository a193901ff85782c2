"""The contract tables of the docs agree with the code's declarations.

README.md ("Message contract") and docs/message-contract.md ("Topics") carry the same table.
Each row is checked against ``shared.keys.TOPIC_TYPES`` (the keys), the message registry (the
message, its fields and its QoS) and the ``PORTS`` every service declares
(``shared.service.contract_rows``): a service that publishes or subscribes to a key is named
in that column, and a service named there declares it. Free text beside the names (a
"localiser", "tests", "operator") is allowed; "any service" / "every service" covers all.
"""

from __future__ import annotations

import importlib
import re
from pathlib import Path

import pytest

from services.tools.launcher.up import Launcher
from shared.keys import ALIVE, TOPIC_TYPES
from shared.messages import REGISTRY
from shared.roster import ROSTER, Process
from shared.service import Service, contract_rows

ROOT = Path(__file__).resolve().parents[2]


def service_class(process: Process) -> type[Service]:
    """The ``Service`` subclass of a roster entry: the one in ``services.<name>.service``
    whose ``NAME`` is the entry's name."""
    module = importlib.import_module(f"{process.module}.service")
    (cls,) = {
        v for v in vars(module).values()
        if isinstance(v, type) and issubclass(v, Service) and v.NAME == process.name
    }
    return cls


#: Everyone on the bus: every process service of the roster and the launcher.
PARTICIPANTS: tuple[type[Service], ...] = (*(service_class(p) for p in ROSTER), Launcher)
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


# --------------------------------------------------------------------------- validation limits
def _validation_rows() -> list[str]:
    """The rows of the "Quantity | Rule" table under "## Validation" of the contract doc."""
    text = (ROOT / "docs/message-contract.md").read_text(encoding="utf-8")
    lines = text[text.index("## Validation"):].splitlines()
    start = next(i for i, line in enumerate(lines) if line.startswith("| Quantity"))
    rows = []
    for line in lines[start + 2:]:
        if not line.startswith("|"):
            break
        rows.append(line)
    return rows


def _spellings(value: float) -> set[str]:
    """How the docs may write the limit |value|: 1000, 1,000, 1e3, 2^31, 4 MiB, pi, 2 pi."""
    import math

    a = abs(float(value))
    out = {name for k, name in ((1, "pi"), (2, "2 pi")) if math.isclose(a, k * math.pi)}
    if a.is_integer():
        n = int(a)
        out |= {str(n), f"{n:,}"}
        if n >= 10 and 10 ** round(math.log10(n)) == n:
            out.add(f"1e{round(math.log10(n))}")
        for m in (n, n + 1):
            if m > 2 and m & (m - 1) == 0:
                out.add(f"2^{m.bit_length() - 1}")
        if n >= 1 << 20 and n % (1 << 20) == 0:
            out.add(f"{n >> 20} MiB")
    elif not out:
        out.add(f"{a:g}")
    return out


def _mentions(row: str, value: float) -> bool:
    return any(re.search(rf"(?<![\d.,^]){re.escape(s)}(?![\d.]|,\d|e\d)", row)
               for s in _spellings(value))


def _field_limits() -> list[tuple[str, str, float]]:
    """(message, field, limit) of every numeric bound a record field declares: the upper
    bound, a lower bound that is neither 0 nor minus the upper one, string and array
    lengths, array value bounds."""
    import math

    out: list[tuple[str, str, float]] = []
    for cls in REGISTRY.values():
        for f in cls.fields_info():
            bounds: list[float] = []
            t = f.type
            le, ge = getattr(t, "le", None), getattr(t, "ge", None)
            if le is not None:
                bounds.append(le)
            if ge is not None and ge != 0 and (le is None or ge != -le):
                bounds.append(ge)
            if getattr(t, "max_length", None) is not None:
                bounds.append(t.max_length)
            if f.array is not None:
                bounds.append(f.array.max_len)
                bounds += [b for b in (f.array.lo, f.array.hi) if b and math.isfinite(b)]
            out += [(cls.__name__, f.name, b) for b in bounds]
    return out


def test_every_field_limit_is_in_the_validation_table() -> None:
    rows = _validation_rows()
    missing = [
        f"{msg}.{name}: {limit:g}"
        for msg, name, limit in _field_limits()
        if not any(f"`{name}`" in row and _mentions(row, limit) for row in rows)
    ]
    assert not missing, "docs/message-contract.md Validation table lacks:\n" + "\n".join(missing)


def test_every_max_constant_is_in_the_validation_table() -> None:
    """Each ``MAX_*`` limit of the records and the codec is named, with its value."""
    from shared.messages import codec, records

    rows = _validation_rows()
    missing = []
    for module in (records, codec):
        for name in dir(module):
            value = getattr(module, name)
            if not name.startswith("MAX_") or not isinstance(value, int | float):
                continue
            if not any(f"`{name}`" in row and _mentions(row, value) for row in rows):
                missing.append(f"{module.__name__}.{name} = {value}")
    assert not missing, "docs/message-contract.md Validation table lacks:\n" + "\n".join(missing)
