"""Fixtures of the telemetry tests: a small circular track, Rerun's config dirs, a watchdog."""

from __future__ import annotations

import faulthandler
import math
import os
import sys
from collections.abc import Iterator
from pathlib import Path

import pytest

from shared.net import free_loopback_port

#: Hard limit of one telemetry test [s]: past it the stacks are dumped and the run ends.
TEST_DEADLINE_S = 50.0


@pytest.fixture(autouse=True)
def _tele_watchdog() -> Iterator[None]:
    """End the test process with a traceback dump if one test runs past the deadline."""
    faulthandler.dump_traceback_later(TEST_DEADLINE_S, exit=True, file=sys.stderr)
    try:
        yield
    finally:
        faulthandler.cancel_dump_traceback_later()


@pytest.fixture(scope="session", autouse=True)
def _tele_rerun_dirs(tmp_path_factory: pytest.TempPathFactory) -> None:
    """Rerun's config and data (analytics) in a temp dir, for this process and children."""
    base = tmp_path_factory.mktemp("rerun-home")
    for name in ("XDG_CONFIG_HOME", "XDG_DATA_HOME"):
        (base / name).mkdir()
        os.environ[name] = str(base / name)


def write_circle_track(path: Path, radius_m: float = 1.2, n: int = 120,
                       width_m: float = 0.4) -> Path:
    """An F1TENTH centreline CSV of a counter-clockwise circle (lap 2 pi r) [m]."""
    lines = ["# x_m, y_m, w_tr_right_m, w_tr_left_m"]
    for i in range(n):
        a = 2 * math.pi * i / n - math.pi / 2
        lines.append(f"{radius_m * math.cos(a):.6f}, {radius_m * math.sin(a) + radius_m:.6f}, "
                     f"{width_m}, {width_m}")
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")
    return path


@pytest.fixture(scope="module")
def tele_circle_csv(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A small circular track (7.54 m: a lap takes about 2.2 s at 3.5 m/s)."""
    return write_circle_track(tmp_path_factory.mktemp("track") / "circle_centerline.csv")


@pytest.fixture
def tele_port() -> int:
    """A free loopback port."""
    return free_loopback_port()
