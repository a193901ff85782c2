"""racestack tune's pure core: search spaces, overlays, scoring (the TOML writer:
tests/shared/test_toml_write.py)."""

from __future__ import annotations

import numpy as np
import pytest

from services.tools.tune.search import (
    PENALTY_S,
    SeedResult,
    UnknownMethodError,
    complete_overlay,
    deep_merge,
    score,
    space_for,
    speed_pair,
    top_progress_speed,
)
from shared.config import RacestackConfig, config_from_dict
from shared.config.planner import CIMPCC_WEIGHTS, MPCC_WEIGHTS, RacelineSettings


def _config(overlay: dict) -> RacestackConfig:
    return config_from_dict(overlay, "overlay")


def test_cimpcc_baseline_is_the_papers_configuration() -> None:
    space = space_for("cimpcc", 4.18)
    cfg = _config(space.overlay(space.baseline(RacestackConfig())))
    w = cfg.planner.cimpcc
    assert w.v_up_mps == CIMPCC_WEIGHTS.v_up_mps == (4.18, 3.8)
    assert w.v_low_mps == CIMPCC_WEIGHTS.v_low_mps == (2.72, 2.47)
    assert w.r3_velocity == CIMPCC_WEIGHTS.r3_velocity
    assert w.gamma == CIMPCC_WEIGHTS.gamma
    assert cfg.curvature == RacestackConfig().curvature
    assert cfg == RacestackConfig()


def test_mpcc_and_raceline_baselines_are_the_defaults() -> None:
    d = RacestackConfig()
    for method in ("mpcc", "raceline", "cimpcc-line"):
        space = space_for(method, 4.18)
        assert _config(complete_overlay(space.overlay(space.baseline(d)), d)) == d
    assert MPCC_WEIGHTS.u_ref == (3.3, 0.0, 3.0)


def test_a_tuned_mpcc_keeps_mpccs_own_weights() -> None:
    """A partial [planner.mpcc] table would take CiMPCC's class defaults (R3 = 40)."""
    d = RacestackConfig()
    space = space_for("mpcc", 4.18)
    over = space.overlay({"v_p_ref": 2.5, "r2_speed": 20.0, "r2_delta": 5.0})
    w = _config(complete_overlay(over, d)).planner.mpcc
    assert w.u_ref == (2.75, 0.0, 2.5) and w.r2_input == (20.0, 5.0, 20.0)
    assert w.r3_velocity == MPCC_WEIGHTS.r3_velocity == (0.0, 0.0)


@pytest.mark.parametrize("line", ["min_time", "min_curvature"])
def test_raceline_space_names_existing_settings(line: str) -> None:
    space = space_for("raceline", 4.18, config_from_dict({"planner": {"raceline": {"line": line}}}))
    fields = set(RacelineSettings.model_fields)
    assert set(space.names()) <= fields


def test_a_tuned_cimpcc_line_keeps_its_own_weights() -> None:
    """A partial [planner.cimpcc_line.weights] table is completed from cimpcc-line's own
    weights (R1 steering 500), not CiMPCC's class defaults (3500)."""
    d = RacestackConfig()
    space = space_for("cimpcc-line", 4.18)
    point = space.baseline(d) | {"q_lag": 1200.0, "grip_fraction": 0.973}
    line = _config(complete_overlay(space.overlay(point), d)).planner.cimpcc_line
    assert line.weights.q_lag == 1200.0
    assert line.weights.r1_delta_u == d.planner.cimpcc_line.weights.r1_delta_u
    assert line.weights.r2_input == d.planner.cimpcc_line.weights.r2_input
    assert line.grip_fraction == 0.97  # rounded: one cached minimum-time solve per value


