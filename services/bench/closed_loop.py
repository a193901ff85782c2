"""One method racing the simulated car in one process (no Zenoh): the bench's closed loop.

Timing model of a planner tick of period ``Ts`` (``planner.dt_s``) at sim time ``t_k``:
the planner sees the car's true rear-axle pose at ``t_k``; its command takes effect after a
compute delay (the fixed ``compute_delay_s`` by default, so results do not depend on the
machine's load, or the measured solve time with ``delay_mode = "measured"``); until then the
previous command acts. The simulator then adds its own actuation and steering delays.

Laps are "flying": the car starts at standstill just past the start line, drives an out lap,
and the lap timer (arc length crossing the start line) times the next ``laps`` laps.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

from services.bench.results import LapRecord, MethodRun, Trace
from services.planner.planner import RECOVERING, SOLVED, Planner
from services.planner.raceline import RacelinePlanner
from services.simulator import Command, LapTimer, Simulator
from services.simulator.laps import centreline_pose
from services.simulator.state import rear_axle
from shared.config.simulator import SimulatorSettings
from shared.track import Track

#: The car gives up a method after this long without progress along the track [s].
STALL_TIMEOUT_S = 10.0
#: ... or this far from the centreline [m] (it is lost, not just off track).
LOST_E_CON_M = 5.0


@dataclass(frozen=True)
class LoopOptions:
    """How to run the closed loop.

    Attributes:
        laps: timed (flying) laps to drive.
        delay_mode: "fixed" (use compute_delay_s) or "measured" (each tick's solve time).
        compute_delay_s: fixed compute delay [s] before a command acts.
        start_offset_m: the car starts this far past the start line [m].
        max_lap_time_s: give up when a lap takes longer [s]; None: 60 s, or a lap at
            1 m/s on a longer track (the full-size F1TENTH maps are 260-460 m).
    """

    laps: int = 17
    delay_mode: str = "fixed"
    compute_delay_s: float = 0.002
    start_offset_m: float = 0.3
    max_lap_time_s: float | None = None


Progress = Callable[[int, int], None]


def run_method(
    name: str,
    planner: Planner | RacelinePlanner,
    track: Track,
    sim_settings: SimulatorSettings,
    opts: LoopOptions,
    progress: Progress | None = None,
) -> MethodRun:
    """Race `planner` on `track` against a fresh simulator; returns the method's record."""
    planner.reset()
    sim = Simulator(sim_settings)
    start = centreline_pose(track, opts.start_offset_m)
    sim.reset(start, speed_mps=0.0)
    veh = sim_settings.vehicle
    timer = LapTimer(track, width_m=veh.width_m, length_m=veh.length_m)
    lr = veh.lr_m
    ts = planner.settings.dt_s
    step_s = sim_settings.integration_step_s
    trace = Trace()
    laps: list[LapRecord] = []
    solve_ms: list[float] = []
    failures = 0
    off_all = off_out = 0
    cmd = Command(0.0, 0.0)
    st = sim.state
    timer.update(sim.t_s, st.x_m, st.y_m, st.yaw_rad, st.v_mps)
    best_progress, last_progress_t = timer.progress_m, sim.t_s
    abort_reason = ""
    max_lap = opts.max_lap_time_s or max(60.0, track.length_m / 1.0)
    t_limit = (opts.laps + 1.5) * max_lap
    while len(laps) < opts.laps:
        st = sim.state
        px, py, pyaw = rear_axle(st.x_m, st.y_m, st.yaw_rad, lr)
        res = planner.step(px, py, pyaw)
        solve_ms.append(res.solve_time_s * 1e3)
        failures += res.status not in (SOLVED, RECOVERING)
        trace.t_s.append(sim.t_s)
        trace.s_m.append(timer.s_m)
        trace.x_m.append(st.x_m)
        trace.y_m.append(st.y_m)
        trace.speed_mps.append(st.v_mps)
        trace.cmd_speed_mps.append(res.command.speed_mps)
        trace.e_con_m.append(timer.e_con_m)
        trace.beta.append(float(res.beta[0]))
        trace.lap.append(timer.laps_completed + 1 if timer.timing else 0)
        delay = res.solve_time_s if opts.delay_mode == "measured" else opts.compute_delay_s
        delay = min(max(delay, 0.0), ts)
        new_cmd = Command(res.command.speed_mps, res.command.steering_rad)
        # the previous command acts during the compute delay, then the new one
        chunks = [(cmd, delay)] if delay > 0 else []
        rest = ts - delay
        n = max(1, math.ceil(rest / step_s - 1e-9))
        chunks += [(new_cmd, rest / n)] * n
        for c, dt in chunks:
            out = sim.step(c, dt)
            s = out.state
            for ev in timer.update(out.t_s, s.x_m, s.y_m, s.yaw_rad, s.v_mps):
                if ev.kind == "off_track":
                    off_all += 1
                    off_out += not laps and not timer.timing
                if ev.kind == "lap" and ev.lap_time_s is not None:
                    laps.append(
                        LapRecord(
                            ev.lap_time_s,
                            ev.mean_speed_mps or 0.0,
                            ev.off_track_events,
                            ev.max_abs_e_con_m,
                        )
                    )
                    if progress:
                        progress(len(laps), opts.laps)
        cmd = new_cmd
        if timer.progress_m > best_progress + 0.5:
            best_progress, last_progress_t = timer.progress_m, sim.t_s
        if sim.t_s - last_progress_t > STALL_TIMEOUT_S:
            abort_reason = f"no progress for {STALL_TIMEOUT_S:.0f} s"
        elif abs(timer.e_con_m) > LOST_E_CON_M:
            abort_reason = f"lost: {abs(timer.e_con_m):.1f} m from the centreline"
        elif sim.t_s > t_limit:
            abort_reason = f"time limit {t_limit:.0f} s"
        if abort_reason:
            break
    extra: dict = {"recoveries": planner.recovery.episodes}
    if abort_reason:
        extra["aborted"] = abort_reason
    return MethodRun(
        name, laps, trace, solve_ms, failures, opts.laps, extra, off_all, off_out
    )
