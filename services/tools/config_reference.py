"""The configuration reference (``docs/configuration.md``), generated from the models.

Every key of ``RacestackConfig`` (walked recursively, so new keys appear by themselves) with
its TOML path, type, unit, default, allowed range and what it does. The text of a key is its
``Field(description=...)``, else its entry in the ``Attributes:`` list of its section's
docstring. The unit is the ``[unit]`` in that text, else the one its name ends in
(``_s`` -> s, ``_mps`` -> m/s, ...; see ``UNIT_SUFFIXES``).

Regenerate with::

    .venv/bin/python -m services.tools.config_reference > docs/configuration.md

(``tests/shared/test_config_reference.py`` fails when the committed file is not current.)
"""

from __future__ import annotations

import argparse
import inspect
import re
import sys
import types
import typing
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal, Union, get_args, get_origin

import annotated_types as at
from pydantic import BaseModel
from pydantic.fields import FieldInfo
from pydantic_core import PydanticUndefined

from shared.config.base import Choices
from shared.config.root import RacestackConfig
from shared.config.toml_write import value as toml_value

__all__ = ["UNIT_SUFFIXES", "KeyDoc", "iter_keys", "main", "render_markdown"]

#: Name endings -> unit, longest first where one ends another.
UNIT_SUFFIXES: tuple[tuple[str, str], ...] = (
    ("_mps2", "m/s^2"), ("_mps", "m/s"), ("_radps", "rad/s"), ("_radpm", "1/m"),
    ("_per_rad", "1/rad"), ("_per_s2", "1/s^2"), ("_per_s", "1/s"), ("_kgm2", "kg m^2"),
    ("_kg", "kg"), ("_m2", "m^2"), ("_ms", "ms"), ("_mb", "MB"), ("_hz", "Hz"),
    ("_rad", "rad"), ("_deg", "deg"), ("_s", "s"), ("_m", "m"), ("_a", "A"), ("_v", "V"),
    ("_bytes", "bytes"), ("_rts", "per sqrt(s)"),
)
_UNIT_IN_TEXT = re.compile(r"\[([^\[\]]{1,24})\]")
#: The words a ``[unit]`` in a description may be made of (anything else in brackets, such
#: as ``[ros2]`` or ``[A-Za-z]``, is not a unit).
_UNIT_WORDS = frozenset(
    "m s rad Hz kg A V ms us deg bit bits MB KB bytes byte of arc messages cells px N Nm W "
    "sqrt per samples scans beams steps points".split()
)


def _looks_like_unit(text: str) -> bool:
    words = re.findall(r"[A-Za-z]+", text)
    if not words or not re.fullmatch(r"[A-Za-z0-9 ^/*()\-.]+", text):
        return False
    return all(w in _UNIT_WORDS for w in words) and not re.search(r"[A-Za-z]-[A-Za-z]", text)
GENERATOR = ".venv/bin/python -m services.tools.config_reference > docs/configuration.md"


@dataclass(frozen=True)
class KeyDoc:
    """One documented key.

    Attributes:
        path: dotted TOML path (``planner.solver.max_iter``; ``<name>`` for a table key,
            ``[]`` for an array of tables).
        type: the TOML type (``float``, ``string``, ``array of 2 float``, ...).
        unit: the unit, or "" when the key has none.
        default: the default as TOML text, ``(required)`` when there is none.
        range: allowed values (bounds, choices, lengths), or "".
        description: what the key does.
    """

    path: str
    type: str
    unit: str
    default: str
    range: str
    description: str


@dataclass(frozen=True)
class SectionDoc:
    """A table of the configuration: its TOML header, its text and its keys."""

    path: str
    text: str
    keys: tuple[KeyDoc, ...]


