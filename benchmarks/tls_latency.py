"""Pose-to-command latency in the secure profile beside the plain one (issue 15's A/B).

Profiles, interleaved run by run on the same machine (fresh processes each run):

* ``plain``: ``benchmarks.stack_latency.run`` as it is (its quiet phase): this process is
  the hub, the bridge and the planner are peers linked directly by gossip, plain TCP;
* ``mtls``: the secure profile as ``racestack up`` deploys it: the router process
  (``services.router``: mutual TLS, the access rules, its denial counting) is the hub; this
  process (identity ``simulator``: it publishes the poses and odometry), the bridge and the
  planner are its TLS clients, so every sample passes the router (two hops per link).

Figures as in ``stack_latency`` (issued = planner's publish stamp - pose publish; delivered =
command decoded here - pose publish), median and p99 per profile pooled over the runs::

    .venv/bin/python -m benchmarks.tls_latency --seconds 30 --runs 3
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import threading
import time
from pathlib import Path

import numpy as np

from benchmarks.stack_latency import (
    SERVICES,
    _stats,
    latency_record,
    publish_along_track,
    summarise,
)
from benchmarks.stack_latency import run as run_plain
from services.tools.launcher.supervisor import Supervisor, service_argv
from shared.bus import Bus
from shared.config import load_config
from shared.messages import DriveCmd, Odom, Plan, Pose
from shared.net import free_loopback_port
from shared.security.certs import make_certs
from shared.service_shell import endpoint_reachable
from shared.track import load_track


def run_mtls(seconds: float, rate_hz: float, odom_hz: float, speed_mps: float) -> dict:
    """One measurement in the secure profile; the same record as ``stack_latency.run``."""
    tmp = Path(tempfile.mkdtemp(prefix="racestack-tls-latency-"))
    make_certs(tmp / "certs")
    port = free_loopback_port()
    cfg_path = tmp / "bench.toml"
    cfg_path.write_text(f'[bus]\nlisten = ["tcp/127.0.0.1:{port}"]\nsecurity = "mtls"\n'
                        f'certs_dir = "{tmp / "certs"}"\n')
    cfg = load_config(cfg_path)
    track = load_track(cfg.track.source)
    published: dict[float, float] = {}
    arrivals: dict[float, float] = {}
    plans: dict[float, tuple[float, float]] = {}
    lock = threading.Lock()

    def on_plan(p: Plan) -> None:
        with lock:
            plans[p.stamp_s] = (p.source_stamp_s, p.solve_time_ms)

    with Supervisor(log_dir=tmp / "logs") as sup:
        sup.start("router", service_argv("router", str(cfg_path)))
        if not sup.wait_until(lambda: endpoint_reachable(f"tcp/127.0.0.1:{port}"), 30.0):
            raise RuntimeError(f"the router did not start; logs in {tmp / 'logs'}")
        with Bus(cfg.bus, "simulator") as bus:
            cmds = bus.subscribe_channel(bus.keys.drive_cmd, DriveCmd, capacity=16)

            def receive() -> None:
                while (c := cmds.recv()) is not None:
                    t = time.time()
                    with lock:
                        arrivals[c.stamp_s] = t

            receiver = threading.Thread(target=receive, name="bench-cmd", daemon=True)
            receiver.start()
            bus.subscribe(bus.keys.plan, Plan, callback=on_plan)
            pose_pub = bus.publisher(bus.keys.pose, Pose)
            odom_pub = bus.publisher(bus.keys.odom, Odom)
            for name in SERVICES:
                sup.start(name, service_argv(name, str(cfg_path)))
            if not sup.wait_until(lambda: not bus.missing_alive(SERVICES), timeout_s=120.0):
                raise RuntimeError(f"services did not start; logs in {tmp / 'logs'}")
            pose_pub.wait_matching(5.0)
            time.sleep(1.0)
            publish_along_track(pose_pub, odom_pub, track, published, seconds, rate_hz,
                                odom_hz, speed_mps)
            time.sleep(0.3)
            counts = {"drops": bus.drops.total, "cmd_gaps": cmds.seq_gaps}
        receiver.join(2.0)
    with lock:
        return latency_record(published, plans, arrivals, {}, counts)


def table(results: dict[str, list[dict]]) -> list[str]:
    """The A/B table: per profile, pooled median and p99 [ms]."""
    lines = ["| profile | runs | matched | issued median | issued p99 | delivered median "
             "| delivered p99 | solve median | solve p99 |",
             "|---|---|---|---|---|---|---|---|---|"]
    for name, runs in results.items():
        pooled = {k: np.concatenate([r[k] for r in runs]) for k in ("issued", "delivered",
                                                                     "solve")}
        i, d, s = (_stats(pooled[k]) for k in ("issued", "delivered", "solve"))
        lines.append(f"| {name} | {len(runs)} | {len(pooled['delivered'])} | {i['median']:.3f} "
                     f"| {i['p99']:.3f} | {d['median']:.3f} | {d['p99']:.3f} | "
                     f"{s['median']:.3f} | {s['p99']:.3f} |")
    return lines


def main(argv: list[str] | None = None) -> int:
    """Command line entry point."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=30.0, help="length of one run [s]")
    ap.add_argument("--runs", type=int, default=3, help="runs per profile, interleaved")
    ap.add_argument("--rate-hz", type=float, default=40.0, help="pose rate")
    ap.add_argument("--odom-hz", type=float, default=50.0, help="wheel odometry rate")
    ap.add_argument("--speed-mps", type=float, default=3.0)
    args = ap.parse_args(argv)
    if args.seconds <= 0 or args.runs < 1 or args.rate_hz <= 0 or args.odom_hz <= 0:
        ap.error("--seconds, --runs, --rate-hz and --odom-hz must be positive")
    results: dict[str, list[dict]] = {"plain": [], "mtls": []}
    for _ in range(args.runs):
        results["plain"].append(run_plain(args.seconds, args.rate_hz, args.odom_hz,
                                          args.speed_mps, phases=("quiet",))["quiet"])
        results["mtls"].append(run_mtls(args.seconds, args.rate_hz, args.odom_hz,
                                        args.speed_mps))
    print(f"poses at {args.rate_hz:g} Hz, odometry at {args.odom_hz:g} Hz, {args.runs} "
          f"interleaved run(s) of {args.seconds:g} s per profile (pose -> command, ms)")
    for name, runs in results.items():
        print(f"-- {name}")
        for line in summarise(runs, "quiet", cpu=False):
            print(line)
    print()
    for line in table(results):
        print(line)
    return 0


if __name__ == "__main__":
    sys.exit(main())
