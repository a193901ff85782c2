"""Garbage flood on ``vehicle/pose`` while the stack races (issue 25): are the valid poses used?

Starts ``racestack up`` (``benchmarks/soak.py``'s configuration: its own car name and a free
loopback port), with the CPU hog of ``benchmarks/hog.py`` pinned to the last CPU (``--no-hog``:
without), joins its hub and measures two phases of ``--seconds`` each: ``quiet`` (the race
alone) then ``flood`` (this process also puts ``--rate-hz`` (1000) invalid payloads a second
on ``vehicle/pose``, in bursts of ``--burst`` every ``burst / rate`` s, raw bytes past the
contract: random bytes, msgpack that is not a record, and pose records with NaN or
out-of-range fields or wrong types, in turn). Per phase it prints:

* valid poses used: of the simulator's poses (its ``vehicle/pose`` records that decode
  here, stamped in the phase and at least 0.2 s before its end), the share whose stamp is
  the ``source_stamp_s`` of at least one ``state`` of the bridge [%] (acceptance >= 99 %);
* brakes: the planner's stale-state brakes (its "stale or invalid state" reports on
  ``events/log``, one per braking episode) and its plans with status ``braking``
  (acceptance: neither);
* the garbage actually sent and its rate, and the load average.

Over the whole run, from the bridge's closing line (``RUN/logs/localization_bridge.log``):
its pose channel's valid records taken by the worker and those lost (overwritten by a newer
one before the worker took it), so valid poses used = taken / (taken + lost) [%], the
acceptance figure; the per-phase figure above is a view from outside (a pose fused behind
a newer queued one has no state of its own, so it reads lower).

    .venv/bin/python -m benchmarks.garbage_flood --seconds 60
    .venv/bin/python -m benchmarks.garbage_flood --seconds 30 --no-hog
"""

from __future__ import annotations

import argparse
import logging
import math
import os
import random
import re
import signal
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import msgpack

from benchmarks.hog import hog_cpu, load_average, start_hog
from benchmarks.soak import ROOT, STALE_LINE, soak_config
from services.tools.launcher.supervisor import stop_process
from shared.bus import Bus
from shared.config import load_config
from shared.messages import LogEvent, Plan, Pose, State
from shared.net import free_loopback_port

#: Acceptance: share of valid poses used [%] (issue 25).
USED_TARGET_PCT = 99.0
#: The bridge's closing line: its pose channel's counts.
BRIDGE_LINE = re.compile(r"(\d+) valid taken, (\d+) valid lost \((\d+) overwritten, (\d+) "
                         r"stale\), (\d+) rejected")
#: Poses stamped this close to a phase's end are not judged (their states may be in flight).
TAIL_S = 0.2


