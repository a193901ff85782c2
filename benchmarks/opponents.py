"""Opponent detection and tracking on synthetic scans (issue #24), in one process.

    .venv/bin/python -m benchmarks.opponents [--scenes 40] [--scans 40] [--noise 0.01]

Each of ``--scenes`` seeded scenes on map416 (``../shared/tracks/map416``; the rasterised
built-in ``paperlike`` without it): the ego car and one opponent drive along the centreline
at constant speeds (ego 2-4 m/s, the opponent 0.5 m/s slower to 0.5 m/s faster) with constant
lateral offsets (ego +-0.2 m, opponent +-0.3 m), the opponent starting 1-4.5 m ahead. The
simulator's lidar (``LidarScanner``, 1080 beams over 4.7 rad, ``--noise`` m range noise on
hits) scans at 40 Hz from the true ego pose (no localisation error in here) with the opponent
as a footprint box; ``OpponentDetector`` (with the track as heading hint) and
``OpponentTracker`` run on every scan. Printed:

- recall: scans whose opponent is within 5 m and visible (at least 4 beams end on it) with a
  detection within 0.3 m of its centre;
- position RMS [m] of those detections, and of the confirmed track's position;
- velocity RMS [m/s] of the confirmed track (the one nearest the truth, within 0.3 m) from the
  10th scan of a scene on, against the central-difference truth;
- false positives per scan: detections farther than 0.3 m from the opponent, on the scans
  with it and on the same scans of the empty track;
- the cost per scan of ``detect`` + ``update`` [ms], median / p99 of the wall time and of the
  process CPU time (the latter unaffected by other processes on a shared machine).
"""

from __future__ import annotations

import argparse
import math
import sys
import time

import numpy as np

from benchmarks.particle_filter import map_and_track
from services.localization_bridge.opponents import OpponentDetector, OpponentTracker
from services.simulator.lidar import LidarScanner
from shared.track import Track

RATE_HZ = 40.0
MATCH_M = 0.3
WITHIN_M = 5.0
MIN_BEAMS = 4
SETTLE_SCANS = 10


def _pose(track: Track, s: float, lateral_m: float) -> np.ndarray:
    """(3,) pose at arc length `s` [m], `lateral_m` left of the centreline, along it (the
    direction of the chord over +-5 cm, smooth where the polyline's segments turn)."""
    a, b = track.point_at(s - 0.05), track.point_at(s + 0.05)
    yaw = math.atan2(float(b[1] - a[1]), float(b[0] - a[0]))
    x, y = (float(v) for v in track.point_at(s))
    return np.array([x - lateral_m * math.sin(yaw), y + lateral_m * math.cos(yaw), yaw])


