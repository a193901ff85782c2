"""A reset during a race (issue 25): how soon ``state`` is on the car again, and the car on track.

Starts ``racestack up`` (the whole stack, as a user would) on its own car name and a free
loopback port, joins its hub as the operator, and ``--trials`` times, once the car is
``--at-s`` metres into a lap and at least ``--gap-s`` after the previous reset, publishes
``sim/control`` reset. For each it takes the simulator's ``vehicle/teleport`` (its stamp T) and
compares every ``state`` with the car: the true rear axle (``sim/truth`` moved back by the
simulator's ``lr_m``, interpolated to the state's stamp). Printed per trial and summed up:

* the first state within 0.1 m of the car [ms after T];
* the largest distance of the states stamped from T + 50 ms to T + 1 s [m];
* off-track events (``lap`` kind ``off_track``) and the largest ``|e_con|`` until the next
  trial; planner warnings (stale state brakes) printed by the launcher meanwhile.

Then it stops the stack with SIGINT (the launcher stops its children and prints its tables,
the CPU use over the race among them, which are passed on)::

    .venv/bin/python -m benchmarks.reset_race --trials 5
"""

from __future__ import annotations

import argparse
import bisect
import math
import os
import signal
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

from services.simulator import rear_axle
from shared.bus import Bus
from shared.config import load_config
from shared.messages import LapEvent, SimControl, SimTruth, State, Teleport
from shared.net import free_loopback_port
from shared.track import load_track

ROOT = Path(__file__).resolve().parents[1]
#: A state this close to the car is "on the car" [m] (issue 25).
NEAR_M = 0.1
#: States from this long after the teleport on must be near [s] (issue 25).
DEADLINE_S = 0.05


class Tape:
    """Everything the trials need from the bus (callbacks only append under one lock)."""

    def __init__(self, bus: Bus) -> None:
        self.lock = threading.Lock()
        self.states: list[State] = []
        self.truth: list[SimTruth] = []
        self.teleports: list[Teleport] = []
        self.off_track: list[float] = []
        bus.subscribe(bus.keys.state, State, callback=self._add(self.states))
        bus.subscribe(bus.keys.sim_truth, SimTruth, callback=self._add(self.truth))
        bus.subscribe(bus.keys.teleport, Teleport, callback=self._add(self.teleports))
        bus.subscribe(bus.keys.lap, LapEvent, callback=self._lap)

    def _add(self, into: list):
        def put(m) -> None:
            with self.lock:
                into.append(m)
        return put

    def _lap(self, m: LapEvent) -> None:
        if m.kind == "off_track":
            with self.lock:
                self.off_track.append(m.stamp_s)


def car_at(truth: list[SimTruth], stamps: list[float], t: float, lr_m: float):
    """The true rear axle at `t` (linear between the two truths around it), or None."""
    k = bisect.bisect_left(stamps, t)
    if k == 0 or k >= len(truth):
        return None
    a, b = truth[k - 1], truth[k]
    if b.stamp_s - a.stamp_s > 0.1:  # a gap in the truth (a skip): no honest interpolation
        return None
    w = (t - a.stamp_s) / (b.stamp_s - a.stamp_s)
    xa, ya, _ = rear_axle(a.x_m, a.y_m, a.yaw_rad, lr_m)
    xb, yb, _ = rear_axle(b.x_m, b.y_m, b.yaw_rad, lr_m)
    return xa + w * (xb - xa), ya + w * (yb - ya)


