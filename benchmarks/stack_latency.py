"""Pose-to-command latency over Zenoh, beside the solve time (issue 4's figure).

Starts the localization bridge and the planner as real processes (the default services with
the default configuration); this process hosts the hub (a router on a free loopback port),
publishes poses along the track at the localiser's rate and wheel odometry at the VESC's
rate (each on its own schedule, as on the car), and receives ``cmd/drive`` and
``planner/plan``. The command is received the way a latency-critical consumer does
(``Bus.subscribe_channel`` and a thread blocked in ``recv``); arrival is taken once it is
decoded. A plan and its command share one stamp (the planner's publish time) and the plan
carries the capture stamp of its pose (``source_stamp_s``), so every command is matched to
the pose it answers (same machine, same clock):

* issued = the planner's publish stamp - pose publish;
* delivered = command decoded here - pose publish (the figure the target is about).

    .venv/bin/python -m benchmarks.stack_latency --seconds 60 --runs 3
    .venv/bin/python -m benchmarks.stack_latency --seconds 60 --breakdown

``--breakdown`` also subscribes to ``state`` to split the path at the bridge (it adds a
subscriber, so the totals of such a run are slightly pessimistic). Target on loopback:
delivered p99 <= solve-time p99 + 2 ms.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import threading
import time
from pathlib import Path

import numpy as np

from services.tools.launcher.supervisor import Supervisor, service_argv
from shared.bus import Bus, TypedPublisher
from shared.config import load_config
from shared.messages import DriveCmd, Odom, Plan, Pose, State
from shared.net import free_loopback_port
from shared.track import Track, load_track

SERVICES = ("localization_bridge", "planner")


def _stats(x: np.ndarray) -> dict[str, float]:
    return {"median": float(np.median(x)), "p99": float(np.percentile(x, 99))}


def publish_along_track(
    pose_pub: TypedPublisher[Pose],
    odom_pub: TypedPublisher[Odom],
    track: Track,
    published: dict[float, float],
    seconds: float,
    rate_hz: float,
    odom_hz: float,
    speed_mps: float,
) -> None:
    """For `seconds` [s], poses along the centreline at `rate_hz` [Hz] (moving at
    `speed_mps` [m/s]) and wheel odometry at `odom_hz` [Hz], each on its own schedule;
    ``published[stamp] = publish time`` of every pose (wall clock [s])."""
    s = 0.0
    now = time.monotonic()
    next_pose, next_odom = now, now + 0.5 / odom_hz
    t_end = now + seconds
    while (now := time.monotonic()) < t_end:
        if now >= next_odom:
            odom_pub.put(Odom(stamp_s=time.time(), speed_mps=speed_mps, steering_rad=0.0,
                              yaw_rate_radps=None))
            next_odom += 1.0 / odom_hz
        if now >= next_pose:
            s = (s + speed_mps / rate_hz) % track.length_m
            (x, y) = track.point_at(s)
            yaw = float(track.heading_at(s))
            stamp = time.time()
            pose_pub.put(Pose(stamp_s=stamp, x_m=float(x), y_m=float(y), yaw_rad=yaw,
                              cov=None))
            published[stamp] = time.time()
            next_pose += 1.0 / rate_hz
        time.sleep(max(0.0, min(next_pose, next_odom) - time.monotonic()))


def latency_record(
    published: dict[float, float],
    plans: dict[float, tuple[float, float]],
    arrivals: dict[float, float],
    states: dict[float, float],
    counts: dict[str, int],
) -> dict:
    """One run's record: every command matched to the pose it answers; arrays [ms] of
    issued, delivered, solve and bridge (NaN where `states` has no entry) and the counts."""
    rows = []
    for cmd_stamp, (src, solve_ms) in plans.items():
        if src in published and cmd_stamp in arrivals:
            p = published[src]
            rows.append((cmd_stamp - p, arrivals[cmd_stamp] - p, solve_ms / 1e3,
                         states.get(src, np.nan) - p))
    r = np.array(rows, dtype=float).reshape(-1, 4) * 1e3
    return {
        "poses": len(published), "plans": len(plans), "commands": len(arrivals),
        "matched": len(r), **counts,
        "issued": r[:, 0], "delivered": r[:, 1], "solve": r[:, 2], "bridge": r[:, 3],
    }


def run(
    seconds: float,
    rate_hz: float,
    odom_hz: float,
    speed_mps: float,
    breakdown: bool = False,
    extra_config: str = "",
) -> dict:
    """One measurement; returns arrays [ms] and counts (see ``summarise``)."""
    tmp = Path(tempfile.mkdtemp(prefix="racestack-latency-"))
    cfg_path = tmp / "bench.toml"
    cfg_path.write_text(f'[bus]\nlisten = ["tcp/127.0.0.1:{free_loopback_port()}"]\n{extra_config}')
    cfg = load_config(cfg_path)
    track = load_track(cfg.track.source)
    published: dict[float, float] = {}  # pose stamp -> publish time
    arrivals: dict[float, float] = {}  # command stamp -> decoded here
    plans: dict[float, tuple[float, float]] = {}  # command stamp -> (pose stamp, solve ms)
    states: dict[float, float] = {}  # pose stamp -> bridge stamp
    lock = threading.Lock()

    def on_plan(p: Plan) -> None:
        with lock:
            plans[p.stamp_s] = (p.source_stamp_s, p.solve_time_ms)

    def on_state(s: State) -> None:
        with lock:
            states[s.source_stamp_s] = s.stamp_s

    with Bus(cfg.bus, "bench", listen_default=True, mode="router") as bus, \
            Supervisor(log_dir=tmp / "logs") as sup:
        cmds = bus.subscribe_channel(bus.keys.drive_cmd, DriveCmd, capacity=16)

        def receive() -> None:
            while (c := cmds.recv()) is not None:
                t = time.time()
                with lock:
                    arrivals[c.stamp_s] = t

        receiver = threading.Thread(target=receive, name="bench-cmd", daemon=True)
        receiver.start()
        bus.subscribe(bus.keys.plan, Plan, callback=on_plan)
        if breakdown:
            bus.subscribe(bus.keys.state, State, callback=on_state)
        pose_pub = bus.publisher(bus.keys.pose, Pose)
        odom_pub = bus.publisher(bus.keys.odom, Odom)
        for name in SERVICES:
            sup.start(name, service_argv(name, str(cfg_path)))
        if not sup.wait_until(lambda: not bus.missing_alive(SERVICES), timeout_s=120.0):
            raise RuntimeError(f"services did not start; logs in {tmp / 'logs'}")
        pose_pub.wait_matching(5.0)
        time.sleep(1.0)  # let the planner settle (first solves, gossip links)
        publish_along_track(pose_pub, odom_pub, track, published, seconds, rate_hz, odom_hz,
                            speed_mps)
        time.sleep(0.3)
        counts = {"drops": bus.drops.total, "cmd_gaps": cmds.seq_gaps}
    receiver.join(2.0)
    with lock:
        return latency_record(published, plans, arrivals, states, counts)


def summarise(runs: list[dict], breakdown: bool) -> list[str]:
    """Text lines: per run and pooled figures and the target check."""
    lines = []
    pooled = {k: np.concatenate([r[k] for r in runs]) for k in ("issued", "delivered", "solve",
                                                                 "bridge")}
    for i, r in enumerate([*runs, None]):
        d = pooled if r is None else r
        if r is None and len(runs) == 1:
            break
        head = "pooled" if r is None else f"run {i + 1}"
        if r is not None:
            lines.append(f"{head}: {r['poses']} poses, {r['plans']} plans, {r['commands']} "
                         f"commands, {r['matched']} matched, {r['drops']} rejected messages")
        else:
            lines.append(f"{head}: {len(d['delivered'])} matched commands")
        iss, dlv, sol = _stats(d["issued"]), _stats(d["delivered"]), _stats(d["solve"])
        lines.append(f"  pose -> command issued    [ms]: median {iss['median']:.3f}  "
                     f"p99 {iss['p99']:.3f}")
        lines.append(f"  pose -> command delivered [ms]: median {dlv['median']:.3f}  "
                     f"p99 {dlv['p99']:.3f}  max {float(np.max(d['delivered'])):.3f}")
        lines.append(f"  solve time                [ms]: median {sol['median']:.3f}  "
                     f"p99 {sol['p99']:.3f}")
        if breakdown:
            b = d["bridge"][np.isfinite(d["bridge"])]
            pl = (d["issued"] - d["bridge"])[np.isfinite(d["bridge"])]
            tr = d["delivered"] - d["issued"]
            for name, x in (("pose -> state published", b), ("state -> command issued", pl),
                            ("  of which not solving", pl - d["solve"][np.isfinite(d["bridge"])]),
                            ("command issued -> decoded", tr)):
                st = _stats(x)
                lines.append(f"  {name:26s}: median {st['median']:.3f}  p99 {st['p99']:.3f}")
        target = sol["p99"] + 2.0
        verdict = "met" if dlv["p99"] <= target else "NOT met"
        lines.append(f"  target delivered p99 <= solve p99 + 2 ms = {target:.3f}: {verdict} "
                     f"({dlv['p99']:.3f})")
    return lines


def main(argv: list[str] | None = None) -> int:
    """Command line entry point."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=60.0, help="length of one run [s]")
    ap.add_argument("--runs", type=int, default=1, help="runs, each with fresh processes")
    ap.add_argument("--rate-hz", type=float, default=40.0, help="pose rate (a lidar localiser)")
    ap.add_argument("--odom-hz", type=float, default=50.0, help="wheel odometry rate (VESC)")
    ap.add_argument("--speed-mps", type=float, default=3.0)
    ap.add_argument("--breakdown", action="store_true",
                    help="also split the path at the bridge (adds a subscriber to state)")
    args = ap.parse_args(argv)
    if args.seconds <= 0 or args.runs < 1 or args.rate_hz <= 0 or args.odom_hz <= 0:
        ap.error("--seconds, --runs, --rate-hz and --odom-hz must be positive")
    runs = []
    for _ in range(args.runs):
        runs.append(run(args.seconds, args.rate_hz, args.odom_hz, args.speed_mps,
                        args.breakdown))
    print(f"poses at {args.rate_hz:g} Hz, odometry at {args.odom_hz:g} Hz, "
          f"{args.runs} run(s) of {args.seconds:g} s")
    for line in summarise(runs, args.breakdown):
        print(line)
    return 0


if __name__ == "__main__":
    sys.exit(main())
