"""The viewer layout as data (views, origins, north up, sliding windows, legends) and the
telemetry's load shedding as pure functions (decimation, drop-line aggregation, queue age)."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import rerun as rr
import rerun.blueprint as rrb

from services.telemetry import blueprint as bp
from services.telemetry.inbox import Inbox
from services.telemetry.recorder import Recorder, car_body, now_text
from services.telemetry.rrd_files import read_store
from services.telemetry.shedding import Decimator, DropSummary, parse_overwritten_drops
from shared.config.methods import CIMPCC
from shared.config.telemetry import TelemetrySettings
from shared.keys import EVENTS_LOG, LAP, STATE
from shared.messages import LapEvent, LogEvent, Plan, State


def _views() -> dict[str, Any]:
    return {v.name: v for v in bp.iter_views(bp.default_blueprint())}


def _prop(view: Any, name: str) -> list[Any] | None:
    """The values of a view property's first component (None when unset)."""
    arch = view.properties.get(name)
    if arch is None:
        return None
    for field_name in ("ranges", "visible", "range"):
        batch = getattr(arch, field_name, None)
        if batch is not None:
            return batch.as_arrow_array().to_pylist()
    return None


# ---------------------------------------------------------------------------- layout
def test_view_layout_views_and_origins() -> None:
    views = _views()
    track = views["Track (north up)"]
    assert isinstance(track, rrb.Spatial2DView)
    # the root, so that the static flip logged ON world applies to every world/** drawing
    assert track.origin == "/" and track.contents == [f"/{bp.MAP_ENTITY}/**"]
    events = views["Events"]
    assert isinstance(events, rrb.TextLogView) and events.origin == "/events"
    assert f"- /{bp.DROPS_ENTITY}/**" in events.contents  # raw drop reports kept out
    assert views["Drop reports (raw)"].origin == f"/{bp.DROPS_ENTITY}"
    assert isinstance(views["Now"], rrb.TextDocumentView) and views["Now"].origin == "/now"
    series = [v for v in views.values() if isinstance(v, rrb.TimeSeriesView)]
    assert len(series) == len(bp.ALL_PANELS)
    # one panel per quantity: no entity query in two panels
    queries = [q for v in series for q in v.contents]
    assert len(queries) == len(set(queries))
    assert views["Lap time [s]"].contents == ["/laps/lap_time_s"]
    assert views["Lap mean speed [m/s]"].contents == ["/laps/mean_speed_mps"]
    assert views["Contour error [m]: red plan, grey truth"].contents == ["/track_error/**"]
    assert views["beta, NSC [-]: green beta, purple NSC"].contents == ["/beta/**"]


def test_view_every_live_series_has_the_same_sliding_window() -> None:
    for panel in bp.ALL_PANELS:
        ranges = _prop(bp.series_view(panel), "VisibleTimeRanges")
        if not panel.window:
            assert ranges is None, panel.name  # the laps: the whole run
            continue
        assert ranges is not None, panel.name
        assert sorted(r["timeline"] for r in ranges) == sorted(bp.TIMELINES)
        for r in ranges:
            assert r["range"] == {"start": -int(bp.WINDOW_S * 1e9), "end": 0}, panel.name
    assert [p.window for p in bp.LAP_TABS] == [False, False]


def test_view_legends_off_but_where_many_keys_share_a_panel() -> None:
    with_legend = {p.name for p in bp.ALL_PANELS if p.legend}
    assert with_legend == {"Message age [ms]", "VESC", "Telemetry [messages]"}
    for panel in bp.ALL_PANELS:
        assert _prop(bp.series_view(panel), "PlotLegend") == [panel.legend]


def test_view_series_have_one_short_name_each_and_sporadic_ones_are_points() -> None:
    names: dict[str, list[str]] = {}
    for entity, style in bp.SERIES_STYLES.items():
        assert 0 < len(style.name) <= 13, entity
        names.setdefault(entity.split("/")[0], []).append(style.name)
    for group, group_names in names.items():
        assert len(group_names) == len(set(group_names)), group
    for entity in ("laps/lap_time_s", "laps/mean_speed_mps"):
        assert bp.SERIES_STYLES[entity].points
    assert not bp.SERIES_STYLES["solver/status_code"].points  # a thin line, no band of dots
    assert bp.LATENCY_STYLE.points
    # the four steering series stay apart when equal: widths / points differ
    steer = [bp.SERIES_STYLES[f"steering/{k}"] for k in ("commanded", "measured", "truth",
                                                         "odom")]
    assert len({(s.width, s.points, s.color) for s in steer}) == 4


