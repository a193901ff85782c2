"""A small TOML writer (tables of strings, numbers, booleans and arrays and inline tables of
them): ``racestack tune`` writes ``best.toml`` with it, the configuration reference its
defaults; ``tomllib`` reads ``dumps``'s output back unchanged.

- ``dumps(data, header)``: nested mappings as a document (``[a.b]`` headers, scalars first);
- ``value(v)``: one value as TOML text (``true``, ``3``, ``0.5``, ``"text"``, ``[1, 2]``,
  ``{a = 1}``, ``nan``, ``inf``); ``other`` may give the text of what TOML cannot hold
  (None, objects), else it raises ``TomlWriteError``;
- ``key(k)``: a key, bare when it may be, else quoted.
"""

from __future__ import annotations

import json
import math
from collections.abc import Callable, Mapping
from typing import Any

__all__ = ["TomlWriteError", "dumps", "key", "value"]


class TomlWriteError(TypeError):
    """A value TOML cannot hold (e.g. None) or this writer does not write."""


def key(k: str) -> str:
    """`k` as a TOML key: bare (ASCII letters, digits, ``_``, ``-``) or a quoted string."""
    bare = k.replace("_", "").replace("-", "").isalnum() and k.isascii()
    return k if bare else json.dumps(k)


def value(v: Any, where: str = "value", other: Callable[[Any], str] | None = None) -> str:
    """`v` as TOML text; what TOML cannot hold goes to `other` (None: raise
    ``TomlWriteError`` naming `where`). Items of arrays and inline tables alike."""
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, int):
        return str(v)
    if isinstance(v, float):
        if math.isnan(v):
            return "nan"
        if math.isinf(v):
            return "inf" if v > 0 else "-inf"
        return repr(v)
    if isinstance(v, str):
        return json.dumps(v, ensure_ascii=False)  # a TOML basic string
    if isinstance(v, list | tuple):
        return "[" + ", ".join(value(x, where, other) for x in v) + "]"
    if isinstance(v, Mapping):
        items = ", ".join(f"{key(str(k))} = {value(x, where, other)}" for k, x in v.items())
        return "{" + items + "}"
    if other is not None:
        return other(v)
    raise TomlWriteError(f"{where}: cannot write {type(v).__name__} to TOML")


def _table(data: Mapping[str, Any], path: list[str], out: list[str]) -> None:
    scalars = [(k, v) for k, v in data.items() if not isinstance(v, Mapping)]
    tables = [(k, v) for k, v in data.items() if isinstance(v, Mapping)]
    if path and (scalars or not tables):
        out.append(f"[{'.'.join(key(p) for p in path)}]")
    for k, v in scalars:
        out.append(f"{key(k)} = {value(v, '.'.join([*path, k]))}")
    if path and (scalars or not tables):
        out.append("")
    for k, v in tables:
        _table(v, [*path, str(k)], out)


def dumps(data: Mapping[str, Any], header: str = "") -> str:
    """`data` (nested tables) as TOML text, `header` lines first as comments."""
    out = [f"# {line}".rstrip() for line in header.splitlines()]
    if out:
        out.append("")
    _table(data, [], out)
    if out and out[-1] == "" and len(out) > 1:
        out.pop()
    return "\n".join(out) + "\n"