def _noisy(ranges: np.ndarray, rng: np.random.Generator, std: float, rmax: float) -> np.ndarray:
    hit = ranges < rmax
    noisy = np.clip(ranges + rng.normal(0.0, std, ranges.shape), 0.0, rmax)
    return np.where(hit, noisy, ranges)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scenes", type=int, default=40, help="seeded scenes (default 40)")
    ap.add_argument("--scans", type=int, default=40, help="scans per scene at 40 Hz (default 40)")
    ap.add_argument("--noise", type=float, default=0.01, help="range noise std [m] (0.01)")
    ap.add_argument("--seed", type=int, default=0, help="first seed (default 0)")
    a = ap.parse_args(argv)
    grid, track, name = map_and_track()
    sc = LidarScanner(grid, beams=1080, fov_rad=4.7, range_max_m=30.0)
    rmax = sc.range_max_m
    det = OpponentDetector(grid, track=track)
    dt = 1.0 / RATE_HZ
    visible = found = 0
    pos_err: list[float] = []
    trk_err: list[float] = []
    vel_err: list[float] = []
    fp = fp_empty = n_scans = 0
    cost_ms: list[float] = []
    cpu_ms: list[float] = []
    for k in range(a.scenes):
        rng = np.random.default_rng(a.seed + k)
        s_e = rng.uniform(0.0, track.length_m)
        v_e = rng.uniform(2.0, 4.0)
        v_o = v_e + rng.uniform(-0.5, 0.5)
        ds = rng.uniform(1.0, 4.5)
        lat_e, lat_o = rng.uniform(-0.2, 0.2), rng.uniform(-0.3, 0.3)
        tracker = OpponentTracker()
        for i in range(a.scans):
            t = i * dt
            ego = _pose(track, s_e + v_e * t, lat_e)
            opp = _pose(track, s_e + ds + v_o * t, lat_o)
            h = 0.005  # central difference [s]
            fwd = _pose(track, s_e + ds + v_o * (t + h), lat_o)
            bwd = _pose(track, s_e + ds + v_o * (t - h), lat_o)
            v_true = (fwd[:2] - bwd[:2]) / (2.0 * h)
            empty = sc.scan(*ego)
            seen = sc.scan(*ego, boxes=opp[None, :])
            beams_on = int(np.sum(seen < empty - 1e-3))
            r = _noisy(seen.astype(float), rng, a.noise, rmax)
            t0, c0 = time.perf_counter(), time.process_time()
            tracked = tracker.predicted_centres(t)  # as the bridge's feed does
            dets = det.detect(r, sc.angle_min_rad, sc.angle_increment_rad, rmax, tuple(ego),
                              tracked)
            tracks = tracker.update(t, [(d.x_m, d.y_m, d.yaw_rad) for d in dets])
            cost_ms.append(1e3 * (time.perf_counter() - t0))
            cpu_ms.append(1e3 * (time.process_time() - c0))
            n_scans += 1
            errs = [math.hypot(d.x_m - opp[0], d.y_m - opp[1]) for d in dets]
            fp += sum(e > MATCH_M for e in errs)
            e_dets = det.detect(
                _noisy(empty.astype(float), rng, a.noise, rmax),
                sc.angle_min_rad,
                sc.angle_increment_rad,
                rmax,
                tuple(ego),
                tracked,  # the car gone, the tracks' places left: no wall points there
            )
            fp_empty += len(e_dets)
            dist = math.hypot(opp[0] - ego[0], opp[1] - ego[1])
            if dist <= WITHIN_M and beams_on >= MIN_BEAMS:
                visible += 1
                best = min(errs, default=math.inf)
                if best <= MATCH_M:
                    found += 1
                    pos_err.append(best)
            near = [
                tr for tr in tracks if math.hypot(tr.x[0] - opp[0], tr.x[1] - opp[1]) <= MATCH_M
            ]
            if near:
                tr = min(near, key=lambda q: math.hypot(q.x[0] - opp[0], q.x[1] - opp[1]))
                trk_err.append(math.hypot(tr.x[0] - opp[0], tr.x[1] - opp[1]))
                if i >= SETTLE_SCANS:
                    vel_err.append(math.hypot(tr.x[2] - v_true[0], tr.x[3] - v_true[1]))

    def rms(v: list[float]) -> float:
        return math.sqrt(float(np.mean(np.square(v)))) if v else math.nan

    c, u = np.array(cost_ms), np.array(cpu_ms)
    print(f"opponents on {name}: {a.scenes} scenes x {a.scans} scans, range noise {a.noise} m")
    print(
        f"  recall within {WITHIN_M:g} m (visible: >= {MIN_BEAMS} beams on the car): "
        f"{found}/{visible} = {100.0 * found / max(visible, 1):.1f} %"
    )
    print(
        f"  position RMS: detections {100 * rms(pos_err):.2f} cm "
        f"(max {100 * max(pos_err, default=math.nan):.2f} cm), tracks {100 * rms(trk_err):.2f} cm"
    )
    print(
        f"  velocity RMS (tracks, from scan {SETTLE_SCANS}): {rms(vel_err):.3f} m/s "
        f"(median {np.median(vel_err):.3f}, p90 {np.percentile(vel_err, 90):.3f}) "
        f"over {len(vel_err)} scans"
    )
    print(
        f"  false positives per scan: {fp / n_scans:.4f} with the opponent, "
        f"{fp_empty / n_scans:.4f} on the empty track"
    )
    print(
        f"  cost per scan (detect + track): wall median {np.median(c):.2f} ms, "
        f"p99 {np.percentile(c, 99):.2f} ms; process CPU median {np.median(u):.2f} ms, "
        f"p99 {np.percentile(u, 99):.2f} ms"
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