# ---------------------------------------------------------------------- text sources
def docstring_attributes(cls: type) -> dict[str, str]:
    """``name -> text`` of the ``Attributes:`` block of a class docstring (entries
    ``name: text`` or ``a, b: text``, continuation lines indented deeper)."""
    doc = inspect.getdoc(cls) or ""
    out: dict[str, str] = {}
    lines = doc.splitlines()
    try:
        start = next(i for i, ln in enumerate(lines) if ln.strip() == "Attributes:")
    except StopIteration:
        return out
    base: int | None = None
    current: list[str] = []
    pending: list[str] = []  # names of an entry whose name list goes on to the next line
    for line in lines[start + 1 :]:
        if not line.strip():
            continue
        indent = len(line) - len(line.lstrip())
        if base is None:
            base = indent
        if indent < base:
            break
        stripped = line.strip()
        if indent == base and re.fullmatch(r"[A-Za-z_][\w, ]*,", stripped):
            pending = [n.strip() for n in stripped.split(",") if n.strip()]
            continue
        m = re.match(r"^\s*([A-Za-z_][\w, ]*):\s*(.*)$", line)
        if m and not (indent == base or pending):
            m = None
        if m:
            current = pending + [n.strip() for n in m.group(1).split(",") if n.strip()]
            pending = []
            for name in current:
                out[name] = m.group(2).strip()
        elif current:
            for name in current:
                out[name] = f"{out[name]} {line.strip()}".strip()
    return out


def _plain(text: str) -> str:
    """One line, RST double backticks as Markdown code."""
    return " ".join(text.replace("``", "`").split())


def _first_paragraph(cls: type) -> str:
    doc = inspect.getdoc(cls) or ""
    return _plain(doc.split("\n\n", 1)[0])


# ---------------------------------------------------------------------- types
def _strip_annotated(tp: Any) -> tuple[Any, list[Any]]:
    """(bare type, constraint metadata) of a possibly ``Annotated`` type."""
    meta: list[Any] = []
    while get_origin(tp) is typing.Annotated:
        args = get_args(tp)
        tp = args[0]
        for m in args[1:]:
            meta.extend(m.metadata if isinstance(m, FieldInfo) else [m])
    return tp, meta


def _is_union(tp: Any) -> bool:
    return get_origin(tp) in (Union, types.UnionType)


def _optional_inner(tp: Any) -> tuple[Any, bool]:
    """(the type without None, whether None is allowed)."""
    if _is_union(tp):
        args = [a for a in get_args(tp) if a is not type(None)]
        if len(args) < len(get_args(tp)):
            return (args[0] if len(args) == 1 else Union[tuple(args)]), True  # noqa: UP007
    return tp, False


def _section_type(tp: Any) -> type[BaseModel] | None:
    tp, _ = _strip_annotated(tp)
    tp, _ = _optional_inner(tp)
    return tp if inspect.isclass(tp) and issubclass(tp, BaseModel) else None


def type_text(tp: Any) -> str:
    """The TOML type of a Python annotation (``float``, ``array of string``, ...)."""
    tp, _ = _strip_annotated(tp)
    inner, optional = _optional_inner(tp)
    if optional:
        return f"{type_text(inner)} (optional)"
    origin = get_origin(tp)
    if origin is Literal:
        kinds = {type(a) for a in get_args(tp)}
        return "string" if kinds == {str} else "integer" if kinds == {int} else "value"
    if _is_union(tp):
        return " or ".join(type_text(a) for a in get_args(tp))
    if origin in (list, tuple, set, frozenset):
        args = [a for a in get_args(tp) if a is not Ellipsis]
        if origin is tuple and args and Ellipsis not in get_args(tp):
            items = {type_text(a) for a in args}
            if len(items) == 1:
                return f"array of {len(args)} {items.pop()}"
            return "array [" + ", ".join(type_text(a) for a in args) + "]"
        return f"array of {type_text(args[0])}" if args else "array"
    if origin is dict:
        return f"table of {type_text(get_args(tp)[1])}"
    if inspect.isclass(tp):
        if issubclass(tp, BaseModel):
            return "table"
        if issubclass(tp, bool):
            return "boolean"
        if issubclass(tp, int):
            return "integer"
        if issubclass(tp, float):
            return "float"
        if issubclass(tp, str | Path):
            return "string"
    return str(tp).replace("typing.", "")