@pytest.mark.parametrize("method", ["cimpcc", "mpcc", "raceline", "cimpcc-line"])
def test_every_point_of_a_space_is_a_valid_configuration(method: str) -> None:
    space = space_for(method, 4.18)
    rng = np.random.default_rng(3)
    corners = [{p.name: (p.low, p.high)[i % 2] for i, p in enumerate(space.params)}]
    corners += [{p.name: p.high for p in space.params}, {p.name: p.low for p in space.params}]
    for point in [*corners, *({p.name: rng.uniform(p.low, p.high) for p in space.params}
                              for _ in range(30))]:
        cfg = _config(complete_overlay(space.overlay(point), RacestackConfig()))
        if method == "cimpcc":
            w = cfg.planner.cimpcc
            assert w.v_up_mps[0] <= 4.18 + 1e-9
            assert w.v_low_mps[1] <= w.v_up_mps[1]
            assert w.v_up_mps[0] == pytest.approx(1.1 * w.v_up_mps[1], abs=0.006)
        if method == "raceline":
            assert cfg.planner.raceline.v_max_mps == 4.18
        if method == "cimpcc-line":
            assert cfg.planner.cimpcc_line.v_max_mps == 4.18
            assert cfg.planner.cimpcc_line.grip_fraction == round(point["grip_fraction"], 2)


def test_speed_pairs_and_top_speed() -> None:
    assert speed_pair(3.8) == [4.18, 3.8]
    assert top_progress_speed(4.18) == 3.8
    assert top_progress_speed(5.0) == 4.54
    assert speed_pair(top_progress_speed(5.0))[0] <= 5.0


def test_unknown_method_is_a_clear_error() -> None:
    with pytest.raises(UnknownMethodError, match="unknown method 'pid'; choose from cimpcc"):
        space_for("pid", 4.18)


def _seed(seed: int, laps=(13.0, 13.1), off=0, rec=0, clear=0.2, aborted="") -> SeedResult:
    return SeedResult(seed, tuple(laps), off, rec, clear, aborted)


def test_score_feasible_is_the_mean_lap() -> None:
    sc = score([_seed(0), _seed(1, (13.2, 13.3))], laps=2, n_seeds=2, margin_m=0.05)
    assert sc.feasible and sc.reasons == ()
    assert sc.value == pytest.approx(13.15)
    assert sc.constraints == (0.0, 0.0, 0.0, pytest.approx(-0.15), 0.0, 0.0)


def test_score_infeasible_cases() -> None:
    off = score([_seed(0, off=2)], 2, 1, 0.05)
    assert not off.feasible and off.value == pytest.approx(13.05)
    assert "2 off-track event(s)" in off.reasons
    rec = score([_seed(0, rec=1)], 2, 1, 0.05)
    assert not rec.feasible and rec.constraints[1] == 1.0
    close = score([_seed(0, clear=0.01)], 2, 1, 0.05)
    assert not close.feasible and close.constraints[3] == pytest.approx(0.04)
    assert any("margin" in r for r in close.reasons)
    short = score([_seed(0, laps=(13.0,), aborted="lost")], 2, 3, 0.05)
    assert not short.feasible and short.value == PENALTY_S and short.mean_lap_s == 13.0
    assert short.constraints[2] == 1.0
    assert "seed 0: lost" in short.reasons and "2 seed(s) skipped" in short.reasons
    none = score([], 2, 3, 0.05)
    assert not none.feasible and none.value == PENALTY_S


def test_deep_merge_keeps_the_base_and_overlays_keys() -> None:
    base = {"planner": {"cimpcc": {"q_lag": 700.0}, "dt_s": 0.05}, "bus": {"car": "x"}}
    over = {"planner": {"cimpcc": {"gamma": 50.0}}, "curvature": {"alpha": 3.0}}
    merged = deep_merge(base, over)
    assert merged == {
        "planner": {"cimpcc": {"q_lag": 700.0, "gamma": 50.0}, "dt_s": 0.05},
        "bus": {"car": "x"},
        "curvature": {"alpha": 3.0},
    }
    assert base["planner"]["cimpcc"] == {"q_lag": 700.0}  # not modified
