"""The default viewer layout of the telemetry recordings (shipped inside every ``.rrd``), as data.

Left: the **Track** view (map frame, north = +y up, x right) with, under it, the event log
(warnings first in view; the services' by-design "overwritten" drop reports summarised, the
raw ones in their own tab), a **Now** panel (beta, NSC, speed, lap, solver of the newest
plan: the text that used to sit over the car) and the lap times. Right: one time-series
panel per quantity and unit (speed, steering, contour error, beta / NSC), then two tab
groups (solver, message age, state age; pose sigmas, VESC, telemetry counters).

* North up: a Rerun 2D view draws +y DOWN (image convention; ``ViewCoordinates`` has no
  effect in 2D views in rerun 0.41), which mirrors the map top to bottom (a counter-clockwise
  race looks clockwise). The recorder logs the static transform ``MAP_TO_VIEW`` (a scale of
  -1 on y) on ``world`` and the track view's origin is the root, so every ``world/**``
  drawing is shown mirrored back: +y (north) up, +x right, as in the paper's figures. The
  data stays in the map frame (``racestack report`` reads it unchanged).
* Legends are off where the panel title names its series and their colours (the colours
  mean the same source everywhere: blue the stack's state, orange the command / plan,
  green odometry, grey the simulator truth, purple progress / NSC); on, top left, only in
  the tabs with many keys (message age, VESC, telemetry).
* Every live time series shows the same sliding window, the last ``WINDOW_S`` seconds before
  the time cursor, on both timelines; the lap panels show the whole run. The time panel
  starts ``following`` (a recording opens at its newest time, on the race; a live view
  follows the newest data).

The service also saves the layout as ``telemetry.rbl`` beside the recording (``rerun
telemetry.rrd telemetry.rbl`` opens both).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import rerun.blueprint as rrb
from rerun.blueprint.api import Container, View
from rerun.blueprint.encodings import TextLogColumn

#: Sliding window of every time series but the laps [s before the time cursor].
WINDOW_S = 30.0
#: Timelines the windows apply to (``recorder.WALL_TIME``, ``recorder.SIM_TIME``).
TIMELINES = ("wall_time", "sim_time")
#: The map-to-view transform logged (static) on ``MAP_ENTITY``: a scale of (1, -1, 1).
MAP_TO_VIEW_SCALE = (1.0, -1.0, 1.0)
MAP_ENTITY = "world"
#: Entity of the "Now" text panel (a ``TextDocument``).
NOW_ENTITY = "now"
#: Raw overwritten-drop reports (debug level), outside the main event log.
DROPS_ENTITY = "events/drops"

#: Colours of the series (RGB or RGBA), one meaning each in every panel.
STATE_BLUE = (60, 140, 255)
CMD_ORANGE = (255, 140, 0, 170)
ODOM_GREEN = (0, 200, 120)
TRUTH_GREY = (235, 235, 235)
PURPLE = (200, 90, 230)
RED = (240, 70, 70)


@dataclass(frozen=True)
class SeriesStyle:
    """How one scalar entity is drawn: a line (width in UI points) or points (marker size)."""

    name: str  #: short legend / tooltip name
    color: tuple[int, ...]
    width: float = 1.5
    points: bool = False  #: sporadic data: points, no line through the gaps


#: Style of every scalar entity with a fixed name (``latency/*`` are all ``LATENCY_STYLE``).
SERIES_STYLES: dict[str, SeriesStyle] = {
    "speed/measured": SeriesStyle("state", STATE_BLUE, 2.0),
    "speed/commanded": SeriesStyle("cmd", CMD_ORANGE, 5.0),
    "speed/odom": SeriesStyle("odom", ODOM_GREEN, 1.0, points=True),
    "speed/truth": SeriesStyle("truth", TRUTH_GREY, 1.0),
    "speed/progress": SeriesStyle("v_p", PURPLE, 1.5),
    "steering/measured": SeriesStyle("state", STATE_BLUE, 2.0),
    "steering/commanded": SeriesStyle("cmd", CMD_ORANGE, 5.0),
    "steering/odom": SeriesStyle("odom", ODOM_GREEN, 1.0, points=True),
    "steering/truth": SeriesStyle("truth", TRUTH_GREY, 1.0),
    "track_error/e_con": SeriesStyle("plan", RED, 1.5),
    "track_error/e_con_truth": SeriesStyle("truth", TRUTH_GREY, 1.0),
    "beta/beta": SeriesStyle("beta", ODOM_GREEN, 1.5),
    "beta/nsc": SeriesStyle("NSC", PURPLE, 1.5),
    "solver/solve_time_ms": SeriesStyle("solve time", RED, 1.0),
    "solver/status_code": SeriesStyle("solver status", CMD_ORANGE[:3], 1.5),
    "health/state_valid": SeriesStyle("state valid", STATE_BLUE, 1.5),
    "health/state_age_ms": SeriesStyle("state age", STATE_BLUE, 1.0),
    "health/pose_sigma_x_m": SeriesStyle("x", STATE_BLUE, 1.5),
    "health/pose_sigma_y_m": SeriesStyle("y", ODOM_GREEN, 1.5),
    "health/pose_sigma_yaw_rad": SeriesStyle("yaw", PURPLE, 1.5),
    "laps/lap_time_s": SeriesStyle("lap time", STATE_BLUE, 6.0, points=True),
    "laps/mean_speed_mps": SeriesStyle("mean speed", ODOM_GREEN, 6.0, points=True),
}
#: Message age per key: points (events are sporadic; a line would join far-apart keys).
LATENCY_STYLE = SeriesStyle("", STATE_BLUE, 1.5, points=True)


@dataclass(frozen=True)
class Panel:
    """One time-series panel: title, entity queries, legend, y range, sliding window."""

    name: str
    contents: tuple[str, ...]
    legend: bool = False
    y_range: tuple[float, float] | None = None
    window: bool = True  #: the last WINDOW_S before the cursor (False: the whole run)


#: The stacked panels of the right column, one quantity and unit each.
MAIN_PANELS = (
    Panel("Speed [m/s]: blue state, orange cmd, green odom, grey truth, purple v_p",
          ("/speed/**",)),
    Panel("Steering [rad]: orange cmd (wide), blue state, grey truth, green odom (dots)",
          ("/steering/**",)),
    Panel("Contour error [m]: red plan, grey truth", ("/track_error/**",)),
    Panel("beta, NSC [-]: green beta, purple NSC", ("/beta/**",), y_range=(-0.05, 1.05)),
)
#: First tab group of the right column.
SOLVER_TABS = (
    Panel("Solve time [ms]", ("/solver/solve_time_ms",)),
    Panel("Solver status: 0 ok, 1 fallback, 2 braking, 3 recovering",
          ("/solver/status_code",), y_range=(-0.2, 3.2)),
    Panel("Message age [ms]", ("/latency/**",), legend=True),
    Panel("State age [ms]", ("/health/state_age_ms",)),
)
#: Second tab group of the right column.
HEALTH_TABS = (
    Panel("Pose sigma [m]: blue x, green y", ("/health/pose_sigma_x_m", "/health/pose_sigma_y_m")),
    Panel("Yaw sigma [rad]", ("/health/pose_sigma_yaw_rad",)),
    Panel("State valid [1 yes, 0 no]", ("/health/state_valid",), y_range=(-0.1, 1.1)),
    Panel("VESC", ("/vesc/**",), legend=True),
    Panel("Telemetry [messages]", ("/telemetry/**",), legend=True),
)
#: The lap panels under the track (sporadic: points over the whole run).
LAP_TABS = (
    Panel("Lap time [s]", ("/laps/lap_time_s",), window=False),
    Panel("Lap mean speed [m/s]", ("/laps/mean_speed_mps",), window=False),
)
ALL_PANELS = MAIN_PANELS + SOLVER_TABS + HEALTH_TABS + LAP_TABS


def sliding_window(seconds: float = WINDOW_S,
                   timelines: Sequence[str] = TIMELINES) -> list[rrb.VisibleTimeRange]:
    """The visible range "the last `seconds` before the time cursor" on every timeline."""
    return [
        rrb.VisibleTimeRange(
            tl,
            start=rrb.TimeRangeBoundary.cursor_relative(seconds=-seconds),
            end=rrb.TimeRangeBoundary.cursor_relative(),
        )
        for tl in timelines
    ]


def series_view(panel: Panel) -> rrb.TimeSeriesView:
    """The ``TimeSeriesView`` of `panel`."""
    return rrb.TimeSeriesView(
        origin="/",
        contents=list(panel.contents),
        name=panel.name,
        plot_legend=rrb.PlotLegend(corner="LeftTop", visible=panel.legend),
        axis_y=rrb.ScalarAxis(range=panel.y_range) if panel.y_range else None,
        time_ranges=sliding_window() if panel.window else None,
    )


#: Map bounds (x_min, x_max, y_min, y_max) [m] of the track the view opens on.
Bounds = tuple[float, float, float, float]
#: Margin around the track in the view it opens on [m].
BOUNDS_MARGIN_M = 1.0


def view_bounds(bounds: Bounds, margin_m: float = BOUNDS_MARGIN_M) -> rrb.VisualBounds2D:
    """The track view's visual bounds of map bounds `bounds` plus `margin_m`, in the view's
    (flipped) coordinates: map y in [y_min, y_max] is view y in [-y_max, -y_min]."""
    x0, x1, y0, y1 = bounds
    sy = MAP_TO_VIEW_SCALE[1]
    ys = sorted((sy * y0, sy * y1))
    return rrb.VisualBounds2D(x_range=(x0 - margin_m, x1 + margin_m),
                              y_range=(ys[0] - margin_m, ys[1] + margin_m))


def track_view(bounds: Bounds | None = None) -> rrb.Spatial2DView:
    """The map view: origin the root (so ``MAP_TO_VIEW_SCALE`` on ``world`` applies),
    opening on the track's `bounds` (None: fit everything, lidar points included)."""
    return rrb.Spatial2DView(origin="/", contents=[f"/{MAP_ENTITY}/**"], name="Track (north up)",
                             visual_bounds=view_bounds(bounds) if bounds else None)


