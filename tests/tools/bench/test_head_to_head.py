"""The bench head to head (issue #24): --opponent parsing, the contact response, and a tiny
``racestack bench --opponent`` run."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from services.simulator import Simulator
from services.tools.bench import main
from services.tools.bench.head_to_head import OpponentSpec, contact_response
from shared.config.simulator import SimulatorSettings


def test_the_opponent_spec_is_a_method_and_a_speed_scale() -> None:
    assert OpponentSpec.parse("raceline:0.85") == OpponentSpec("raceline", 0.85)
    assert OpponentSpec.parse("cimpcc") == OpponentSpec("cimpcc", 1.0)
    for bad in ("raceline:fast", "raceline:0", "raceline:1.5", ":0.8"):
        with pytest.raises(ValueError):
            OpponentSpec.parse(bad)


def test_touching_cars_are_pushed_apart_and_lose_their_closing_speed() -> None:
    a, b = Simulator(SimulatorSettings()), Simulator(SimulatorSettings())
    a.reset((0.0, 0.0, 0.0), speed_mps=4.0)  # a rear-ends b: 0.5 m apart, 0.58 m long
    b.reset((0.5, 0.0, 0.0), speed_mps=2.0)
    contact_response(a, b, np.array([1.0, 0.0]), 0.08)
    sa, sb = a.state, b.state
    assert sb.x_m - sa.x_m == pytest.approx(0.581, abs=1e-6)  # apart by the depth
    # momentum kept (equal masses), closing speed reversed at the restitution
    assert sa.v_mps + sb.v_mps == pytest.approx(6.0)
    assert sb.v_mps - sa.v_mps == pytest.approx(0.2 * 2.0)
    assert abs(sa.slip_rad) < 1e-9 and abs(sb.slip_rad) < 1e-9


def test_a_tiny_head_to_head_bench_run(tmp_path, capsys) -> None:
    cfg = tmp_path / "c.toml"
    cfg.write_text('[planner.raceline]\nline = "min_curvature"\n', encoding="utf-8")
    out = tmp_path / "out"
    rc = main([
        "--config", str(cfg), "--track", "paperlike", "--methods", "raceline",
        "--opponent", "raceline:0.5", "--laps", "1", "--seeds", "1", "--out", str(out),
    ])
    text = capsys.readouterr().out
    assert rc == 0, text
    assert "head to head on" in text and "raceline" in text
    doc = json.loads((out / "results.json").read_text(encoding="utf-8"))
    m = doc["head_to_head"]["raceline"]
    assert doc["opponent"] == {"method": "raceline", "speed_scale": 0.5}
    assert m["seeds"] == 1 and m["contacts"] == 0
    assert m["off_track_ego"] == 0 and math.isfinite(m["solo_time_s"])
    assert len(m["per_seed"]) == 1


def test_a_bad_opponent_is_one_line_and_exit_2(tmp_path, capsys) -> None:
    rc = main(["--track", "paperlike", "--opponent", "nosuch:0.8", "--out", str(tmp_path)])
    assert rc == 2
    assert "unknown --opponent method nosuch" in capsys.readouterr().err
