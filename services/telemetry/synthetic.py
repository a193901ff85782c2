"""A synthetic but realistic message stream of a car lapping a track (tests, benchmarks).

``lap_stream`` yields every message the stack would publish while a car drives the
centreline at constant speed: pose, IMU, odometry, state, plan (with an (N+1, 4) horizon),
drive command, simulator truth and lidar scans at the stack's rates, lap events (timing start
and each completed lap) and a few log events, in time order. ``replay`` publishes such a
stream on a ``shared.bus.Bus`` in real time.
"""

from __future__ import annotations

import heapq
import math
import time
from collections.abc import Callable, Iterator, Mapping
from typing import Any

import numpy as np

from shared.car import CAR
from shared.config.methods import CIMPCC
from shared.keys import (
    DRIVE_CMD,
    EVENTS_LOG,
    IMU,
    LAP,
    ODOM,
    PLAN,
    POSE,
    SCAN,
    SIM_TRUTH,
    STATE,
    TOPIC_TYPES,
)
from shared.messages import (
    REGISTRY,
    DriveCmd,
    Imu,
    LapEvent,
    LogEvent,
    Message,
    Odom,
    Plan,
    Pose,
    Scan,
    SimTruth,
    State,
)
from shared.track import Track

#: Publishing rates of the stack [Hz] per key suffix.
STACK_RATES: Mapping[str, float] = {
    POSE: 40.0,
    IMU: 100.0,
    ODOM: 50.0,
    STATE: 40.0,
    PLAN: 20.0,
    DRIVE_CMD: 20.0,
    SIM_TRUTH: 50.0,
    SCAN: 10.0,
}


def _ticks(rates: Mapping[str, float], duration_s: float) -> Iterator[tuple[float, int, str]]:
    """(t [s], tie-break, suffix) of every periodic message in [0, duration_s), in time order."""
    streams = []
    for k, (suffix, hz) in enumerate(sorted(rates.items())):
        n = math.floor(duration_s * hz - 1e-9) + 1
        streams.append([(i / hz, k, suffix) for i in range(n)])
    yield from heapq.merge(*streams)


