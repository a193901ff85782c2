"""Pose-to-command latency over Zenoh, beside the solve time (issue 4's figure).

Starts the localization bridge and the planner as real processes; this process hosts the hub
(a router on a free loopback port), publishes poses along the track at the localiser's rate
(the car "driving" the centreline at racing speed) and receives ``planner/plan``. A plan
carries the capture stamp of the pose it came from (``source_stamp_s``), so each plan is
matched to its pose; the command of that tick is the last ``cmd/drive`` that arrived before
the plan (the planner publishes the command first): latency = command arrival - pose publish
(same machine, same clock).

    .venv/bin/python -m benchmarks.stack_latency --seconds 60

Target on loopback: latency p99 <= solve-time p99 + 2 ms.
"""

from __future__ import annotations

import argparse
import socket
import sys
import tempfile
import threading
import time
from pathlib import Path

import numpy as np

from services.launcher.supervisor import Supervisor, service_argv
from shared.bus import Bus
from shared.config import load_config
from shared.messages import DriveCmd, Odom, Plan, Pose
from shared.track import load_track


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def run(seconds: float, rate_hz: float, speed_mps: float) -> dict:
    """Run the measurement; returns latency and solve-time figures [ms]."""
    tmp = Path(tempfile.mkdtemp(prefix="racestack-latency-"))
    cfg_path = tmp / "bench.toml"
    cfg_path.write_text(f'[bus]\nlisten = ["tcp/127.0.0.1:{_free_port()}"]\n')
    cfg = load_config(cfg_path)
    track = load_track(cfg.track.source)
    published: dict[float, float] = {}
    # (pose stamp, command arrival, solve ms, command publish stamp)
    arrivals: list[tuple[float, float, float, float]] = []
    lock = threading.Lock()

    last_cmd = [0.0]

    def on_cmd(_c: DriveCmd) -> None:
        t = time.time()
        with lock:
            last_cmd[0] = t

    def on_plan(p: Plan) -> None:
        with lock:
            arrivals.append((p.source_stamp_s, last_cmd[0], p.solve_time_ms, p.stamp_s))

    with Bus(cfg.bus, "bench", listen_default=True, mode="router") as bus, \
            Supervisor(log_dir=tmp / "logs") as sup:
        bus.subscribe(bus.keys.drive_cmd, DriveCmd, callback=on_cmd)
        bus.subscribe(bus.keys.plan, Plan, callback=on_plan)
        pose_pub = bus.publisher(bus.keys.pose, Pose)
        odom_pub = bus.publisher(bus.keys.odom, Odom)
        for name in ("localization_bridge", "planner"):
            sup.start(name, service_argv(name, str(cfg_path)))
        if not sup.wait_until(lambda: not bus.missing_alive(["localization_bridge", "planner"]),
                              timeout_s=120.0):
            raise RuntimeError(f"services did not start; logs in {tmp / 'logs'}")
        pose_pub.wait_matching(5.0)
        period = 1.0 / rate_hz
        s = 0.0
        t_next = time.monotonic()
        t_end = t_next + seconds
        while time.monotonic() < t_end:
            s = (s + speed_mps * period) % track.length_m
            (x, y) = track.point_at(s)
            yaw = float(track.heading_at(s))
            now = time.time()
            odom_pub.put(Odom(stamp_s=now, speed_mps=speed_mps, steering_rad=0.0,
                              yaw_rate_radps=None))
            stamp = time.time()
            pose_pub.put(Pose(stamp_s=stamp, x_m=float(x), y_m=float(y), yaw_rad=yaw, cov=None))
            published[stamp] = time.time()
            t_next += period
            time.sleep(max(0.0, t_next - time.monotonic()))
        time.sleep(0.3)
    with lock:
        matched = [(arr - published[src], solve, issued - published[src])
                   for src, arr, solve, issued in arrivals
                   if src in published and arr >= published[src]]
    lat = np.array([m[0] for m in matched]) * 1e3
    solve = np.array([m[1] for m in matched])
    issued = np.array([m[2] for m in matched]) * 1e3
    return {
        "issued_median_ms": float(np.median(issued)),
        "issued_p99_ms": float(np.percentile(issued, 99)),
        "poses": len(published),
        "plans": len(arrivals),
        "matched": len(matched),
        "latency_median_ms": float(np.median(lat)),
        "latency_p99_ms": float(np.percentile(lat, 99)),
        "latency_max_ms": float(lat.max()),
        "solve_median_ms": float(np.median(solve)),
        "solve_p99_ms": float(np.percentile(solve, 99)),
        "overhead_median_ms": float(np.median(lat - solve)),
        "overhead_p99_ms": float(np.percentile(lat - solve, 99)),
    }


def main(argv: list[str] | None = None) -> int:
    """Command line entry point."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=60.0)
    ap.add_argument("--rate-hz", type=float, default=40.0, help="pose rate (a lidar localiser)")
    ap.add_argument("--speed-mps", type=float, default=3.0)
    args = ap.parse_args(argv)
    r = run(args.seconds, args.rate_hz, args.speed_mps)
    print(f"{r['poses']} poses at {args.rate_hz:g} Hz, {r['plans']} plans, {r['matched']} matched")
    print(f"pose -> command issued [ms]:   median {r['issued_median_ms']:.3f}  "
          f"p99 {r['issued_p99_ms']:.3f}  (the planner's publish stamp)")
    print(f"pose -> command delivered [ms]: median {r['latency_median_ms']:.3f}  "
          f"p99 {r['latency_p99_ms']:.3f}  max {r['latency_max_ms']:.3f}")
    print(f"solve time [ms]:            median {r['solve_median_ms']:.3f}  "
          f"p99 {r['solve_p99_ms']:.3f}")
    print(f"delivered - solve [ms]:     median {r['overhead_median_ms']:.3f}  "
          f"p99 {r['overhead_p99_ms']:.3f}")
    for what, key in (("issued", "issued_p99_ms"), ("delivered", "latency_p99_ms")):
        ok = r[key] <= r["solve_p99_ms"] + 2.0
        print(f"target p99 <= solve p99 + 2 ms ({what}): {'met' if ok else 'NOT met'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
