"""``benchmarks/line_reserves.py``: each variant removes one reserve of the raceline's line, and
the table's ratios are the variants' laps over the limit (laps stubbed: nothing solved)."""

from __future__ import annotations

import dataclasses
from types import SimpleNamespace

import pytest

from benchmarks import line_reserves
from services.planner.mintime.ocp import MinTimeError, MinTimeSettings


def test_each_variant_removes_one_reserve_only() -> None:
    line = MinTimeSettings(margin_m=0.05, slip_fraction=0.8, ellipse_fraction=0.95)
    limit = MinTimeSettings()
    assert line_reserves.variant(line, limit, "line") is line
    for name, field, value in (("no margin", "margin_m", limit.margin_m),
                               ("no slip", "slip_fraction", 1.0),
                               ("no ellipse", "ellipse_fraction", 1.0)):
        got = line_reserves.variant(line, limit, name)
        assert getattr(got, field) == value
        assert dataclasses.replace(got, **{field: getattr(line, field)}) == line
    with pytest.raises(ValueError, match="unknown variant"):
        line_reserves.variant(line, limit, "no servo")


def test_the_high_speed_variants_remove_one_part_of_that_reserve_only() -> None:
    line = MinTimeSettings(v_max_mps=10.0, reserve_speed_mps=4.18, reserve_fraction=0.9,
                           reserve_rear_fraction=0.8, reserve_yaw_pole_per_s=2.0,
                           reserve_steering_weight_s=0.1, reserve_margin_m=0.1)
    limit = MinTimeSettings(v_max_mps=10.0)
    for name, fields in (("no speed margin", {"reserve_margin_m": 0.0}),
                         ("no steer cost", {"reserve_steering_weight_s": 0.0}),
                         ("no yaw bound", {"reserve_yaw_pole_per_s": None}),
                         ("no rear share", {"reserve_rear_fraction": None}),
                         ("no hs ellipse", {"reserve_fraction": 1.0,
                                            "reserve_rear_fraction": None})):
        got = line_reserves.variant(line, limit, name)
        assert all(getattr(got, f) == v for f, v in fields.items())
        assert dataclasses.replace(got, **{f: getattr(line, f) for f in fields}) == line


def test_at_speed_the_table_prices_the_high_speed_reserve(monkeypatch, capsys) -> None:
    def lap(track, car, settings, use=None, progress=None):
        if use == "limit":
            return SimpleNamespace(lap_time_s=10.0)
        return SimpleNamespace(lap_time_s=11.0 - (settings.reserve_yaw_pole_per_s is None))

    monkeypatch.setattr(line_reserves, "make_min_time_lap", lap)
    assert line_reserves.main(["--tracks", "paperlike", "--cars", "default",
                               "--v-max", "10"]) == 0
    out = capsys.readouterr().out.splitlines()
    header = next(r for r in out if r.startswith("track"))
    assert "no yaw bound" in header and "no rear share" in header
    cells = next(r for r in out if r.startswith("paperlike")).split()
    assert [float(c) for c in cells[4:13]] == [1.1] * 6 + [1.0] + [1.1] * 2


def test_the_table_prints_each_variant_over_the_limit(monkeypatch, capsys) -> None:
    def lap(track, car, settings, use=None, progress=None):
        if use == "limit":
            return SimpleNamespace(lap_time_s=10.0)
        if settings.ellipse_fraction == 1.0 and settings.slip_fraction != 1.0:
            raise MinTimeError("x", "infeasible here")
        return SimpleNamespace(lap_time_s=10.0 + 10.0 * settings.margin_m)

    monkeypatch.setattr(line_reserves, "make_min_time_lap", lap)
    assert line_reserves.main(["--tracks", "paperlike", "--cars", "identified"]) == 0
    out = capsys.readouterr().out
    row = next(r for r in out.splitlines() if r.startswith("paperlike"))
    cells = row.split()
    assert cells[1:3] == ["identified", "truth"] and cells[3] == "10.000"
    margin = float(cells[-1])  # the line's margin, the servo's tube in it
    assert float(cells[4]) == pytest.approx(1.0 + margin, abs=1e-4)  # the line
    assert float(cells[5]) == pytest.approx(1.0 + MinTimeSettings().margin_m, abs=1e-4)
    assert cells[7] == "infeasible"


def test_a_wrong_car_or_track_is_one_line(capsys) -> None:
    assert line_reserves.main(["--cars", "tractor"]) == 2
    assert "unknown car tractor" in capsys.readouterr().err
    assert line_reserves.main(["--tracks", "/nonexistent/track"]) == 2
    assert "line_reserves:" in capsys.readouterr().err