def _bounds(meta: list[Any]) -> list[str]:
    """Interval notation (``(0, 20]``, ``>= 0``) and length / pattern limits."""
    parts = []
    lo = hi = None
    for m in meta:
        for attr, sym in (("gt", "("), ("ge", "[")):
            if isinstance(m, getattr(at, attr.capitalize())):
                lo = (sym, _num(getattr(m, attr)))
        for attr, sym in (("lt", ")"), ("le", "]")):
            if isinstance(m, getattr(at, attr.capitalize())):
                hi = (sym, _num(getattr(m, attr)))
    if lo and hi:
        parts.append(f"{lo[0]}{lo[1]}, {hi[1]}{hi[0]}")
    elif lo:
        parts.append(f"{'>' if lo[0] == '(' else '>='} {lo[1]}")
    elif hi:
        parts.append(f"{'<' if hi[0] == ')' else '<='} {hi[1]}")
    for m in meta:
        if isinstance(m, at.MinLen):
            parts.append(f"length >= {m.min_length}")
        if isinstance(m, at.MaxLen):
            parts.append(f"length <= {m.max_length}")
        if isinstance(m, at.MultipleOf):
            parts.append(f"multiple of {_num(m.multiple_of)}")
        pattern = getattr(m, "pattern", None)
        if isinstance(pattern, str):
            parts.append(f"matches `{pattern}`")
    return parts


def range_text(tp: Any, field_meta: list[Any]) -> str:
    """Allowed values: bounds of the field and of its items, choices of a Literal."""
    tp, meta = _strip_annotated(tp)
    parts = _bounds(field_meta + meta)
    inner, _ = _optional_inner(tp)
    choices = [m for m in field_meta + meta if isinstance(m, Choices)]
    if choices:
        parts.append("one of " + ", ".join(_toml(a) for a in choices[0].names()))
    elif get_origin(inner) is Literal:
        parts.append("one of " + ", ".join(_toml(a) for a in get_args(inner)))
    elif get_origin(inner) in (list, tuple):
        items = []
        for a in get_args(inner):
            if a is Ellipsis:
                continue
            sub = range_text(a, [])
            if sub:
                items.append(sub)
        if items:
            uniq = list(dict.fromkeys(items))
            parts.append("each " + "; ".join(uniq) if len(uniq) == 1 else
                         "items: " + " / ".join(items))
    return ", ".join(parts)


# ---------------------------------------------------------------------- values
def _num(v: Any) -> str:
    if isinstance(v, float):
        text = repr(v)
        return text.removesuffix(".0") if abs(v) >= 1e5 else text
    return str(v)


def _not_toml(v: Any) -> str:
    """The reference's text of a default TOML cannot hold: ``none`` (an absent optional),
    ``{...}`` (a table given as a model), a set as an array."""
    if v is None:
        return "none"
    if isinstance(v, BaseModel):
        return "{...}"
    if isinstance(v, set | frozenset):
        return _toml(sorted(v, key=str))
    return str(v)


def _toml(v: Any) -> str:
    """A default as TOML text (``shared.config.toml_write``; ``_not_toml`` for the rest)."""
    return toml_value(v, other=_not_toml)


def _unit(name: str, text: str) -> str:
    """The one ``[unit]`` of the text, else the unit of the name's ending, else the text's
    first ``[unit]``, else ""."""
    found = [m.group(1).strip() for m in _UNIT_IN_TEXT.finditer(text)]
    found = [u for u in found if _looks_like_unit(u)]
    if len(set(found)) == 1:
        return found[0]
    for suffix, unit in UNIT_SUFFIXES:
        if name.endswith(suffix):
            return unit
    return found[0] if found else ""


# ---------------------------------------------------------------------- walking
def _default(info: FieldInfo) -> Any:
    if info.default is PydanticUndefined and info.default_factory is None:
        return PydanticUndefined
    return info.get_default(call_default_factory=True)


