"""The default viewer layout of the telemetry recordings (shipped inside every ``.rrd``).

The track view is large on the left with the event log under it; the time series are
stacked on the right (speed, steering, contour error / beta, solver), with tabs for the
message latency, lap times, VESC values and localization / telemetry health. The service
also saves it as ``telemetry.rbl`` beside the recording (``rerun telemetry.rrd
telemetry.rbl`` opens both).
"""

from __future__ import annotations

from pathlib import Path

import rerun.blueprint as rrb


def default_blueprint() -> rrb.Blueprint:
    """The default layout: track view large, time series beside it, events below."""
    track = rrb.Spatial2DView(origin="/world", name="Track")
    events = rrb.TextLogView(origin="/events", name="Events")
    speed = rrb.TimeSeriesView(origin="/speed", name="Speed [m/s]")
    steering = rrb.TimeSeriesView(origin="/steering", name="Steering [rad]")
    tracking = rrb.TimeSeriesView(
        origin="/", contents=["/track_error/**", "/beta/**"], name="Contour error [m], beta, NSC"
    )
    solver = rrb.TimeSeriesView(
        origin="/solver", contents=["/solver/solve_time_ms", "/solver/status_code"],
        name="Solve time [ms], status",
    )
    latency = rrb.TimeSeriesView(origin="/latency", name="Message age [ms]")
    laps = rrb.TimeSeriesView(origin="/laps", name="Laps")
    vesc = rrb.TimeSeriesView(origin="/vesc", name="VESC")
    health = rrb.TimeSeriesView(
        origin="/", contents=["/health/**", "/telemetry/**"], name="Health"
    )
    return rrb.Blueprint(
        rrb.Horizontal(
            rrb.Vertical(track, events, row_shares=[4, 1]),
            rrb.Vertical(
                speed,
                steering,
                tracking,
                solver,
                rrb.Tabs(latency, laps, vesc, health),
                row_shares=[1, 1, 1, 1, 1],
            ),
            column_shares=[3, 2],
        ),
        collapse_panels=True,
    )


def save_blueprint(path: str | Path, app_id: str = "racestack") -> Path:
    """Write the default layout to a ``.rbl`` file for application `app_id`; returns the path."""
    path = Path(path)
    default_blueprint().save(app_id, str(path))
    return path
