"""The minimum-time lap driven in the simulator: does the car really do the optimal time?

``replay_min_time(lap, track, sim_settings)`` drives the optimal lap in a fresh
``services.simulator.Simulator`` with the stack's tracker (``services.planner.raceline.tracker``:
the lap's own steering and acceleration demand fed forward over the delays, a small
feedback on the lateral and heading error, an acceleration cut when the car drifts to the
outside of a bend) and times flying laps with the bench's ``LapTimer`` (arc length across
the start line; the footprint against the boundaries). The raceline planner drives the
same lap with the same tracker at its own 20 Hz; here the tracker runs every
``control_dt_s`` (5 ms) on the true CoG pose with no compute delay, so the replay measures
what the plan is worth with as little control loss as the car's delays allow.

The delays come from the simulator's settings: the speed loop acts ``actuation_delay_s``
(10 ms) after the pose, the wheels ``actuation_delay_s + steering_delay_s +
steering_time_constant_s`` (40 ms) after it. The car starts on the plan (pose, speed,
steering) about ``start_fraction`` of a lap before the start line, at the straightest node
nearby (the reset puts slip and yaw rate at their kinematic values), so an out lap settles
it before timing starts.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from services.planner import (
    DELTA,
    MinTimeLap,
    ReferenceLap,
    Tracker,
    TrackerGains,
    TrackerTiming,
    servo_reach,
)
from services.simulator import Command, LapTimer, Simulator
from shared.config.simulator import SimulatorSettings
from shared.track import Track


@dataclass(frozen=True)
class ReplayOptions:
    """How to drive the optimal lap.

    Attributes:
        laps: flying laps to time.
        control_dt_s: period of the tracker [s].
        gains: the tracker's feedback (``services.planner.raceline.tracker.TrackerGains``).
        start_fraction: the car starts this share of a lap before the start line.
    """

    laps: int = 2
    control_dt_s: float = 0.005
    gains: TrackerGains = field(default_factory=TrackerGains)
    start_fraction: float = 0.5


@dataclass(frozen=True)
class ReplayResult:
    """What the replay measured.

    Attributes:
        lap_times_s: the flying laps [s].
        off_track_events: times the footprint left the track during the timed laps.
        out_lap_off_track_events: ... before the first line crossing (the out lap).
        max_abs_error_m: largest distance of the CoG from the optimal line while timed [m].
        ocp_lap_time_s: the optimal lap's own time [s].
    """

    lap_times_s: tuple[float, ...]
    off_track_events: int
    out_lap_off_track_events: int
    max_abs_error_m: float
    ocp_lap_time_s: float

    @property
    def relative_error(self) -> float:
        """(mean replayed lap - OCP lap) / OCP lap [-]."""
        return float(np.mean(self.lap_times_s)) / self.ocp_lap_time_s - 1.0


def replay_timing(settings: SimulatorSettings, control_dt_s: float) -> TrackerTiming:
    """The tracker's timing in `settings`' simulator, driven every `control_dt_s` [s] on the
    true pose with no compute delay (module docstring)."""
    veh = settings.vehicle
    pure = settings.actuation_delay_s + settings.steering_delay_s
    tau = servo_reach(veh)
    if tau is not None:  # a slow servo: its lag inverted (TrackerTiming)
        return TrackerTiming(control_dt_s, settings.actuation_delay_s, pure, tau)
    return TrackerTiming(
        period_s=control_dt_s,
        speed_delay_s=settings.actuation_delay_s,
        steering_delay_s=pure + veh.steering_time_constant_s,
    )


def replay_min_time(
    lap: MinTimeLap,
    track: Track,
    sim_settings: SimulatorSettings | None = None,
    opts: ReplayOptions | None = None,
) -> ReplayResult:
    """Drive `lap` on `track` in a fresh simulator and time flying laps (module docstring)."""
    o = opts or ReplayOptions()
    settings = sim_settings or SimulatorSettings()
    veh = settings.vehicle
    plan = ReferenceLap.from_min_time(lap)
    tracker = Tracker.for_vehicle(plan, replay_timing(settings, o.control_dt_s), o.gains, veh)
    sim = Simulator(settings)
    timer = LapTimer(track, width_m=veh.width_m, length_m=veh.length_m)
    n = len(lap.v_mps)
    centre = round((1.0 - o.start_fraction) * n)
    window = (centre + np.arange(-n // 8, n // 8 + 1)) % n
    k0 = int(window[np.argmin(np.abs(lap.kappa_radpm[window]))])  # straightest: calm reset
    sim.reset(
        (float(lap.x_m[k0]), float(lap.y_m[k0]), float(lap.yaw_rad[k0])),
        speed_mps=float(lap.v_mps[k0]),
        steering_rad=float(lap.states[k0, DELTA]),
    )
    st = sim.state
    timer.update(sim.t_s, st.x_m, st.y_m, st.yaw_rad, st.v_mps)
    tracker.reset(float(plan.s_m[k0]))
    laps: list[float] = []
    off = off_out = 0
    max_e = 0.0
    t_limit = (o.laps + 2) * 3.0 * lap.lap_time_s
    while len(laps) < o.laps and sim.t_s < t_limit:
        st = sim.state
        cmd = tracker.command(st.x_m, st.y_m, st.yaw_rad)
        if timer.timing:
            max_e = max(max_e, abs(cmd.e_m))
        out = sim.step(Command(cmd.speed_mps, cmd.steering_rad), o.control_dt_s)
        s = out.state
        for ev in timer.update(out.t_s, s.x_m, s.y_m, s.yaw_rad, s.v_mps):
            if ev.kind == "off_track" and timer.timing:
                off += 1
            elif ev.kind == "off_track":
                off_out += 1
            elif ev.kind == "lap" and ev.lap_time_s is not None:
                laps.append(float(ev.lap_time_s))
    return ReplayResult(tuple(laps), off, off_out, max_e, lap.lap_time_s)
