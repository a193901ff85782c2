"""``racestack sysid --drive``: the identification drive in the simulator, recorded.

The manoeuvre programme (``shared.vehicle.sysid_drive``: speed steps, steering steps and
sweeps, cornering at a rising lateral acceleration that stops short of the grip seen) drives
the simulator's car in-process: a command every ``[planner] dt_s`` from the programme, the
simulator stepped at its integration step between them (its actuation and steering delays
acting), the simulator's own odometry and IMU (with their noise) and the commands
recorded as the stack records them (``cmd/drive``, ``vehicle/odom``, ``vehicle/imu``
through the telemetry ``Recorder``) into ``RUN_DIR/telemetry.0000.rrd``, which
``racestack sysid RUN_DIR --out car.toml`` reads. The programme sees the true pose (as the
bench's "truth" estimator) and the measured speed, steering, yaw rate and a_y.

On the real car the same programme would be the planner's command source; that process
version is not written yet (the drive runs in the simulator only).
"""

from __future__ import annotations

import math
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from services.simulator import ImuSensor, LapTimer, OdometrySensor, Simulator, centreline_pose
from services.telemetry import Recorder, open_segment
from shared.config import ConfigError, config_from_dict, load_config
from shared.config.simulator import SimulatorSettings
from shared.config.telemetry import TelemetrySettings
from shared.keys import DRIVE_CMD, IMU, ODOM
from shared.messages import DriveCmd, Imu, Message, Odom
from shared.track import Track, TrackError, load_track
from shared.vehicle.sysid_drive import DriveProgramme, DriveSettings, Observation

Signals = dict[str, tuple[np.ndarray, np.ndarray]]
#: The signals ``identify`` reads, in the order recorded.
SIGNAL_NAMES = ("cmd_speed_mps", "cmd_steering_rad", "speed_mps", "steering_rad",
                "yaw_rate_radps", "ax_mps2", "ay_mps2")


class SignalTap:
    """Records what the stack would: the commands as sent, the simulator's odometry and
    IMU (their noise and rates) from each ``StepResult`` (``feed``)."""

    def __init__(self, settings: SimulatorSettings, seed: int) -> None:
        self.imu = ImuSensor(settings.imu, np.random.default_rng(seed + 101))
        self.odo = OdometrySensor(settings.odometry, np.random.default_rng(seed + 102))
        self.rows: dict[str, list[tuple[float, float]]] = {k: [] for k in SIGNAL_NAMES}
        self.last: dict[str, float] = {"speed_mps": 0.0, "steering_rad": 0.0,
                                       "yaw_rate_radps": 0.0, "ay_mps2": 0.0}

    def command(self, t_s: float, speed_mps: float, steering_rad: float) -> None:
        """A command sent at `t_s` [s]."""
        self.rows["cmd_speed_mps"].append((t_s, float(speed_mps)))
        self.rows["cmd_steering_rad"].append((t_s, float(steering_rad)))

    def feed(self, out: Any) -> None:
        """One simulator step's truth through the sensors."""
        rows, last = self.rows, self.last
        for m in self.imu.update(out):
            rows["yaw_rate_radps"].append((m.stamp_s, m.yaw_rate_radps))
            rows["ax_mps2"].append((m.stamp_s, m.accel_long_mps2))
            rows["ay_mps2"].append((m.stamp_s, m.accel_lat_mps2))
            last["yaw_rate_radps"], last["ay_mps2"] = m.yaw_rate_radps, m.accel_lat_mps2
        for m in self.odo.update(out):
            rows["speed_mps"].append((m.stamp_s, m.speed_mps))
            rows["steering_rad"].append((m.stamp_s, m.steering_rad))
            last["speed_mps"], last["steering_rad"] = m.speed_mps, m.steering_rad

    def signals(self) -> Signals:
        """The recorded signals: name -> (stamps [s], values)."""
        return {k: (np.array([a for a, _ in v]), np.array([b for _, b in v]))
                for k, v in self.rows.items()}


@dataclass
class DriveSummary:
    """How a drive went: simulated and wall time [s], off-track events, the phases'
    trace (one row per tick: t, phase, speed command, envelope target, lateral error,
    off-track events so far), the envelope at
    the end (saturated?, a_y where, largest a_y seen), the largest |lateral error| [m]."""

    sim_s: float
    wall_s: float
    off_track: int
    max_abs_e_m: float
    saturated: bool
    ay_saturation_mps2: float
    ay_seen_mps2: float
    ay_target_mps2: float
    reason: str
    trace: list[tuple[float, str, float, float, float, int]]