def test_view_map_is_drawn_north_up() -> None:
    """The 2D view draws +y down; the flip on world maps map north (+y) to screen up and
    keeps a counter-clockwise loop counter-clockwise on screen (x right)."""
    scale = np.asarray(bp.MAP_TO_VIEW_SCALE[:2])

    def screen(p: np.ndarray) -> np.ndarray:  # view coordinates -> screen (y down = row)
        v = p * scale
        return np.array([v[0], v[1]])  # the 2D view shows +y downward

    north, east = screen(np.array([0.0, 1.0])), screen(np.array([1.0, 0.0]))
    assert north[1] < 0 and north[0] == 0  # up on screen
    assert east[0] > 0 and east[1] == 0  # right on screen
    loop = np.array([[1, 0], [0, 1], [-1, 0], [0, -1]], dtype=float)  # CCW in the map
    s = np.array([screen(p) for p in loop])
    signed_area_screen = 0.5 * np.sum(s[:, 0] * np.roll(s[:, 1], -1)
                                      - np.roll(s[:, 0], -1) * s[:, 1])
    # on a y-down screen a loop that LOOKS counter-clockwise has a negative signed area
    assert signed_area_screen < 0


def test_view_opens_on_the_track_in_flipped_coordinates() -> None:
    vb = bp.view_bounds((-2.0, 10.0, 1.0, 5.0), margin_m=0.5)
    rng = vb.range.as_arrow_array().to_pylist()[0]
    assert rng["x_range"] == [-2.5, 10.5]
    assert rng["y_range"] == [-5.5, -0.5]  # map y 1..5 is view y -5..-1
    track = bp.track_view((-2.0, 10.0, 1.0, 5.0))
    assert "VisualBounds2D" in track.properties
    assert "VisualBounds2D" not in bp.track_view().properties


def test_view_time_panel_follows_the_newest_data() -> None:
    tp = bp.default_blueprint().time_panel
    assert tp is not None
    assert "following" in repr(tp.play_state).lower() or tp.play_state is not None


def test_view_recording_holds_the_flip_the_car_body_and_no_label(tmp_path: Path) -> None:
    path = tmp_path / "view.rrd"
    rec = rr.RecordingStream("racestack-test", recording_id="view-test")
    rec.set_sinks(rr.FileSink(str(path)))
    r = Recorder(rec, TelemetrySettings())
    t0 = 1.7e9
    for k in range(10):
        t = t0 + 0.025 * k
        r.handle(STATE, State(stamp_s=t, x_m=1.0, y_m=2.0, yaw_rad=0.5, speed_mps=2.0,
                              yaw_rate_radps=0.0, steering_rad=0.0, source_stamp_s=t,
                              valid=True), t + 0.001)
        r.handle("planner/plan", _plan(t), t + 0.001)
    r.close()
    rec.flush(timeout_sec=5.0)
    rec.disconnect()
    store, _ = read_store(path)
    flip = car = beta = now = None
    for chunk in store.stream():
        batch = chunk.to_record_batch()
        e = chunk.entity_path.lstrip("/")
        cols = set(batch.schema.names)
        if e == bp.MAP_ENTITY and any("Transform3D:scale" in c for c in cols):
            flip = batch.column("Transform3D:scale").to_pylist()[0][0]
        elif e == "world/car" and "LineStrips2D:strips" in cols and not chunk.is_static:
            car = batch.column("LineStrips2D:strips").to_pylist()[0]
        elif e == "world/car_beta" and chunk.is_static:
            beta = batch
        elif e == bp.NOW_ENTITY and "TextDocument:text" in cols:
            now = batch.column("TextDocument:text").to_pylist()[0][0]
    assert flip is not None and tuple(flip) == bp.MAP_TO_VIEW_SCALE
    assert car is not None and len(car) == 2  # outline box + body
    body = np.asarray(car[1])
    assert np.allclose(body.mean(axis=0), [1.0, 2.0])
    assert beta is not None and "Points2D:labels" not in beta.schema.names  # no label over it
    assert now is not None and "beta 0.30" in now and "v 2.00 m/s" in now


def _plan(t: float) -> Plan:
    n = 4
    horizon = np.column_stack([np.linspace(1.0, 2.0, n + 1), np.full(n + 1, 2.0),
                               np.zeros(n + 1), np.linspace(0.0, 1.0, n + 1)])
    return Plan(stamp_s=t, horizon=horizon, inputs=np.full((n, 3), 1.0), beta=np.full(n, 0.3),
                status="solved", solver_status="ok", iterations=3, solve_time_ms=4.0,
                method=CIMPCC, s_m=0.5, e_con_m=0.01, source_stamp_s=t,
                consecutive_failures=0)