def iter_sections(
    model: type[BaseModel] = RacestackConfig, path: str = "", defaults: BaseModel | None = None
) -> Iterator[SectionDoc]:
    """Every table of `model` (depth first, in declaration order) with its plain keys;
    `defaults` is the instance whose values are the defaults (None: the model's own)."""
    attrs = docstring_attributes(model)
    keys: list[KeyDoc] = []
    nested: list[tuple[str, type[BaseModel], str, BaseModel | None]] = []
    for name, info in model.model_fields.items():
        text = _plain(info.description or attrs.get(name, ""))
        sub = _section_type(info.annotation)
        full = f"{path}.{name}" if path else name
        ann, _ = _strip_annotated(info.annotation)
        ann, optional = _optional_inner(ann)
        origin = get_origin(ann)
        default = getattr(defaults, name) if defaults is not None else _default(info)
        if sub is not None:
            note = " (optional: absent = none)" if optional else ""
            inst = default if isinstance(default, BaseModel) else None
            nested.append((full, sub, text + note, inst))
            continue
        if origin is dict and _section_type(get_args(ann)[1]) is not None:
            nested.append((f"{full}.<name>", _section_type(get_args(ann)[1]), text, None))
            continue
        if origin in (list, tuple) and get_args(ann) and _section_type(get_args(ann)[0]):
            nested.append((f"{full}[]", _section_type(get_args(ann)[0]), text, None))
            keys.append(KeyDoc(full, "array of tables", "", _n_entries(default), "", text))
            continue
        keys.append(
            KeyDoc(
                path=full,
                type=type_text(info.annotation),
                unit=_unit(name, text),
                default="(required)" if default is PydanticUndefined else _toml(default),
                range=range_text(info.annotation, list(info.metadata)),
                description=text,
            )
        )
    yield SectionDoc(path, _first_paragraph(model), tuple(keys))
    for full, sub, text, inst in nested:
        for i, sec in enumerate(iter_sections(sub, full, inst)):
            yield SectionDoc(sec.path, text or sec.text, sec.keys) if i == 0 and text else sec


def _n_entries(default: Any) -> str:
    if default is PydanticUndefined:
        return "(required)"
    return "[]" if not default else f"{len(default)} entries"


def iter_keys(model: type[BaseModel] = RacestackConfig) -> Iterator[KeyDoc]:
    """Every plain key of the configuration (what the reference's tables list)."""
    for sec in iter_sections(model):
        yield from sec.keys


# ---------------------------------------------------------------------- markdown
def _cell(text: str) -> str:
    return text.replace("|", "\\|").replace("\n", " ") or " "


def render_markdown(model: type[BaseModel] = RacestackConfig) -> str:
    """The whole reference as Markdown (one table per section)."""
    out = [
        "# Configuration reference",
        "",
        "<!-- Generated from the configuration models (shared/config/*.py); do not edit.",
        f"     Regenerate: {GENERATOR} -->",
        "",
        "Every key of the racestack configuration (`--config FILE.toml`, see",
        "`config/racestack.toml` and the real-car example `config/car.toml`). Every section and",
        "key is optional: what a file leaves out takes the default below; unknown keys and",
        "values out of range are errors naming the file and the key. A `<name>` in a path is",
        "a table key of your choice (e.g. a service name); `[]` is an array of tables",
        "(`[[path]]` in TOML). Units are in the names (`_s` seconds, `_m` metres, `_mps` m/s,",
        "`_hz` Hz, `_rad` radians).",
        "",
    ]
    sections = [s for s in iter_sections(model) if s.path]
    out.append("Sections: " + ", ".join(f"[`[{s.path}]`](#{_anchor(s.path)})"
                                        for s in sections) + ".")
    out.append("")
    for sec in sections:
        out += [f"## [{sec.path}]", ""]
        if sec.text:
            out += [sec.text, ""]
        if not sec.keys:
            out += ["(only the tables below)", ""]
            continue
        out += ["| key | type | unit | default | range | what it does |",
                "|---|---|---|---|---|---|"]
        for k in sec.keys:
            leaf = k.path.removeprefix(sec.path + ".")
            out.append(
                f"| `{leaf}` | {_cell(k.type)} | {_cell(k.unit)} | `{_cell(k.default)}` | "
                f"{_cell(k.range)} | {_cell(k.description)} |"
            )
        out.append("")
    return "\n".join(out).rstrip() + "\n"


def _anchor(path: str) -> str:
    """GitHub's heading anchor of ``## [path]``."""
    text = f"[{path}]".lower()
    return re.sub(r"[^a-z0-9 _-]", "", text).replace(" ", "-")


def main(argv: list[str] | None = None) -> int:
    """Print the reference (or write it with ``--out``); returns the exit code."""
    ap = argparse.ArgumentParser(
        prog="python -m services.tools.config_reference",
        description="print the configuration reference (docs/configuration.md)",
    )
    ap.add_argument("--out", help="write it to this file instead of printing it")
    args = ap.parse_args(argv)
    text = render_markdown()
    if args.out:
        Path(args.out).write_text(text, encoding="utf-8")
    else:
        sys.stdout.write(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())

