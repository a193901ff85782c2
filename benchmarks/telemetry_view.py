"""Screenshot of the default Rerun layout of a recording, for looking at it (issue 22).

A manual check, no test depends on it: it needs the Rerun viewer to render headless, i.e. a
Vulkan driver (a GPU, or Mesa's software lavapipe: ``apt-get install mesa-vulkan-drivers``;
``WGPU_BACKEND=vulkan``, the default here). Run from the project root:

    .venv/bin/python -m benchmarks.telemetry_view runs/<time> --out view.png
    .venv/bin/python -m benchmarks.telemetry_view --demo 40 --out view.png

``--demo S`` first records S seconds of the synthetic lap stream (``services.telemetry.
synthetic``) through the real ``Recorder`` with the default layout, plus what a live stack
adds to the event log: every second a by-design "dropped N valid messages ... overwritten"
report from two services and, every 9 s, a solver-fallback warning. The viewer opens the
recording (its time panel following: the cursor at the newest time) and saves the window.
For the live view see ``benchmarks.telemetry_load --serve --viewer-lag --screenshot PNG``.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

from benchmarks.telemetry_load import HeadlessViewer


def record_demo(path: Path, seconds: float, track_spec: str = "builtin:paperlike") -> Path:
    """Record `seconds` of the synthetic stream (wall-clock stamps ending now) to `path`."""
    from services.telemetry.recorder import Recorder
    from services.telemetry.recording import open_segment, track_bounds
    from services.telemetry.synthetic import lap_stream
    from shared.config import RacestackConfig
    from shared.curvature import track_profile
    from shared.keys import EVENTS_LOG
    from shared.messages import LogEvent
    from shared.track import load_track

    cfg = RacestackConfig()
    track = load_track(track_spec)
    rec = open_segment(cfg.telemetry, path, "view-demo", track_bounds(track))
    recorder = Recorder(rec, cfg.telemetry)
    recorder.log_static(track, track_profile(track, cfg.curvature), {"car": "demo"})
    t0 = time.time() - seconds
    total, next_report = 0, 1.0
    for t, suffix, msg in lap_stream(track, seconds, t0_s=t0, speed_mps=3.3):
        recorder.handle(suffix, msg, t0 + t + 0.003)
        recorder.periodic(t0 + t)
        if t < next_report:
            continue
        next_report += 1.0
        for source in ("planner", "localization_bridge"):
            total += 3
            recorder.handle(EVENTS_LOG, LogEvent(
                stamp_s=t0 + t, level="info", source=source,
                text=f"dropped 3 valid messages (total {total}): racestack/demo/vehicle/pose "
                     "overwritten x2, racestack/demo/state overwritten x1"), t0 + t)
        if int(t) % 9 == 0:
            recorder.handle(EVENTS_LOG, LogEvent(
                stamp_s=t0 + t, level="warning", source="planner",
                text="solver fallback: Maximum_Iterations_Exceeded (1 failures in a row)"),
                t0 + t)
    recorder.close()
    rec.flush(timeout_sec=5.0)
    rec.disconnect()
    return path


def main(argv: list[str] | None = None) -> int:
    """Record the demo if asked, open the recording in a headless viewer, save the PNG."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("run", nargs="?", help="a run folder or .rrd files' folder (or --demo)")
    ap.add_argument("--demo", type=float, metavar="S", help="record S s of a demo first")
    ap.add_argument("--out", required=True, help="the PNG to write")
    ap.add_argument("--window", default="1600x1000", help="viewer size in UI points")
    args = ap.parse_args(argv)
    with tempfile.TemporaryDirectory(prefix="telemetry-view-") as tmp:
        work = Path(tmp)
        if args.demo:
            files = [record_demo(work / "telemetry.0000.rrd", args.demo)]
        elif args.run:
            from services.telemetry import find_segments

            files = find_segments(Path(args.run))
        else:
            ap.error("give a run folder or --demo S")
        viewer = HeadlessViewer(work, args.window)
        try:
            viewer.open(*(str(f) for f in files))
            out = viewer.screenshot(Path(args.out).resolve())
        finally:
            viewer.stop()
    print(f"screenshot: {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