def test_view_car_body_fills_the_footprint() -> None:
    body = car_body(0.0, 0.0, math.pi / 2, 0.58, 0.31)
    # a line 0.31 m wide with round ends along the heading: 0.58 m long in all
    assert np.allclose(body[:, 0], 0.0)
    assert np.ptp(body[:, 1]) + 0.31 == pytest.approx(0.58)
    assert np.allclose(car_body(1, 2, 0.0, 0.2, 0.4), [[1, 2], [1, 2]])  # shorter than wide


def test_view_now_text() -> None:
    text = now_text(0.28, 0.51, _plan(0.0), 2, 3.2)
    assert text.splitlines()[0] == "beta 0.28   NSC 0.51"
    assert "lap 2" in text and f"{CIMPCC} solved 4.0 ms" in text
    assert "NSC -" in now_text(0.28, None, _plan(0.0), 0, None)


# ---------------------------------------------------------------------------- shedding
def test_shed_decimator_keeps_at_most_max_hz() -> None:
    d = Decimator(30.0)
    kept = {hz: sum(d.due(f"k{hz}", i / hz) for i in range(int(10 * hz)))
            for hz in (100.0, 50.0, 40.0, 20.0, 10.0)}
    assert kept[100.0] == 300 and kept[50.0] == 300 and kept[40.0] == 300
    assert kept[20.0] == 200 and kept[10.0] == 100  # slower keys keep everything
    assert d.kept + d.skipped == sum(int(10 * hz) for hz in (100, 50, 40, 20, 10))
    every = Decimator(0.0)
    assert all(every.due("k", i / 1000) for i in range(1000))
    again = Decimator(30.0)
    assert again.due("k", 100.0) and not again.due("k", 100.001)
    assert again.due("k", 5.0)  # stamps went back (a restarted simulation): kept
    with pytest.raises(ValueError):
        Decimator(-1.0)


def test_shed_parse_overwritten_drop_lines() -> None:
    line = ("dropped 5 valid messages (total 9): racestack/car0/vehicle/pose overwritten x3, "
            "racestack/car0/state overwritten x2")
    assert parse_overwritten_drops(line) == {"racestack/car0/vehicle/pose": 3,
                                             "racestack/car0/state": 2}
    stale = "dropped 2 valid messages (total 2): racestack/car0/state stale x2"
    assert parse_overwritten_drops(stale) is None  # a warning: stays in the event log
    mixed = ("dropped 3 valid messages (total 3): racestack/car0/state overwritten x1, "
             "racestack/car0/state stale x2")
    assert parse_overwritten_drops(mixed) is None
    assert parse_overwritten_drops("rejected 3 messages (total 7): k not_msgpack x3") is None
    assert parse_overwritten_drops("lap 1: 12.3 s") is None


def test_shed_drop_summary_one_line_per_period_per_source() -> None:
    agg = DropSummary(10.0)
    out = []
    for k in range(25):  # one report a second from two services
        for src in ("planner", "localization_bridge"):
            s = agg.add(src, 100.0 + k, {"racestack/car0/vehicle/pose": 2})
            if s is not None:
                out.append(s)
    assert [(s.source, s.lines, s.total) for s in out] == [
        ("planner", 11, 22), ("localization_bridge", 11, 22),
        ("planner", 11, 22), ("localization_bridge", 11, 22)]
    assert out[0].start_s == 100.0 and out[0].end_s == 110.0
    assert "[planner] 22 valid messages overwritten in 10.0 s (11 reports" in out[0].text()
    assert agg.due(121.0) == []  # the open windows started at 122
    late = agg.due(200.0)
    assert sorted(s.source for s in late) == ["localization_bridge", "planner"]
    assert all(s.lines == 3 for s in late)
    assert agg.flush() == []
    agg.add("planner", 5.0, {"k": 1})
    assert [s.total for s in agg.flush()] == [1]