def judge(tape: Tape, tp: Teleport, until: float, lr_m: float) -> dict[str, float]:
    """The figures of one trial (module docstring)."""
    with tape.lock:
        truth = [m for m in tape.truth if tp.stamp_s - 1.0 <= m.stamp_s <= until + 0.1]
        states = [s for s in tape.states if tp.stamp_s <= s.stamp_s <= until]
        off = [t for t in tape.off_track if tp.stamp_s <= t <= until]
    stamps = [m.stamp_s for m in truth]
    first, worst = math.nan, 0.0
    for s in states:
        car = car_at(truth, stamps, s.stamp_s, lr_m)
        if car is None:
            continue
        err = math.hypot(s.x_m - car[0], s.y_m - car[1])
        if math.isnan(first) and err < NEAR_M:
            first = s.stamp_s - tp.stamp_s
        if tp.stamp_s + DEADLINE_S <= s.stamp_s <= tp.stamp_s + 1.0:
            worst = max(worst, err)
    e_con = max((abs(m.e_con_m) for m in truth if m.stamp_s >= tp.stamp_s), default=math.nan)
    return {"first_near_ms": 1e3 * first, "max_err_m": worst, "off_track": float(len(off)),
            "max_abs_e_con_m": e_con}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--trials", type=int, default=5)
    ap.add_argument("--at-s", type=float, default=20.0, help="reset this far into a lap [m]")
    ap.add_argument("--gap-s", type=float, default=8.0, help="shortest time between resets [s]")
    ap.add_argument("--out", default=None, help="folder of the run (default: a temp folder)")
    args = ap.parse_args(argv)
    out = Path(args.out) if args.out else Path(tempfile.mkdtemp(prefix="racestack-reset-"))
    out.mkdir(parents=True, exist_ok=True)
    port = free_loopback_port()
    toml = out / "reset.toml"
    toml.write_text(f'[bus]\ncar = "reset{port}"\nlisten = ["tcp/127.0.0.1:{port}"]\n')
    cfg = load_config(toml)
    lr_m = cfg.simulator.vehicle.lr_m
    length_m = load_track(cfg.track.source).length_m
    env = {**os.environ, "PYTHONPATH": str(ROOT), "PYTHONUNBUFFERED": "1"}
    for name in ("XDG_CONFIG_HOME", "XDG_DATA_HOME"):
        (out / name).mkdir(exist_ok=True)
        env[name] = str(out / name)
    cmd = [sys.executable, "-m", "services.tools.cli", "up", "--config", str(toml), "--laps",
           "1000", "--run-dir", str(out / "run")]
    log_path = out / "up.log"
    print(f"reset_race: {args.trials} resets; {' '.join(cmd)}; log {log_path}", flush=True)
    rows: list[dict[str, float]] = []
    with open(log_path, "wb") as log:
        proc = subprocess.Popen(cmd, cwd=str(ROOT), env=env, stdout=log, stderr=subprocess.STDOUT)
        try:
            deadline = time.monotonic() + 600.0
            while b"racing" not in log_path.read_bytes():
                if proc.poll() is not None or time.monotonic() > deadline:
                    print(f"reset_race: the stack did not start; see {log_path}", file=sys.stderr)
                    return 1
                time.sleep(0.5)
            with Bus(cfg.bus, "operator") as bus:
                tape = Tape(bus)
                control = bus.publisher(bus.keys.sim_control, SimControl)
                control.wait_matching(10.0)
                last = time.monotonic()
                pending: Teleport | None = None
                while len(rows) < args.trials and proc.poll() is None:
                    time.sleep(0.01)
                    with tape.lock:
                        now_truth = tape.truth[-1] if tape.truth else None
                        n_tp = len(tape.teleports)
                    if now_truth is None or time.monotonic() - last < args.gap_s:
                        continue
                    if pending is not None:  # the previous trial ends where the next begins
                        rows.append(judge(tape, pending, now_truth.stamp_s, lr_m))
                        print(f"trial {len(rows)}: " + ", ".join(
                            f"{k} {v:.3g}" for k, v in rows[-1].items()), flush=True)
                        pending = None
                        if len(rows) >= args.trials:
                            break
                    if not args.at_s <= now_truth.s_m % length_m <= args.at_s + 3.0:
                        continue
                    control.put(SimControl(stamp_s=time.time(), action="reset"))
                    got = False
                    t_wait = time.monotonic() + 5.0
                    while time.monotonic() < t_wait and not got:
                        time.sleep(0.005)
                        with tape.lock:
                            got = len(tape.teleports) > n_tp
                    if not got:
                        print("reset_race: no vehicle/teleport after a reset", file=sys.stderr)
                        return 1
                    with tape.lock:
                        pending = tape.teleports[-1]
                    last = time.monotonic()
        finally:
            if proc.poll() is None:
                proc.send_signal(signal.SIGINT)
            try:
                proc.wait(timeout=60)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait(timeout=10)
    text = log_path.read_text(errors="replace")
    tail = text[text.rfind("Lap time [s]") - 200:] if "Lap time [s]" in text else text[-3000:]
    print(tail.strip())
    brakes = sum("stale or invalid state" in line for line in text.splitlines())
    if rows:
        first = [r["first_near_ms"] for r in rows]
        print(f"\n{len(rows)} resets: first state within {NEAR_M} m of the car "
              f"{min(first):.1f}-{max(first):.1f} ms after the teleport; largest distance "
              f"from {1e3 * DEADLINE_S:.0f} ms on {max(r['max_err_m'] for r in rows):.3f} m; "
              f"off-track {sum(r['off_track'] for r in rows):.0f}; largest |e_con| after a "
              f"reset {max(r['max_abs_e_con_m'] for r in rows):.2f} m; planner stale-state "
              f"warnings in the whole run {brakes}")
    return 0 if len(rows) == args.trials else 1


if __name__ == "__main__":
    sys.exit(main())
