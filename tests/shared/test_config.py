"""The one configuration: paper defaults, unknown keys and out-of-range values are errors."""

from __future__ import annotations

from pathlib import Path

import pytest

from shared.config import ConfigError, RacestackConfig, config_from_dict, load_config


def test_defaults_are_the_papers() -> None:
    cfg = RacestackConfig()
    p = cfg.planner
    assert p.horizon_steps == 10
    assert p.bounds.v_l_mps == (-10.0, 10.0)
    assert p.bounds.delta_rad == (-0.35, 0.35)
    assert p.wheelbase_m == 0.324
    ci, mp = p.cimpcc, p.mpcc
    assert (ci.q_contour, ci.q_lag, ci.gamma) == (800.0, 800.0, 40.0)
    assert ci.r1_delta_u == mp.r1_delta_u == (10.0, 3500.0, 0.0)
    assert ci.r2_input == (0.0, 10.0, 0.0) and ci.r3_velocity == (40.0, 40.0)
    assert ci.v_up_mps == (4.18, 3.8) and ci.v_low_mps == (2.72, 2.47)
    assert mp.u_ref == (3.3, 0.0, 3.0) and mp.r2_input == (40.0, 10.0, 40.0)
    assert mp.r3_velocity == (0.0, 0.0)
    assert cfg.curvature.alpha == 5.0 and cfg.curvature.window_m == 1.2
    assert cfg.track.source == "builtin:paperlike"


@pytest.mark.parametrize(
    ("data", "fragment"),
    [
        ({"planner": {"horizon": 10}}, "planner.horizon: unknown key"),
        ({"nonsense": {}}, "nonsense: unknown key"),
        ({"planner": {"horizon_steps": 0}}, "planner.horizon_steps"),
        ({"planner": {"dt_s": -0.1}}, "planner.dt_s"),
        ({"planner": {"method": "pid"}}, "planner.method"),
        ({"planner": {"bounds": {"delta_rad": [0.3, -0.3]}}}, "lower bound"),
        ({"curvature": {"alpha": 0}}, "curvature.alpha"),
        ({"planner": {"cimpcc": {"q_lag": "lots"}}}, "planner.cimpcc.q_lag"),
        ({"planner": {"cimpcc": {"gamma": float("nan")}}}, "planner.cimpcc.gamma"),
    ],
)
def test_invalid_config_is_a_clear_error(data: dict, fragment: str) -> None:
    with pytest.raises(ConfigError) as info:
        config_from_dict(data, "my.toml")
    assert "my.toml" in str(info.value)
    assert fragment in str(info.value)


def test_config_is_frozen() -> None:
    cfg = RacestackConfig()
    with pytest.raises(Exception):  # noqa: B017 - pydantic raises ValidationError
        cfg.planner.horizon_steps = 5  # type: ignore[misc]


def test_toml_file(tmp_path: Path) -> None:
    path = tmp_path / "race.toml"
    path.write_text('[planner]\nmethod = "mpcc"\nhorizon_steps = 12\n[track]\nsource = "gentle"\n')
    cfg = load_config(path)
    assert cfg.planner.method == "mpcc" and cfg.planner.horizon_steps == 12
    assert cfg.track.source == "gentle"
    (tmp_path / "broken.toml").write_text("[planner\n")
    with pytest.raises(ConfigError, match=r"broken\.toml: not valid TOML"):
        load_config(tmp_path / "broken.toml")
    with pytest.raises(ConfigError, match="cannot read"):
        load_config(tmp_path / "absent.toml")


def test_a_typo_d_key_gets_a_did_you_mean() -> None:
    from shared.config import ConfigError, config_from_dict

    with pytest.raises(ConfigError, match=r"planner\.horizon_step: unknown key; did you mean "
                       r"'horizon_steps'\?"):
        config_from_dict({"planner": {"horizon_step": 3}})
    with pytest.raises(ConfigError, match=r"planer: unknown key; did you mean 'planner'\?"):
        config_from_dict({"planer": {}})
    with pytest.raises(ConfigError) as err:  # nothing close: no guess
        config_from_dict({"planner": {"zzzz": 1}})
    assert str(err.value).endswith("planner.zzzz: unknown key")
