"""docs/configuration.md is generated from the configuration models and must be current."""

from __future__ import annotations

from pathlib import Path

from pydantic import BaseModel

from services.tools.config_reference import (
    GENERATOR,
    docstring_attributes,
    iter_keys,
    render_markdown,
)
from shared.config import RacestackConfig

ROOT = Path(__file__).resolve().parents[2]
DOC = ROOT / "docs" / "configuration.md"


def test_the_committed_reference_is_current() -> None:
    committed = DOC.read_text(encoding="utf-8") if DOC.exists() else ""
    assert committed == render_markdown(), (
        f"docs/configuration.md is not what the configuration models give: run `{GENERATOR}`"
    )


def _leaf_paths(model: type[BaseModel], prefix: str = "") -> set[str]:
    """Every plain key of the model, found independently of the generator's walk."""
    out = set()
    for name, info in model.model_fields.items():
        sub = next((a for a in _classes(info.annotation) if issubclass(a, BaseModel)), None)
        path = f"{prefix}{name}"
        if sub is None:
            out.add(path)
        elif "dict" in str(info.annotation):
            out |= _leaf_paths(sub, f"{path}.<name>.")
        elif "tuple" in str(info.annotation) or "list" in str(info.annotation):
            out.add(path)
            out |= _leaf_paths(sub, f"{path}[].")
        else:
            out |= _leaf_paths(sub, f"{path}.")
    return out


def _classes(tp: object) -> list[type]:
    import typing

    found = [tp] if isinstance(tp, type) else []
    for arg in typing.get_args(tp):
        found += _classes(arg)
    return found


def test_every_key_is_in_the_reference_with_a_type_and_a_default() -> None:
    docs = {k.path: k for k in iter_keys()}
    assert set(docs) == _leaf_paths(RacestackConfig)
    assert all(k.type and k.default for k in docs.values())
    assert docs["planner.dt_s"].unit == "s" and docs["planner.dt_s"].range == "(0.0, 0.5]"
    assert docs["planner.mpcc.u_ref"].default == "[3.3, 0.0, 3.0]"  # the field's default
    assert docs["planner.method"].range.startswith('one of "cimpcc"')


def test_every_key_says_what_it_does() -> None:
    missing = sorted(k.path for k in iter_keys() if not k.description)
    assert not missing, (
        "keys without a description (a Field(description=...) or an entry in the "
        f"section docstring's Attributes: list): {', '.join(missing)}"
    )


def test_docstring_attributes_are_parsed_with_continuations() -> None:
    class Demo:
        """Demo.

        Attributes:
            a_s: first line
                goes on [s].
            b_m, c_m: shared text [m].
            d_long, e_long,
                f_long: names over two lines.
        """

    got = docstring_attributes(Demo)
    assert got["a_s"] == "first line goes on [s]."
    assert got["b_m"] == got["c_m"] == "shared text [m]."
    assert got["d_long"] == got["f_long"] == "names over two lines."
