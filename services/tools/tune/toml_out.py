"""A small TOML writer for configuration files (tables of strings, numbers, booleans and
arrays of them), enough for ``best.toml``; ``tomllib`` reads its output back unchanged."""

from __future__ import annotations

import json
import math
from collections.abc import Mapping
from typing import Any


class TomlWriteError(TypeError):
    """A value TOML cannot hold (e.g. None) or this writer does not write."""


def _key(k: str) -> str:
    bare = k.replace("_", "").replace("-", "").isalnum() and k.isascii()
    return k if bare else json.dumps(k)


def _value(v: Any, where: str) -> str:
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
        return "[" + ", ".join(_value(x, where) for x in v) + "]"
    if isinstance(v, Mapping):
        items = ", ".join(f"{_key(str(k))} = {_value(x, where)}" for k, x in v.items())
        return "{" + items + "}"
    raise TomlWriteError(f"{where}: cannot write {type(v).__name__} to TOML")


def _table(data: Mapping[str, Any], path: list[str], out: list[str]) -> None:
    scalars = [(k, v) for k, v in data.items() if not isinstance(v, Mapping)]
    tables = [(k, v) for k, v in data.items() if isinstance(v, Mapping)]
    if path and (scalars or not tables):
        out.append(f"[{'.'.join(_key(p) for p in path)}]")
    for k, v in scalars:
        out.append(f"{_key(k)} = {_value(v, '.'.join([*path, k]))}")
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
