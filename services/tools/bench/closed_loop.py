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

from services.planner import PlannerLike, SolveResult
from services.simulator import Command, LapTimer, Simulator, centreline_pose, rear_axle
from services.tools.bench.estimation import InLoopEstimator
from services.tools.bench.race import race
from shared.config.localization import LocalizationSettings
from shared.config.simulator import SimulatorSettings
from shared.evaluation import LapRecord, MethodRun, Trace
from shared.evaluation.results import OUT_LAP_START_M
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
        estimator: what pose the planner sees: "truth" (the true rear axle), "ekf" or
            "lidar" (``services.tools.bench.estimation``: the simulator's sensors through the
            bridge's filter); `localization`: its ``[localization]`` settings.
    """

    laps: int = 17
    delay_mode: str = "fixed"
    compute_delay_s: float = 0.002
    start_offset_m: float = OUT_LAP_START_M
    max_lap_time_s: float | None = None
    estimator: str = "truth"
    localization: LocalizationSettings | None = None


Progress = Callable[[int, int], None]


class SimulatorPlant:
    """The dynamic ``Simulator`` as a plant of ``race``: the bench's timing model (module
    docstring), the ``LapTimer``, the trace, the laps and the give-up rules.

    Attributes:
        sim, timer: the simulator and its lap timer.
        trace: one row per tick (the state the planner saw, its command, the car's rear
            slip angle).
        laps: the timed laps.
        off_all, off_out: off-track events, all and in the out lap.
        off_xy: where the car was at each off-track event [m].
    """

    def __init__(
        self,
        track: Track,
        sim_settings: SimulatorSettings,
        opts: LoopOptions,
        progress: Progress | None = None,
    ) -> None:
        self.opts = opts
        self.progress = progress
        self.sim = Simulator(sim_settings)
        self.sim.reset(centreline_pose(track, opts.start_offset_m), speed_mps=0.0)
        veh = sim_settings.vehicle
        self.timer = LapTimer(track, width_m=veh.width_m, length_m=veh.length_m)
        self.lr = veh.lr_m
        self.step_s = sim_settings.integration_step_s
        self.trace = Trace()
        self.laps: list[LapRecord] = []
        self.off_all = self.off_out = 0
        self.off_xy: list[tuple[float, float]] = []
        self.cmd = Command(0.0, 0.0)
        st = self.sim.state
        self.timer.update(self.sim.t_s, st.x_m, st.y_m, st.yaw_rad, st.v_mps)
        self.best_progress, self.last_progress_t = self.timer.progress_m, self.sim.t_s
        self.abort_reason = ""
        max_lap = opts.max_lap_time_s or max(60.0, track.length_m / 1.0)
        self.t_limit = (opts.laps + 1.5) * max_lap
        self.estimator: InLoopEstimator | None = None
        if opts.estimator != "truth":
            self.estimator = InLoopEstimator(
                opts.estimator,
                track,
                sim_settings,
                opts.localization or LocalizationSettings(),
                self.true_pose(),
                self.sim.t_s,
            )

    @property
    def laps_completed(self) -> int:
        """Timed laps completed."""
        return len(self.laps)

    @property
    def stop_reason(self) -> str:
        """Why the car gave up ("" while it races)."""
        return self.abort_reason

    def true_pose(self) -> tuple[float, float, float]:
        """The car's true rear-axle pose."""
        st = self.sim.state
        return rear_axle(st.x_m, st.y_m, st.yaw_rad, self.lr)

    def pose(self) -> tuple[float, float, float]:
        """The pose the planner sees: the truth, or the estimator's estimate now."""
        if self.estimator is None:
            return self.true_pose()
        return self.estimator.pose(self.sim.t_s, self.true_pose())

    def advance(self, result: SolveResult, period_s: float) -> None:
        """Record the tick, then drive one period: the previous command during the compute
        delay, then `result`'s."""
        sim, timer, trace, opts = self.sim, self.timer, self.trace, self.opts
        st = sim.state
        res = result
        trace.t_s.append(sim.t_s)
        trace.s_m.append(timer.s_m)
        trace.x_m.append(st.x_m)
        trace.y_m.append(st.y_m)
        trace.speed_mps.append(st.v_mps)
        trace.cmd_speed_mps.append(res.command.speed_mps)
        trace.e_con_m.append(timer.e_con_m)
        trace.beta.append(float(res.beta[0]))
        trace.lap.append(timer.laps_completed + 1 if timer.timing else 0)
        trace.rear_slip_rad.append(sim.model.tyre_state(sim.state_tuple, 0.0).slip_rear_rad)
        ts = period_s
        delay = res.solve_time_s if opts.delay_mode == "measured" else opts.compute_delay_s
        delay = min(max(delay, 0.0), ts)
        new_cmd = Command(res.command.speed_mps, res.command.steering_rad)
        # the previous command acts during the compute delay, then the new one
        chunks = [(self.cmd, delay)] if delay > 0 else []
        rest = ts - delay
        n = max(1, math.ceil(rest / self.step_s - 1e-9))
        chunks += [(new_cmd, rest / n)] * n
        for c, dt in chunks:
            out = sim.step(c, dt)
            if self.estimator is not None:
                self.estimator.feed(out)
            s = out.state
            for ev in timer.update(out.t_s, s.x_m, s.y_m, s.yaw_rad, s.v_mps):
                if ev.kind == "off_track":
                    self.off_all += 1
                    self.off_xy.append((s.x_m, s.y_m))
                    self.off_out += not self.laps and not timer.timing
                if ev.kind == "lap" and ev.lap_time_s is not None:
                    self.laps.append(
                        LapRecord(
                            ev.lap_time_s,
                            ev.mean_speed_mps or 0.0,
                            ev.off_track_events,
                            ev.max_abs_e_con_m,
                        )
                    )
                    if self.progress:
                        self.progress(len(self.laps), opts.laps)
        self.cmd = new_cmd
        if timer.progress_m > self.best_progress + 0.5:
            self.best_progress, self.last_progress_t = timer.progress_m, sim.t_s
        if sim.t_s - self.last_progress_t > STALL_TIMEOUT_S:
            self.abort_reason = f"no progress for {STALL_TIMEOUT_S:.0f} s"
        elif abs(timer.e_con_m) > LOST_E_CON_M:
            self.abort_reason = f"lost: {abs(timer.e_con_m):.1f} m from the centreline"
        elif sim.t_s > self.t_limit:
            self.abort_reason = f"time limit {self.t_limit:.0f} s"


def run_method(
    name: str,
    planner: PlannerLike,
    track: Track,
    sim_settings: SimulatorSettings,
    opts: LoopOptions,
    progress: Progress | None = None,
) -> MethodRun:
    """Race `planner` on `track` against a fresh simulator; returns the method's record."""
    planner.reset()
    plant = SimulatorPlant(track, sim_settings, opts, progress)
    got = race(planner, plant, opts.laps, reset=False)
    solve_ms = [t * 1e3 for t in got.solve_times_s]
    extra: dict = {"recoveries": planner.recovery.episodes}
    if plant.abort_reason:
        extra["aborted"] = plant.abort_reason
    if plant.estimator is not None:
        extra["localisation"] = plant.estimator.errors()
    return MethodRun(
        name,
        plant.laps,
        plant.trace,
        solve_ms,
        got.failures,
        opts.laps,
        extra,
        plant.off_all,
        plant.off_out,
        plant.off_xy,
    )
