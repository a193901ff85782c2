"""pyproject.toml states its licence the PEP 639 way, so installing prints no setuptools
deprecation warning (``project.license`` as a table is deprecated since setuptools 77)."""

from __future__ import annotations

import re
import tomllib
from pathlib import Path

PYPROJECT = Path(__file__).resolve().parents[2] / "pyproject.toml"


def test_the_licence_is_an_spdx_string_with_a_setuptools_that_reads_it() -> None:
    data = tomllib.loads(PYPROJECT.read_text(encoding="utf-8"))
    assert data["project"]["license"] == "Apache-2.0"
    assert not any(c.startswith("License ::") for c in data["project"].get("classifiers", []))
    requires = " ".join(data["build-system"]["requires"])
    m = re.search(r"setuptools\s*>=\s*(\d+)", requires)
    assert m and int(m.group(1)) >= 77, requires
