"""The F1TENTH raceline CSV: write, read back, reject malformed files."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from shared.track import RacelineTable, TrackError, load_f1tenth_raceline, write_f1tenth_raceline

HEADER = "# s_m; x_m; y_m; psi_rad; kappa_radpm; vx_mps; ax_mps2"


def table(n: int = 40) -> RacelineTable:
    th = np.linspace(0.0, 2 * np.pi, n, endpoint=False)
    s = 2.0 * th
    return RacelineTable(s, 2 * np.cos(th), 2 * np.sin(th), np.mod(th + np.pi / 2, 2 * np.pi),
                         np.full(n, 0.5), np.full(n, 3.0), np.zeros(n))


def test_round_trip(tmp_path: Path) -> None:
    path = tmp_path / "line.csv"
    src = table()
    write_f1tenth_raceline(path, src, ("first comment", "second"))
    lines = path.read_text().splitlines()
    assert lines[:3] == ["# first comment", "# second", HEADER]
    back = load_f1tenth_raceline(path)
    assert np.allclose(back.columns(), src.columns(), atol=1e-7)
    assert back.source == str(path)
    assert not list(tmp_path.glob("*.tmp"))


def test_reads_the_f1tenth_collection_format(shared_tracks: Path) -> None:
    line = load_f1tenth_raceline(shared_tracks / "f1tenth" / "Spielberg" / "Spielberg_raceline.csv")
    assert len(line.s_m) > 1000
    assert 0.0 <= line.psi_rad.min() and line.psi_rad.max() < 2 * np.pi
    assert line.vx_mps.max() == pytest.approx(8.0)


@pytest.mark.parametrize(
    ("mutate", "message"),
    [
        (lambda ls: [ls[0], ls[1], "# x_m; y_m", *ls[3:]], "header"),
        (lambda ls: [*ls[:5], "1;2;3", *ls[6:]], "columns"),
        (lambda ls: [*ls[:5], "1;2;3;4;5;6;x", *ls[6:]], "not a number"),
        (lambda ls: [*ls[:5], "nan;2;3;4;5;6;7", *ls[6:]], "non-finite"),
        (lambda ls: [*ls[:3], ls[5], ls[4], *ls[6:]], "increase"),
        (lambda ls: ls[:8], "at least"),
    ],
)
def test_malformed_files_fail_naming_the_file(tmp_path: Path, mutate, message: str) -> None:
    path = tmp_path / "bad.csv"
    write_f1tenth_raceline(path, table())
    path.write_text("\n".join(mutate(path.read_text().splitlines())) + "\n")
    with pytest.raises(TrackError, match=message) as err:
        load_f1tenth_raceline(path)
    assert str(path) in str(err.value)