def run_drive(track: Track, sim_settings: SimulatorSettings, dt_s: float = 0.05,
              settings: DriveSettings | None = None, seed: int | None = None
              ) -> tuple[Signals, DriveSummary]:
    """Drive the programme on `track` in the simulator; the recorded signals and a
    summary. `dt_s`: the command period [s]."""
    t0 = time.perf_counter()
    veh = sim_settings.vehicle
    prog = DriveProgramme(track, veh.wheelbase_m, veh.steering_max_rad, settings)
    sim = Simulator(sim_settings)
    sim.reset(centreline_pose(track, 0.0), speed_mps=0.0)
    timer = LapTimer(track, width_m=veh.width_m, length_m=veh.length_m)
    tap = SignalTap(sim_settings, sim_settings.seed if seed is None else seed)
    tap.feed(sim.snapshot())
    state = prog.start()
    n_sub = max(1, math.ceil(dt_s / sim_settings.integration_step_s - 1e-9))
    off = 0
    max_e = 0.0
    s_hint = 0.0
    trace: list[tuple[float, str, float, float, float, int]] = []
    while True:
        st = sim.state
        s_m, e_m = track.project_near(st.x_m, st.y_m, s_hint)
        s_hint = s_m
        max_e = max(max_e, abs(e_m))
        last = tap.last
        obs = Observation(sim.t_s, st.x_m, st.y_m, st.yaw_rad, s_m, e_m, last["speed_mps"],
                          last["steering_rad"], last["yaw_rate_radps"], last["ay_mps2"])
        cmd, state = prog.command(obs, state)
        if cmd.phase == "done":
            break
        trace.append((sim.t_s, cmd.phase, cmd.speed_mps, state.envelope.ay_target_mps2, e_m,
                      off))
        tap.command(sim.t_s, cmd.speed_mps, cmd.steering_rad)
        for j in range(n_sub):
            out = sim.step((cmd.speed_mps, cmd.steering_rad) if j == 0 else None,
                           dt_s / n_sub)
            tap.feed(out)
            s = out.state
            off += sum(ev.kind == "off_track"
                       for ev in timer.update(out.t_s, s.x_m, s.y_m, s.yaw_rad, s.v_mps))
    env = state.envelope
    summary = DriveSummary(sim.t_s, time.perf_counter() - t0, off, max_e, env.saturated,
                           env.ay_saturation_mps2, env.ay_seen_mps2, env.ay_target_mps2,
                           env.reason, trace)
    return tap.signals(), summary


def write_recording(path: Path, signals: Signals,
                    keys: tuple[str, ...] = (ODOM, IMU, DRIVE_CMD)) -> Path:
    """Record `signals` as the telemetry service does: the messages of `keys` through the
    ``Recorder`` into the segment `path` (closed, with its footer)."""
    msgs: list[tuple[float, str, Message]] = []
    if ODOM in keys:
        t, v = signals["speed_mps"]
        d = signals["steering_rad"][1]
        msgs += [(ti, ODOM, Odom(stamp_s=ti, speed_mps=vi, steering_rad=di))
                 for ti, vi, di in zip(t.tolist(), v.tolist(), d.tolist(), strict=True)]
    if IMU in keys:
        t, r = signals["yaw_rate_radps"]
        ax, ay = signals["ax_mps2"][1], signals["ay_mps2"][1]
        msgs += [(ti, IMU, Imu(stamp_s=ti, yaw_rate_radps=ri, ax_mps2=xi, ay_mps2=yi))
                 for ti, ri, xi, yi in zip(t.tolist(), r.tolist(), ax.tolist(), ay.tolist(),
                                           strict=True)]
    if DRIVE_CMD in keys:
        t, v = signals["cmd_speed_mps"]
        d = signals["cmd_steering_rad"][1]
        msgs += [(ti, DRIVE_CMD, DriveCmd(stamp_s=ti, speed_mps=vi, steering_rad=di))
                 for ti, vi, di in zip(t.tolist(), v.tolist(), d.tolist(), strict=True)]
    msgs.sort(key=lambda m: m[0])
    settings = TelemetrySettings()
    path.parent.mkdir(parents=True, exist_ok=True)
    rec = open_segment(settings, path, "sysid-drive")
    recorder = Recorder(rec, settings)
    recorder.log_static(None)
    now = time.time()
    for t_s, suffix, msg in msgs:
        recorder.handle(suffix, msg, now + t_s)
    recorder.close()
    rec.flush(timeout_sec=5.0)
    rec.disconnect()
    return path


def drive_main(out: str, track_spec: str | None, car_config: str | None,
               prog: str = "racestack sysid") -> int:
    """``racestack sysid --drive``: record the drive of `car_config`'s car (a ``--config``
    file; None: the defaults) on `track_spec` (None: its ``[track]`` source) into
    ``out/telemetry.0000.rrd``; 0 written, 2 bad input."""
    try:
        cfg = load_config(car_config) if car_config else config_from_dict({})
        track = load_track(track_spec or cfg.track.source)
    except (ConfigError, TrackError, OSError) as exc:
        print(f"{prog}: error: {str(exc).splitlines()[0]}", file=sys.stderr)
        return 2
    settings = DriveSettings()
    print(f"{prog}: identification drive on {track.name} ({settings.duration_s:.0f} s "
          "simulated: speed steps, steering steps, cornering at rising a_y)", flush=True)
    signals, summ = run_drive(track, cfg.simulator, cfg.planner.dt_s, settings)
    path = write_recording(Path(out) / "telemetry.0000.rrd", signals)
    print(report_line(summ))
    print(f"wrote {path}\nnext: racestack sysid {out} --out car.toml "
          f"{'--config ' + car_config if car_config else ''}".rstrip())
    return 0


def report_line(summ: DriveSummary) -> str:
    """One line on how a drive went."""
    sat = (f"saturation seen at |a_y| {summ.ay_saturation_mps2:.2f} m/s^2 ({summ.reason}), "
           f"held at {summ.ay_target_mps2:.2f}" if summ.saturated else
           f"no saturation seen (target reached {summ.ay_target_mps2:.2f} m/s^2)")
    return (f"{summ.sim_s:.0f} s simulated ({summ.wall_s:.0f} s wall), {summ.off_track} "
            f"off-track events, largest lateral error {summ.max_abs_e_m:.2f} m, largest "
            f"|a_y| {summ.ay_seen_mps2:.2f} m/s^2; {sat}")