def test_shed_recorder_summarises_drop_lines_and_keeps_warnings() -> None:
    class Sink:
        def __init__(self) -> None:
            self.logs: list[tuple[str, Any]] = []

        def log(self, entity: str, *parts: Any, **_kw: Any) -> None:
            self.logs.extend((entity, p) for p in parts)

        def __getattr__(self, _name: str) -> Any:
            return lambda *a, **k: None

    sink = Sink()
    t0 = 1.7e9
    ahead = [t0 + 1000.0]  # a wall clock far ahead of the stamps closes no window early
    r = Recorder(sink, TelemetrySettings(drop_summary_interval_s=10.0),  # type: ignore[arg-type]
                 clock=lambda: ahead[0])
    for k in range(25):
        ahead[0] += 1.0
        r.periodic()
        r.handle(EVENTS_LOG, LogEvent(
            stamp_s=t0 + k, level="info", source="planner",
            text=f"dropped 2 valid messages (total {2 * k + 2}): "
                 "racestack/car0/vehicle/pose overwritten x2"), t0 + k)
    r.handle(EVENTS_LOG, LogEvent(stamp_s=t0 + 25, level="warning", source="planner",
                                  text="solver fallback"), t0 + 25)
    r.handle(LAP, LapEvent(stamp_s=t0 + 26, kind="start", lap=0, off_track_events=0), t0 + 26)
    r.close()
    texts = [(e, p.text.as_arrow_array().to_pylist()[0]) for e, p in sink.logs
             if isinstance(p, rr.TextLog)]
    main = [(e, t) for e, t in texts if not e.startswith(bp.DROPS_ENTITY)]
    raw = [t for e, t in texts if e.startswith(bp.DROPS_ENTITY)]
    assert len(raw) == 25
    summaries = [t for e, t in main if "overwritten in" in t]
    assert len(summaries) == 3  # 0-10, 11-21, the rest at close
    assert sum(int(t.split()[1]) for t in summaries) == 50
    assert any("solver fallback" in t for _, t in main)  # the warning is as it was
    assert not any(t.startswith("[planner] dropped") for _, t in main)


def test_shed_recorder_decimates_series_not_events() -> None:
    class Sink:
        def __init__(self) -> None:
            self.samples: dict[str, int] = {}

        def send_columns(self, entity: str, indexes: Any, columns: Any) -> None:
            self.samples[entity] = self.samples.get(entity, 0) + len(indexes[0].as_arrow_array())

        def __getattr__(self, _name: str) -> Any:
            return lambda *a, **k: None

    sink = Sink()
    r = Recorder(sink, TelemetrySettings(series_max_hz=20.0))  # type: ignore[arg-type]
    t0 = 1.7e9
    for k in range(400):  # 10 s of state at 40 Hz
        t = t0 + k / 40
        r.handle(STATE, State(stamp_s=t, x_m=0.0, y_m=0.0, yaw_rad=0.0, speed_mps=1.0,
                              yaw_rate_radps=0.0, steering_rad=0.0, source_stamp_s=t,
                              valid=True), t)
    for k in range(3):
        r.handle(LAP, LapEvent(stamp_s=t0 + 0.001 * k, kind="lap", lap=k + 1, lap_time_s=5.0,
                               mean_speed_mps=1.0, off_track_events=0), t0)
    r.close()
    assert sink.samples["speed/measured"] == 200 and sink.samples["latency/state"] == 200
    assert sink.samples["laps/lap_time_s"] == 3  # events: every one, even 1 ms apart
    assert r.shed == 200 and r.counts[STATE] == 400


def test_shed_inbox_drops_data_that_waited_too_long() -> None:
    now = [0.0]
    box = Inbox(100, clock=lambda: now[0], max_age_s=1.0)
    for k in range(5):
        now[0] = 0.1 * k
        box.put(STATE, k)  # type: ignore[arg-type]
    box.put(LAP, "event")  # type: ignore[arg-type]
    now[0] = 1.25  # the first three waited more than 1 s
    batch = box.get_batch(0.0)
    assert [i.msg for i in batch] == [3, 4, "event"]  # arrival order
    assert box.dropped() == {STATE: 3}
    with pytest.raises(ValueError):
        Inbox(10, max_age_s=0.0)


def _overloaded_inbox_ages(max_age_s: float | None, seconds: float = 180.0) -> list[float]:
    """Ages [s] of the messages a logging thread gets from a full inbox when 330 msg/s
    arrive (the stack's rates) and it logs only 300 msg/s (starved of CPU); fake clock."""
    now = [0.0]
    box = Inbox(4096, clock=lambda: now[0], max_age_s=max_age_s)
    ages: list[float] = []
    step, arrive, take = 0.02, 330, 300
    for k in range(int(seconds / step)):
        now[0] = k * step
        for i in range(round(arrive * step)):
            now[0] = k * step + i * step / (arrive * step)
            box.put(STATE, k)  # type: ignore[arg-type]
        now[0] = (k + 1) * step
        ages += [now[0] - item.recv_wall_s for item in box.get_batch(0.0, round(take * step))]
    return ages


def test_shed_queue_age_bounds_the_lag_of_a_starved_telemetry() -> None:
    """Why the live view lagged 14-16 s: a full 4096-message inbox at the stack's ~330
    msg/s is 12 s of backlog; with ``max_queue_age_s`` the lag stays under it."""
    bloated = _overloaded_inbox_ages(None)
    assert max(bloated) > 10.0  # the whole queue, 4096 / 330 s, in front of every message
    bounded = _overloaded_inbox_ages(TelemetrySettings().max_queue_age_s)
    assert max(bounded) <= TelemetrySettings().max_queue_age_s + 0.02