def event_views() -> tuple[rrb.TextLogView, rrb.TextLogView]:
    """The event log (without the raw drop reports) and the raw drop reports."""
    columns = rrb.TextLogColumns(  # the recording's timeline, level and text (no entity)
        text_log_columns=[TextLogColumn("loglevel"), TextLogColumn("body"),
                          TextLogColumn("entitypath", visible=False)],
    )
    events = rrb.TextLogView(origin="/events",
                             contents=["/events/**", f"- /{DROPS_ENTITY}/**"],
                             name="Events", columns=columns)
    drops = rrb.TextLogView(origin=f"/{DROPS_ENTITY}", name="Drop reports (raw)",
                            columns=columns)
    return events, drops


def default_blueprint(bounds: Bounds | None = None) -> rrb.Blueprint:
    """The default layout (see the module docstring); the track view opens on the map
    `bounds` (x_min, x_max, y_min, y_max) [m] of the track when given."""
    events, drops = event_views()
    now = rrb.TextDocumentView(origin=f"/{NOW_ENTITY}", name="Now")
    laps = rrb.Tabs(*(series_view(p) for p in LAP_TABS))
    bottom = rrb.Horizontal(
        rrb.Tabs(events, drops),
        rrb.Vertical(now, laps, row_shares=[1, 2]),
        column_shares=[3, 2],
    )
    right = rrb.Vertical(
        *(series_view(p) for p in MAIN_PANELS),
        rrb.Tabs(*(series_view(p) for p in SOLVER_TABS)),
        rrb.Tabs(*(series_view(p) for p in HEALTH_TABS)),
    )
    return rrb.Blueprint(
        rrb.Horizontal(
            rrb.Vertical(track_view(bounds), bottom, row_shares=[3, 2]),
            right,
            column_shares=[3, 2],
        ),
        rrb.TimePanel(state="collapsed", play_state="following"),
        collapse_panels=True,
    )


def save_blueprint(path: str | Path, app_id: str = "racestack",
                   bounds: Bounds | None = None) -> Path:
    """Write the default layout (track view on `bounds`) to a ``.rbl`` file for application
    `app_id`; returns the path."""
    path = Path(path)
    default_blueprint(bounds).save(app_id, str(path))
    return path


def iter_views(node: rrb.Blueprint | Container | View) -> list[View]:
    """Every view in a blueprint, container or view, depth first."""
    if isinstance(node, rrb.Blueprint):
        node = node.root_container
    if isinstance(node, View):
        return [node]
    return [v for child in node.contents for v in iter_views(child)]
