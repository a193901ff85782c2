"""``racestack report`` marks where the recorded car left the track (issue #22): the
off-track lap events' times looked up in the recorded position, on hand-made data (no
recording file, no processes)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from services.tools.report import RecordingData, method_run
from shared.config.root import RacestackConfig
from shared.curvature import track_profile
from shared.track import load_track


def test_report_run_has_the_off_track_positions() -> None:
    track = load_track("builtin:paperlike")
    profile = track_profile(track, RacestackConfig().curvature)
    t = np.arange(0.0, 10.0, 0.05)
    s = np.mod(2.0 * t, track.length_m)
    xy = np.array([track.point_at(v) for v in s])
    data = RecordingData(path=Path("test.rrd"))
    data.series = {"truth/x_m": (t, xy[:, 0]), "truth/y_m": (t, xy[:, 1]),
                   "truth/s_m": (t, s), "speed/truth": (t, np.full(t.size, 2.0)),
                   "track_error/e_con_truth": (t, np.zeros(t.size))}
    data.rows = {"events/lap": [
        {"kind": "start", "lap": 0, "t_s": 0.5},
        {"kind": "off_track", "lap": 0, "t_s": 3.0},
        {"kind": "back_on_track", "lap": 0, "t_s": 3.4},
    ]}
    run = method_run(data, track, profile)
    assert len(run.off_track_xy) == 1
    assert run.off_track_xy[0] == pytest.approx(tuple(track.point_at(6.0)), abs=1e-9)
