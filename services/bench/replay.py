"""The minimum-time lap driven in the simulator: does the car really do the optimal time?

``replay_min_time(lap, track, sim_settings)`` feeds the optimal line and its speeds forward
into a fresh ``services.simulator.Simulator`` with a small feedback, and times flying laps
with the bench's ``LapTimer`` (arc length across the start line; the footprint against the
boundaries). Every ``control_dt_s`` the car's CoG is projected onto the optimal line
(arc length ``s``, distance ``e`` right +); with ``p(s)`` the plan at ``s``, ``s_a = s + v
T_speed`` and the speed error ``dv = v - v_p(s)``::

    steering = delta_p(s + v T_steer) + k_e e - k_psi wrap(yaw - yaw_p(s))
    a_cmd    = a_p(s_a) - k_v dv - k_out max(0, e_out),  e_out = e tanh(kappa_p(s) / 0.1)
    speed    = v_p(s_a) + dv + a_cmd / k_loop

``T_steer`` (45 ms) looks ahead over the steering's delays (10 ms actuation + 20 ms steering
+ the servo's 10 ms time constant + half a control period), ``T_speed`` over the 10 ms
actuation delay. The simulator's speed loop is proportional, ``a = k_loop (v_cmd - v)``
(``speed_gain_accel_per_s`` 4.755 / ``speed_gain_brake_per_s`` 19.02 by the sign of
``a_cmd``), so the speed command asks it for ``a_cmd``: the planned acceleration demand
``a_p`` (the OCP's input), a speed correction, and a cut when the car drifts towards the
outside of the bend (``e_out > 0``). That cut matters: at the optimum the front axle is at
its friction ellipse through most corners (and the steering at its end stop in the
tightest), so more steering buys no lateral force there; only giving up longitudinal force
does (without it the car slid off the track 3 times a lap on map416). The car starts on
the plan (pose, speed, steering) about ``start_fraction`` of a lap before the start line,
at the straightest node nearby (the reset puts slip and yaw rate at their kinematic
values), so an out lap settles it before timing starts.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from services.planner.mintime import MinTimeLap
from services.planner.mintime_model import DELTA
from services.simulator import Command, LapTimer, Simulator
from shared.config.simulator import SimulatorSettings
from shared.track import Track

#: Path curvature [1/m] above which a bend's outside is fully defined (tanh scale).
OUTWARD_KAPPA_1PM = 0.1


@dataclass(frozen=True)
class ReplayOptions:
    """How to drive the optimal lap.

    Attributes:
        laps: flying laps to time.
        control_dt_s: period of the feedback [s].
        steering_lead_s: the steering plan is read this far ahead [s].
        speed_lead_s: the speed plan is read this far ahead [s].
        k_lateral_radpm: steering per metre of lateral error [rad/m].
        k_heading: steering per radian of yaw error [-].
        k_speed_per_s: acceleration per m/s of speed error [1/s].
        k_outward_per_s2: acceleration cut per metre of lateral error towards the outside of
            the line's bend [1/s^2].
        start_fraction: the car starts this share of a lap before the start line.
    """

    laps: int = 2
    control_dt_s: float = 0.005
    steering_lead_s: float = 0.045
    speed_lead_s: float = 0.01
    k_lateral_radpm: float = 0.5
    k_heading: float = 1.2
    k_speed_per_s: float = 4.755
    k_outward_per_s2: float = 40.0
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


class _Plan:
    """The optimal lap as periodic functions of the driven line's arc length."""

    def __init__(self, lap: MinTimeLap) -> None:
        xy = np.column_stack([lap.x_m, lap.y_m])
        self.line = Track("min-time line", xy, np.ones(len(xy)), np.ones(len(xy)))
        L = self.line.length_m
        self.length = L
        self.s = np.append(self.line.s_m, L)
        yaw = np.asarray(lap.yaw_rad, dtype=float)
        closing = yaw[-1] + math.remainder(yaw[0] - yaw[-1], math.tau)
        self.turns = closing - yaw[0]
        self.yaw = np.append(yaw, closing)
        self.delta = np.append(lap.states[:, DELTA], lap.states[0, DELTA])
        self.v = np.append(lap.v_mps, lap.v_mps[0])
        self.a = np.append(lap.inputs[:, 1], lap.inputs[0, 1])
        self.kappa = np.append(lap.kappa_radpm, lap.kappa_radpm[0])

    def at(self, table: np.ndarray, s: float) -> float:
        return float(np.interp(s % self.length, self.s, table))

    def yaw_at(self, s: float) -> float:
        return float(np.interp(s % self.length, self.s, self.yaw))


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
    plan = _Plan(lap)
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
    s_hint = float(plan.line.s_m[k0])
    laps: list[float] = []
    off = off_out = 0
    max_e = 0.0
    t_limit = (o.laps + 2) * 3.0 * lap.lap_time_s
    while len(laps) < o.laps and sim.t_s < t_limit:
        st = sim.state
        s_l, e_l = plan.line.project_near(st.x_m, st.y_m, s_hint)
        s_hint = s_l
        if timer.timing:
            max_e = max(max_e, abs(e_l))
        yaw_err = math.remainder(st.yaw_rad - plan.yaw_at(s_l), math.tau)
        v = max(st.v_mps, 0.0)
        steer = (
            plan.at(plan.delta, s_l + v * o.steering_lead_s)
            + o.k_lateral_radpm * e_l
            - o.k_heading * yaw_err
        )
        s_v = s_l + v * o.speed_lead_s
        a_p = plan.at(plan.a, s_v)
        error = st.v_mps - plan.at(plan.v, s_l)
        outward = max(0.0, e_l * math.tanh(plan.at(plan.kappa, s_l) / OUTWARD_KAPPA_1PM))
        a_cmd = a_p - o.k_speed_per_s * error - o.k_outward_per_s2 * outward
        gain = veh.speed_gain_accel_per_s if a_cmd >= 0.0 else veh.speed_gain_brake_per_s
        speed = plan.at(plan.v, s_v) + error + a_cmd / gain
        out = sim.step(Command(speed, steer), o.control_dt_s)
        s = out.state
        for ev in timer.update(out.t_s, s.x_m, s.y_m, s.yaw_rad, s.v_mps):
            if ev.kind == "off_track" and timer.timing:
                off += 1
            elif ev.kind == "off_track":
                off_out += 1
            elif ev.kind == "lap" and ev.lap_time_s is not None:
                laps.append(float(ev.lap_time_s))
    return ReplayResult(tuple(laps), off, off_out, max_e, lap.lap_time_s)
