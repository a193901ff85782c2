"""One Zenoh hop between two Python processes: publish -> the record on its consumer.

This process is the hub (a router on a free loopback port) and the subscriber; a child
process (this module with ``--publish``, started and stopped by its PID) publishes ``Pose``
records on ``vehicle/pose`` at ``--rate`` Hz, each stamped with its publish time. The
latency of a record is the wall clock once it is decoded where it is consumed, minus that
stamp (same machine, same clock), for three ways of receiving it (one child per way):

* ``channel``: ``Bus.subscribe_channel`` (decoded and validated on Zenoh's thread, handed
  to a thread blocked in ``recv``), what the bridge and the planner use;
* ``ring``: Zenoh's own ``RingChannel`` handler, a thread blocked in its ``recv`` decodes;
* ``callback``: ``Bus.subscribe`` with the work in Zenoh's callback.

Each phase drops its first ``WARMUP`` records (the link's set-up). Prints median, p99 and max
per way; asserts nothing (issue 25: what a hop of the critical path costs).

    .venv/bin/python -m benchmarks.bus_hop --seconds 20 --runs 2
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import threading
import time
from pathlib import Path
from subprocess import Popen

import numpy as np
import zenoh

from services.tools.launcher.supervisor import stop_process
from shared.bus import Bus
from shared.config import load_config
from shared.messages import Pose
from shared.messages.codec import decode_any
from shared.net import free_loopback_port

WAYS = ("channel", "ring", "callback")
#: Records dropped at the start of each phase (the link's set-up) [-].
WARMUP = 20


def publish(config: Path, seconds: float, rate_hz: float) -> int:
    """The child: poses at `rate_hz` [Hz] for `seconds` [s] once the subscriber matches."""
    cfg = load_config(config)
    with Bus(cfg.bus, "bus-hop-publisher", listen_default=False) as bus:
        pub = bus.publisher(bus.keys.pose, Pose)
        pub.wait_matching(10.0)
        time.sleep(0.5)
        t_end = time.monotonic() + seconds
        nxt = time.monotonic()
        while (now := time.monotonic()) < t_end:
            pub.put(Pose(stamp_s=time.time(), x_m=1.0, y_m=2.0, yaw_rad=0.1, cov=None))
            nxt += 1.0 / rate_hz
            time.sleep(max(0.0, nxt - now))
    return 0


def measure(way: str, seconds: float, rate_hz: float) -> np.ndarray:
    """Latencies [ms] of one phase received `way` (module docstring)."""
    tmp = Path(tempfile.mkdtemp(prefix="racestack-hop-"))
    config = tmp / "hop.toml"
    config.write_text(f'[bus]\nlisten = ["tcp/127.0.0.1:{free_loopback_port()}"]\n')
    cfg = load_config(config)
    got: list[float] = []
    with Bus(cfg.bus, "bus-hop", listen_default=True, mode="router") as bus:
        key = bus.keys.pose
        if way == "channel":
            chan = bus.subscribe_channel(key, Pose, capacity=4)

            def consume() -> None:
                while (m := chan.recv()) is not None:
                    got.append(time.time() - m.stamp_s)

            threading.Thread(target=consume, daemon=True).start()
        elif way == "ring":
            ring = bus.session.declare_subscriber(key, zenoh.handlers.RingChannel(4))

            def consume() -> None:
                while True:
                    try:
                        sample = ring.recv()
                    except Exception:  # the session closed
                        return
                    m = decode_any(sample.payload.to_bytes())
                    got.append(time.time() - m.stamp_s)

            threading.Thread(target=consume, daemon=True).start()
        else:
            bus.subscribe(key, Pose, callback=lambda m: got.append(time.time() - m.stamp_s))
        child = Popen([sys.executable, "-m", "benchmarks.bus_hop", "--publish", str(config),
                       "--seconds", str(seconds), "--rate", str(rate_hz)])
        try:
            child.wait(timeout=seconds + 30.0)
        finally:
            stop_process(child, grace_s=5.0)
        time.sleep(0.2)  # the last records in
    return np.asarray(got[WARMUP:]) * 1e3


def main(argv: list[str] | None = None) -> int:
    """Command line entry point."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=20.0, help="length of each phase [s]")
    ap.add_argument("--rate", type=float, default=40.0, help="poses a second [Hz]")
    ap.add_argument("--runs", type=int, default=1, help="phases per way")
    ap.add_argument("--publish", type=Path, default=None, help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.publish is not None:
        return publish(args.publish, args.seconds, args.rate)
    for run in range(max(args.runs, 1)):
        for way in WAYS:
            lat = measure(way, args.seconds, args.rate)
            if not lat.size:
                print(f"run {run + 1} {way:8s}: no record arrived")
                continue
            print(f"run {run + 1} {way:8s}: {lat.size} records, publish -> consumed median "
                  f"{np.median(lat):.3f} ms, p99 {np.percentile(lat, 99):.3f} ms, max "
                  f"{lat.max():.3f} ms", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
