"""shared.config.toml_write: the one TOML writer (best.toml, the configuration reference)."""

from __future__ import annotations

import math
import tomllib

import pytest

from shared.config import config_from_dict, toml_write
from shared.config.toml_write import TomlWriteError, dumps, key, value


def test_toml_writer_round_trips() -> None:
    data = {
        "title": 'a "quoted" \\ string',
        "planner": {
            "method": "cimpcc",
            "cimpcc": {"v_up_mps": [4.18, 3.8], "gamma": 40.0},
            "solver": {"compile": False, "max_iter": 100},
        },
        "bus": {"connect": ["tcp/1.2.3.4:7447"], "services": {"router": {"mode": "router"}}},
        "empty": {},
    }
    text = dumps(data, "a header\nsecond line")
    assert text.startswith("# a header\n# second line\n")
    assert tomllib.loads(text) == data
    with pytest.raises(TomlWriteError):
        dumps({"x": None})


def test_values_and_keys() -> None:
    assert value(True) == "true" and value(False) == "false"
    assert value(3) == "3" and value(0.5) == "0.5" and value(1e-7) == "1e-07"
    assert value(math.inf) == "inf" and value(-math.inf) == "-inf" and value(math.nan) == "nan"
    assert value("a\nb \u00e9") == '"a\\nb \u00e9"'
    assert value((1, [2.0, "x"])) == '[1, [2.0, "x"]]'
    assert value({"a b": 1, "c": {"d": True}}) == '{"a b" = 1, c = {d = true}}'
    assert key("max_iter") == "max_iter" and key("a-b") == "a-b"
    assert key("a.b") == '"a.b"'
    accented = "\u00e9 x"
    assert tomllib.loads(key(accented) + " = 1") == {accented: 1}
    for v in (1e300, -0.0, 123456789.125, 1e16, "quote \" and \\ back"):
        assert tomllib.loads(f"x = {value(v)}")["x"] == v


def test_what_toml_cannot_hold_goes_to_other_or_raises() -> None:
    assert value([1, None], other=lambda v: "none") == "[1, none]"
    with pytest.raises(TomlWriteError, match=r"planner\.x: cannot write NoneType"):
        value(None, "planner.x")
    with pytest.raises(TomlWriteError):
        value(object())


def test_a_written_configuration_loads() -> None:
    data = {"planner": {"dt_s": 0.05, "mpcc": {"u_ref": [3.0, 0.0, 2.5]}}, "bus": {"car": "x"}}
    cfg = config_from_dict(tomllib.loads(toml_write.dumps(data)))
    assert cfg.planner.dt_s == 0.05 and cfg.bus.car == "x"
    assert list(cfg.planner.mpcc.u_ref) == [3.0, 0.0, 2.5]
