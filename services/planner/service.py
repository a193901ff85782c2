"""The planner service: ``state`` in, ``cmd/drive`` and ``planner/plan`` out, over Zenoh.

Event-driven: each new ``State`` is planned at once (low pose-to-command latency), at most
once per planner period (a state arriving sooner than ``MIN_PERIOD_FRACTION * dt_s`` after
the last solve is skipped, the next one is used). A state older than ``stale_state_s``
(by its ``source_stamp_s`` against this machine's wall clock) or none at all for that long
gives a braking command (speed 0), never a guess. Stamps are wall-clock seconds.
"""

from __future__ import annotations

import argparse
import logging
import threading
import time
from collections.abc import Sequence

import numpy as np

from services.planner.planner import BRAKING, SOLVED, Planner, SolveResult
from shared.bus import Bus, DropReporter
from shared.config import RacestackConfig
from shared.messages import DriveCmd, LogEvent, Plan, State
from shared.service_shell import run_service
from shared.track import load_track

log = logging.getLogger(__name__)
SERVICE = "planner"
#: A new state is solved only once this share of the planner period has passed.
MIN_PERIOD_FRACTION = 0.8


def plan_message(res: SolveResult, stamp_s: float, source_stamp_s: float) -> Plan:
    """The ``planner/plan`` record of one solve result."""
    return Plan(
        stamp_s=stamp_s,
        horizon=np.ascontiguousarray(res.states, dtype=np.float64),
        inputs=np.ascontiguousarray(res.inputs, dtype=np.float64),
        beta=np.ascontiguousarray(res.beta, dtype=np.float64),
        status=res.status,
        solver_status=res.solver_status[:200],
        iterations=max(0, res.iterations),
        solve_time_ms=res.solve_time_s * 1e3,
        method=res.method,
        s_m=res.s_m,
        e_con_m=float(np.clip(res.e_con_m, -1e3, 1e3)),
        source_stamp_s=source_stamp_s,
        consecutive_failures=res.consecutive_failures,
    )


def run(cfg: RacestackConfig, args: argparse.Namespace, stop: threading.Event) -> int:
    """The service body (see the module docstring)."""
    track = load_track(cfg.track.source)
    log.info(
        "building the %s planner on %s (compiled problem cached)", cfg.planner.method, track.name
    )
    planner = Planner(track, cfg.planner, cfg.curvature)
    period = cfg.planner.dt_s
    stale_s = cfg.planner.stale_state_s
    with Bus(cfg.bus, SERVICE) as bus:
        states = bus.subscribe(bus.keys.state, State)
        cmd_pub = bus.publisher(bus.keys.drive_cmd, DriveCmd)
        plan_pub = bus.publisher(bus.keys.plan, Plan)
        log_pub = bus.publisher(bus.keys.events_log, LogEvent)
        drops = DropReporter(bus, SERVICE, publisher=log_pub)

        def say(level: str, text: str) -> None:
            getattr(log, level)(text)
            log_pub.put(LogEvent(stamp_s=time.time(), level=level, source=SERVICE, text=text))

        log.info("ready; waiting for %s", bus.keys.state)
        last_solve = 0.0
        last_state_wall = time.monotonic()
        braking = True
        steering = 0.0
        while not stop.is_set():
            drops.poll()
            st = states.wait(timeout_s=period)
            now_wall = time.time()
            if st is not None:
                last_state_wall = time.monotonic()
                age = now_wall - st.source_stamp_s
                if age > stale_s or not st.valid:
                    if not braking:
                        say("warning", f"stale or invalid state (age {age * 1e3:.0f} ms): braking")
                    braking = True
                    cmd_pub.put(DriveCmd(stamp_s=now_wall, speed_mps=0.0, steering_rad=steering))
                    continue
                if time.monotonic() - last_solve < MIN_PERIOD_FRACTION * period:
                    continue
                last_solve = time.monotonic()
                res = planner.step(st.x_m, st.y_m, st.yaw_rad)
                steering = res.command.steering_rad
                stamp = time.time()
                cmd_pub.put(
                    DriveCmd(stamp_s=stamp, speed_mps=res.command.speed_mps, steering_rad=steering)
                )
                plan_pub.put(plan_message(res, stamp, st.source_stamp_s))
                if braking:
                    say("info", "state fresh: racing")
                    braking = False
                if res.status != SOLVED:
                    level = "error" if res.status == BRAKING else "warning"
                    say(level, f"solver {res.status}: {res.solver_status}")
            elif time.monotonic() - last_state_wall > stale_s:
                if not braking:
                    say("warning", f"no state for {stale_s * 1e3:.0f} ms: braking")
                    braking = True
                    planner.reset()
                cmd_pub.put(DriveCmd(stamp_s=now_wall, speed_mps=0.0, steering_rad=steering))
        log.info("stopping")
    return 0


def main(argv: Sequence[str] | None = None) -> int:
    """``python -m services.planner``."""
    return run_service(SERVICE, argv, run, description=__doc__.splitlines()[0])