def lap_stream(
    track: Track,
    duration_s: float,
    *,
    t0_s: float = 100.0,
    speed_mps: float = 3.0,
    rates: Mapping[str, float] = STACK_RATES,
    horizon_n: int = 10,
    dt_plan_s: float = 0.05,
    beams: int = 1080,
    log_every_s: float = 1.0,
) -> Iterator[tuple[float, str, Message]]:
    """Yield (t [s from the start], key suffix, record) of a car lapping `track`.

    The car follows the centreline at `speed_mps` from s = 0; every stamp is ``t0_s + t``.
    Timing starts at t = 0 (a "start" lap event); a "lap" event follows each completed lap
    (lap time = lap length / speed). A log event ("info") is sent every `log_every_s`.
    """
    L = track.length_m
    curv = track.signed_curvature()
    rng = np.random.default_rng(1)
    base_ranges = (2.0 + 6.0 * rng.random(beams)).astype(np.float32)
    base_ranges[::97] = np.inf
    lap_time = L / speed_mps

    def pose_at(t: float) -> tuple[float, float, float, float, float]:
        s = speed_mps * t
        x, y = (float(v) for v in track.point_at(s))
        yaw = float(track.heading_at(s))
        k = float(np.interp(s % L, track.s_m, curv))
        return s, x, y, yaw, k

    events: list[tuple[float, int, str]] = [(0.0, -2, LAP)]
    events += [(k * lap_time, -2, LAP) for k in range(1, int(duration_s / lap_time) + 1)]
    events += [(k * log_every_s, -1, EVENTS_LOG)
               for k in range(int(duration_s / log_every_s) + 1) if k * log_every_s < duration_s]
    events.sort()
    laps_done = 0
    for t, _k, suffix in heapq.merge(_ticks(rates, duration_s), events):
        stamp = t0_s + t
        s, x, y, yaw, kappa = pose_at(t)
        steer = float(np.clip(math.atan(CAR.wheelbase_m * kappa), -0.4, 0.4))
        yaw_rate = float(np.clip(speed_mps * kappa, -20.0, 20.0))
        msg: Message
        if suffix == POSE:
            msg = Pose(stamp_s=stamp, x_m=x, y_m=y, yaw_rad=yaw,
                       cov=np.diag([0.0004, 0.0004, 0.0001]))
        elif suffix == IMU:
            msg = Imu(stamp_s=stamp, yaw_rate_radps=yaw_rate, ax_mps2=0.0,
                      ay_mps2=float(np.clip(speed_mps * yaw_rate, -400, 400)))
        elif suffix == ODOM:
            msg = Odom(stamp_s=stamp, speed_mps=speed_mps, steering_rad=steer,
                       yaw_rate_radps=yaw_rate)
        elif suffix == STATE:
            msg = State(stamp_s=stamp, x_m=x, y_m=y, yaw_rad=yaw, speed_mps=speed_mps,
                        yaw_rate_radps=yaw_rate, steering_rad=steer,
                        source_stamp_s=stamp - 0.002, valid=True)
        elif suffix == PLAN:
            ts = t + dt_plan_s * np.arange(horizon_n + 1)
            sh = speed_mps * ts
            pts = track.point_at(sh)
            horizon = np.column_stack([pts, np.unwrap(track.heading_at(sh)), sh])
            inputs = np.tile([speed_mps, steer, speed_mps], (horizon_n, 1))
            beta = np.full(horizon_n, 0.5 + 0.5 * math.cos(min(1.0, abs(kappa)) * math.pi))
            msg = Plan(stamp_s=stamp, horizon=horizon, inputs=inputs, beta=beta,
                       status="solved", solver_status="Solve_Succeeded", iterations=6,
                       solve_time_ms=4.0 + 2.0 * float(rng.random()), method=CIMPCC,
                       s_m=s % L, e_con_m=0.01 * math.sin(t), source_stamp_s=stamp - 0.003,
                       consecutive_failures=0)
        elif suffix == DRIVE_CMD:
            msg = DriveCmd(stamp_s=stamp, speed_mps=speed_mps, steering_rad=steer)
        elif suffix == SIM_TRUTH:
            msg = SimTruth(stamp_s=stamp, x_m=x, y_m=y, yaw_rad=yaw, speed_mps=speed_mps,
                           yaw_rate_radps=yaw_rate, slip_rad=0.01, steering_rad=steer,
                           s_m=s % L, e_con_m=0.01 * math.sin(t), off_track=False,
                           lap=int(s // L))
        elif suffix == SCAN:
            msg = Scan(stamp_s=stamp, angle_min_rad=-2.35, angle_increment_rad=4.7 / beams,
                       ranges_m=np.roll(base_ranges, int(t * 10)))
        elif suffix == LAP:
            if t == 0.0:
                msg = LapEvent(stamp_s=stamp, kind="start", lap=0, off_track_events=0)
            else:
                laps_done += 1
                msg = LapEvent(stamp_s=stamp, kind="lap", lap=laps_done, lap_time_s=lap_time,
                               mean_speed_mps=speed_mps, off_track_events=0,
                               max_abs_e_con_m=0.01)
        else:
            msg = LogEvent(stamp_s=stamp, level="info", source="synthetic",
                           text=f"synthetic stream at t = {t:.1f} s")
        yield t, suffix, msg


def replay(
    bus: Any,
    stream: Iterator[tuple[float, str, Message]],
    *,
    realtime: bool = True,
    before_put: Callable[[float], None] | None = None,
) -> dict[str, int]:
    """Publish `stream` on `bus` (a ``shared.bus.Bus``); returns messages sent per suffix.

    With `realtime` each message is sent at its time t after the start (wall clock);
    `before_put(t)` is called before each message (e.g. to inject garbage).
    """
    pubs = {suffix: bus.publisher(bus.keys.key(suffix), REGISTRY[tag])
            for suffix, tag in TOPIC_TYPES.items()}
    sent: dict[str, int] = {}
    start = time.monotonic()
    for t, suffix, msg in stream:
        if realtime:
            delay = start + t - time.monotonic()
            if delay > 0:
                time.sleep(delay)
        if before_put is not None:
            before_put(t)
        pubs[suffix].put(msg)
        sent[suffix] = sent.get(suffix, 0) + 1
    return sent
