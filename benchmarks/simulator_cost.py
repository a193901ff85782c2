"""Cost of the simulator's hot paths (the figures the in-process bench depends on).

    .venv/bin/python -m benchmarks.simulator_cost

Prints median and p99 over many repetitions of: one ``Simulator.step`` of 10 ms, one step plus
the pose/IMU/odometry sensors, one ``LapTimer.update``, and one 1080-beam lidar scan on the
map416 occupancy map (or the rasterised default track when ../shared is absent), in wall
time and in the thread's CPU time (the cost without a loaded machine's waits).
"""

from __future__ import annotations

import math
import sys
import time
from pathlib import Path

import numpy as np

from services.simulator import Command, LapTimer, LidarScanner, SensorSuite, Simulator
from shared.config.simulator import SimulatorSettings
from shared.track import load_ros_map, load_track, rasterize_track

MAP416 = Path(__file__).resolve().parents[1].parent / "shared" / "tracks" / "map416"


def _stats(samples_s: list[float]) -> str:
    t = np.asarray(samples_s) * 1e6
    return f"median {np.median(t):8.1f} us   p99 {np.percentile(t, 99):8.1f} us"


def main() -> int:
    """Measure and print."""
    settings = SimulatorSettings()
    sim = Simulator(settings)
    sim.reset((0.0, 0.0, 0.0), speed_mps=3.0)
    cmds = [Command(3.0 + 0.5 * math.sin(0.01 * k), 0.2 * math.sin(0.02 * k)) for k in range(20000)]
    step_t = []
    for c in cmds:
        t0 = time.perf_counter()
        sim.step(c, 0.01)
        step_t.append(time.perf_counter() - t0)
    print(f"Simulator.step(0.01 s)          {_stats(step_t)}   ({len(step_t)} steps)")

    suite = SensorSuite(settings, None)
    sens_t = []
    for c in cmds[:5000]:
        t0 = time.perf_counter()
        suite.update(sim.step(c, 0.01))
        sens_t.append(time.perf_counter() - t0)
    print(f"step + pose/IMU/odom sensors    {_stats(sens_t)}")

    track = load_track("paperlike")
    timer = LapTimer(track)
    lap_t = []
    for k in range(5000):
        s = (0.03 * k) % track.length_m
        x, y = track.point_at(s)
        t0 = time.perf_counter()
        timer.update(0.01 * k, float(x), float(y), float(track.heading_at(s)), 3.0)
        lap_t.append(time.perf_counter() - t0)
    print(f"LapTimer.update                 {_stats(lap_t)}")

    if MAP416.is_dir():
        grid, where = load_ros_map(MAP416 / "map416.yaml"), "map416"
        scan_track = load_track(MAP416)
    else:
        grid, where, scan_track = rasterize_track(track), "paperlike (rasterised)", track
    scanner = LidarScanner(grid, beams=1080, fov_rad=4.7)
    scan_t, scan_cpu = [], []
    for k in range(200):
        s = (0.15 * k) % scan_track.length_m
        x, y = scan_track.point_at(s)
        t0, c0 = time.perf_counter(), time.thread_time()
        scanner.scan(float(x), float(y), float(scan_track.heading_at(s)))
        scan_cpu.append(time.thread_time() - c0)
        scan_t.append(time.perf_counter() - t0)
    print(f"lidar scan, 1080 beams, {where}: {_stats(scan_t)}")
    # the thread's CPU time: what the scan costs, without the waits of a loaded machine
    print(f"  the same, CPU time of the thread:   {_stats(scan_cpu)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