def garbage(k: int, rng: random.Random) -> bytes:
    """The `k`-th invalid payload: four kinds in turn (none of them a valid ``Pose``)."""
    kind = k % 4
    if kind == 0:  # random bytes
        return rng.randbytes(rng.randint(1, 200))
    if kind == 1:  # msgpack, not a record
        return msgpack.packb([rng.random(), "pose", {"x": rng.random()}])
    base = {"type": "pose", "v": 1, "stamp_s": time.time(), "seq": k, "x_m": 1.0,
            "y_m": 2.0, "yaw_rad": 0.1, "cov": None}
    if kind == 2:  # a pose with a non-finite or out-of-range field
        field = ("x_m", "y_m", "yaw_rad", "stamp_s")[(k // 4) % 4]
        base[field] = (math.nan, 1e12, math.inf, -1e12)[(k // 16) % 4]  # none valid
    else:  # a pose with a field of the wrong type
        base["x_m"] = "one metre"
    return msgpack.packb(base)


class Tape:
    """The simulator's poses (stamps), the bridge's states (source stamps) and the
    planner's braking plans, each with its arrival time; callbacks append under a lock."""

    def __init__(self, bus: Bus) -> None:
        self.lock = threading.Lock()
        self.poses: list[float] = []
        self.sources: set[float] = set()
        self.braking: list[float] = []
        self.stale: list[float] = []  #: stamps of the planner's stale-state brake reports
        bus.subscribe(bus.keys.pose, Pose, callback=self._pose)
        bus.subscribe(bus.keys.state, State, callback=self._state)
        bus.subscribe(bus.keys.plan, Plan, callback=self._plan)
        bus.subscribe(bus.keys.events_log, LogEvent, callback=self._event)

    def _event(self, e: LogEvent) -> None:
        if e.source == "planner" and STALE_LINE.search(e.text):
            with self.lock:
                self.stale.append(e.stamp_s)

    def _pose(self, p: Pose) -> None:
        with self.lock:
            self.poses.append(p.stamp_s)

    def _state(self, s: State) -> None:
        with self.lock:
            self.sources.add(s.source_stamp_s)

    def _plan(self, p: Plan) -> None:
        if p.status == "braking":
            with self.lock:
                self.braking.append(p.stamp_s)

    def judge(self, t0: float, t1: float) -> dict[str, float]:
        """Valid poses stamped in [t0, t1 - TAIL_S], the share used [%], braking plans."""
        with self.lock:
            poses = [s for s in self.poses if t0 <= s <= t1 - TAIL_S]
            used = sum(s in self.sources for s in poses)
            brakes = sum(t0 <= s <= t1 for s in self.braking)
            stale = sum(t0 <= s <= t1 for s in self.stale)
        return {"poses": len(poses), "used": used,
                "used_pct": 100.0 * used / len(poses) if poses else math.nan,
                "braking_plans": brakes, "stale_brakes": stale}


def flood(bus: Bus, key: str, seconds: float, rate_hz: float, burst: int) -> int:
    """Put `rate_hz` invalid payloads a second on `key` for `seconds`, `burst` at a time;
    returns how many were sent."""
    rng = random.Random(25)
    period = burst / rate_hz
    sent = 0
    t_end = time.monotonic() + seconds
    next_t = time.monotonic()
    while (now := time.monotonic()) < t_end:
        if now >= next_t:
            for _ in range(burst):
                bus.put_raw(key, garbage(sent, rng))
                sent += 1
            next_t += period
            if next_t < now - 1.0:  # far behind (a loaded machine): no catch-up burst
                next_t = now
        time.sleep(max(0.0, min(next_t, t_end) - time.monotonic()))
    return sent


def main(argv: list[str] | None = None) -> int:
    """Command line entry point."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=60.0, help="length of each phase [s]")
    ap.add_argument("--rate-hz", type=float, default=1000.0, help="garbage rate [Hz]")
    ap.add_argument("--burst", type=int, default=10, help="payloads per burst (default 10)")
    ap.add_argument("--no-hog", action="store_true",
                    help="no CPU hog (default: a busy loop pinned to the last CPU)")
    ap.add_argument("--track", default="builtin:paperlike", help="track to race")
    ap.add_argument("--out", help="folder of the run (default: a temp folder)")
    args = ap.parse_args(argv)
    if args.seconds <= 0 or args.rate_hz <= 0 or args.burst < 1:
        ap.error("--seconds and --rate-hz must be positive, --burst at least 1")
    out = Path(args.out) if args.out else Path(tempfile.mkdtemp(prefix="racestack-flood-"))
    out.mkdir(parents=True, exist_ok=True)
    port = free_loopback_port()
    toml = soak_config(out / "flood.toml", port, args.track, 60.0, 10.0)
    cfg = load_config(toml)
    env = {**os.environ, "PYTHONPATH": str(ROOT), "PYTHONUNBUFFERED": "1"}
    for name in ("XDG_CONFIG_HOME", "XDG_DATA_HOME"):
        (out / name).mkdir(exist_ok=True)
        env[name] = str(out / name)
    run_dir = out / "run"
    cmd = [sys.executable, "-m", "services.tools.cli", "up", "--config", str(toml), "--laps",
           "100000", "--run-dir", str(run_dir)]
    log_path = out / "up.log"
    print(f"garbage_flood: {args.seconds:g} s quiet + {args.seconds:g} s of {args.rate_hz:g} "
          f"Hz garbage on vehicle/pose, hog {'off' if args.no_hog else 'on'}; log {log_path}",
          flush=True)
    rows: dict[str, dict[str, float]] = {}
    hog = None
    with open(log_path, "wb") as log:
        proc = subprocess.Popen(cmd, cwd=str(ROOT), env=env, stdout=log, stderr=subprocess.STDOUT)
        try:
            deadline = time.monotonic() + 600.0
            while b"racing" not in log_path.read_bytes():
                if proc.poll() is not None or time.monotonic() > deadline:
                    print(f"garbage_flood: the stack did not start; see {log_path}",
                          file=sys.stderr)
                    return 1
                time.sleep(0.5)
            if not args.no_hog:
                hog = start_hog(hog_cpu())
            # this process decodes the garbage too (it watches vehicle/pose): its own drop
            # reports would flood the output
            logging.getLogger("racestack.bus").setLevel(logging.ERROR)
            with Bus(cfg.bus, "flood") as bus:
                tape = Tape(bus)
                time.sleep(2.0)  # the subscriptions settle, the race is on
                for phase in ("quiet", "flood"):
                    load0 = load_average()
                    t0 = time.time()
                    if phase == "flood":
                        w0 = time.monotonic()
                        sent = flood(bus, bus.keys.pose, args.seconds, args.rate_hz, args.burst)
                        rate = sent / (time.monotonic() - w0)
                    else:
                        time.sleep(args.seconds)
                        sent, rate = 0, 0.0
                    t1 = time.time()
                    time.sleep(0.5)  # the last states come in
                    rows[phase] = {**tape.judge(t0, t1), "garbage": sent, "garbage_hz": rate,
                                   "load0": load0, "load1": load_average()}
        finally:
            if hog is not None:
                stop_process(hog, grace_s=2.0)
            if proc.poll() is None:
                proc.send_signal(signal.SIGINT)
            try:
                proc.wait(timeout=120)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait(timeout=30)
    planner_log = run_dir / "logs" / "planner.log"
    stale = STALE_LINE.findall(planner_log.read_text(errors="replace")) \
        if planner_log.exists() else []
    bridge_log = run_dir / "logs" / "localization_bridge.log"
    found = BRIDGE_LINE.findall(bridge_log.read_text(errors="replace")) \
        if bridge_log.exists() else []
    ok = bool(found)
    if found:
        taken, lost, over, stale_n, rejected = (int(v) for v in found[-1])
        used_pct = 100.0 * taken / max(1, taken + lost)
        met = used_pct >= USED_TARGET_PCT
        ok = met
        print(f"whole run, the bridge's pose channel: {taken} valid poses taken, {lost} lost "
              f"({over} overwritten, {stale_n} stale), {rejected} garbage rejected")
        print(f"{'PASS' if met else 'FAIL'}  valid poses used (whole run, with the flood) >= "
              f"{USED_TARGET_PCT:g} %: {used_pct:.2f} %")
    else:
        print("the bridge's closing line is missing: no whole-run figure")
    for phase, r in rows.items():
        print(f"{phase}: {r['poses']} valid poses, {r['used']} with a state of their own "
              f"({r['used_pct']:.2f} %); {r['stale_brakes']} stale-state brakes, "
              f"{r['braking_plans']} braking plans; {r['garbage']} garbage payloads "
              f"({r['garbage_hz']:.0f} Hz); load average {r['load0']} -> {r['load1']}")
        if phase == "flood":
            none = r["braking_plans"] == 0 and r["stale_brakes"] == 0
            ok = ok and none
            print(f"{'PASS' if none else 'FAIL'}  no brake under the flood: "
                  f"{r['stale_brakes']} stale-state brakes, {r['braking_plans']} braking plans")
    print(f"planner stale-state brakes in the whole run: {len(stale)}"
          + (f" (ages {', '.join(stale[:10])} ms)" if stale else ""))
    return 0 if ok and len(rows) == 2 else 1


if __name__ == "__main__":
    sys.exit(main())
