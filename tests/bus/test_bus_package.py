"""The bus as a package: the pure modules and the fake bus need no zenoh; the session's names
are re-exported by ``shared.bus`` on first use."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

import shared.bus
import shared.bus.session
from shared.bus import SeqTracker, is_put

ROOT = Path(__file__).resolve().parents[2]
PROBE = Path(__file__).with_name("zenoh_free_probe.py")


def test_pure_modules_and_fake_bus_work_without_zenoh() -> None:
    """In a fresh interpreter where ``import zenoh`` fails (a meta-path finder), the pure
    modules and the fake bus import and work, and zenoh is never asked for."""
    path = [str(ROOT), *filter(None, [os.environ.get("PYTHONPATH")])]
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(path)}
    proc = subprocess.run(
        [sys.executable, str(PROBE)], cwd=ROOT, env=env, capture_output=True, text=True,
        timeout=60, stdin=subprocess.DEVNULL,
    )  # fmt: skip
    assert proc.returncode == 0, proc.stdout + proc.stderr
    assert proc.stdout.strip().splitlines()[-1] == "zenoh-free: ok"


def test_every_public_name_resolves_and_the_session_names_are_the_sessions() -> None:
    for name in shared.bus.__all__:
        assert getattr(shared.bus, name) is not None, name
        assert name in dir(shared.bus)
    for name in ("Bus", "BusOpenError", "zenoh_config", "open_session", "enable_zenoh_log"):
        assert getattr(shared.bus, name) is getattr(shared.bus.session, name)
    with pytest.raises(AttributeError):
        _ = shared.bus.no_such_name  # type: ignore[attr-defined]


def test_is_put_recognises_zenoh_sample_kinds() -> None:
    zenoh = pytest.importorskip("zenoh")
    assert is_put(zenoh.SampleKind.PUT)
    assert not is_put(zenoh.SampleKind.DELETE)


def test_seq_tracker_counts_gaps_per_key_and_restarts() -> None:
    seq = SeqTracker()
    assert [seq.gap("a", s) for s in (0, 1, 4)] == [0, 0, 2]
    assert seq.gap("b", 7) == 0  # the first record of a key: no gap
    assert seq.gap("a", 0) == 0 and seq.gap("a", 2) == 1  # a restarted publisher
