"""EKF accuracy over a simulated race: fused state vs raw pose, with and without latency
compensation (issue 13).

    python -m benchmarks.localization_ekf [--track ../shared/tracks/map416] [--laps 3]
        [--seeds 3] [--rate-hz 30] [--latency-ms 30] [--noise-cm 2] [--noise-deg 2]

The raceline planner races the simulated car on the TRUE pose (so every variant sees the same
drive); the drive's truth then goes through the simulator's sensor models (pose at
`--rate-hz`, `--latency-ms` late, white noise; IMU; wheel odometry) into the bridge's
``FusedEstimator``. Every 10 ms step the estimate is compared with the true rear-axle pose:
RMS position and yaw error of

- the fused state with latency compensation (the default),
- the fused state applying each measurement at its arrival (``latency_compensation = false``),
- the raw pose: the newest one received, as it is (what a bridge without a filter passes on),
  and the pose noise itself (each pose against the truth at its own capture).
"""

from __future__ import annotations

import argparse
import math
import time

import numpy as np

from services.localization_bridge import FusedEstimator
from services.planner import RacelinePlanner, ensure_artefacts
from services.simulator import SensorSuite, StepResult, rear_axle
from services.tools.bench import LoopOptions, SimulatorPlant, race
from shared.angles import wrap_angle
from shared.config import load_config
from shared.config.methods import RACELINE
from shared.config.simulator import PoseSensorSettings
from shared.track import load_track


def drive(track, cfg, laps: int) -> list[StepResult]:
    """Every simulation step of a raceline race on the true pose."""
    ensure_artefacts(RACELINE, track, cfg.planner, cfg.vehicle)
    planner = RacelinePlanner(track, cfg.planner, cfg.curvature, vehicle=cfg.vehicle)
    plant = SimulatorPlant(track, cfg.simulator, LoopOptions(laps=laps))
    steps: list[StepResult] = []
    step = plant.sim.step

    def recording(c, dt):
        out = step(c, dt)
        steps.append(out)
        return out

    plant.sim.step = recording  # type: ignore[method-assign]
    race(planner, plant, laps)
    return steps


def errors(steps: list[StepResult], sim_settings, loc, lr_m: float) -> dict[str, tuple]:
    """(RMS position [m], RMS yaw [deg]) of each variant (module docstring)."""
    out = {}
    for name, settings in (
        ("fused, compensated", loc),
        ("fused, at arrival", loc.model_copy(update={"latency_compensation": False})),
    ):
        sensors = SensorSuite(sim_settings, None)
        est = FusedEstimator(settings)
        e_xy, e_yaw, r_xy, r_yaw, n_xy, n_yaw = [], [], [], [], [], []
        truth_at: dict[float, tuple[float, float, float]] = {}
        last = None
        for s in steps:
            now = s.t_s
            got = sensors.update(s)
            st = s.state
            tx, ty, tyaw = rear_axle(st.x_m, st.y_m, st.yaw_rad, lr_m)
            truth_at[round(now, 6)] = (tx, ty, tyaw)
            for m in got.imu:
                est.imu(m.stamp_s, m.yaw_rate_radps, now)
            for o in got.odometry:
                est.odom(o.stamp_s, o.speed_mps, o.steering_rad, None, now)
            for p in got.pose:
                est.pose(p.stamp_s, p.x_m, p.y_m, p.yaw_rad, None, now)
                last = p
                cx, cy, cyaw = truth_at.get(round(p.stamp_s, 6), (tx, ty, tyaw))
                n_xy.append(math.hypot(p.x_m - cx, p.y_m - cy))
                n_yaw.append(wrap_angle(p.yaw_rad - cyaw))
            if last is None or now < 1.0:
                continue
            e = est.estimate(now)
            e_xy.append(math.hypot(e.x_m - tx, e.y_m - ty))
            e_yaw.append(wrap_angle(e.yaw_rad - tyaw))
            r_xy.append(math.hypot(last.x_m - tx, last.y_m - ty))
            r_yaw.append(wrap_angle(last.yaw_rad - tyaw))
        out[name] = (rms(e_xy), math.degrees(rms(e_yaw)), dict(est.counts))
        raw = (rms(r_xy), math.degrees(rms(r_yaw)), {})
        noise = (rms(n_xy), math.degrees(rms(n_yaw)), {})
    out["raw pose, newest received"] = raw
    out["raw pose at its capture (noise)"] = noise
    return out


def rms(v: list[float]) -> float:
    return float(np.sqrt(np.mean(np.square(v)))) if v else math.nan


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--track", default="../shared/tracks/map416")
    ap.add_argument("--config", default=None)
    ap.add_argument("--laps", type=int, default=3)
    ap.add_argument("--seeds", type=int, default=3)
    ap.add_argument("--rate-hz", type=float, default=30.0)
    ap.add_argument("--latency-ms", type=float, default=30.0)
    ap.add_argument("--noise-cm", type=float, default=2.0)
    ap.add_argument("--noise-deg", type=float, default=2.0)
    args = ap.parse_args(argv)
    cfg = load_config(args.config)
    track = load_track(args.track)
    t0 = time.perf_counter()
    steps = drive(track, cfg, args.laps)
    print(f"race: {track.name}, {args.laps} laps + out lap, {steps[-1].t_s:.1f} s simulated, "
          f"{time.perf_counter() - t0:.1f} s wall")
    pose = PoseSensorSettings(
        rate_hz=args.rate_hz,
        latency_s=args.latency_ms / 1e3,
        position_noise_std_m=args.noise_cm / 100,
        yaw_noise_std_rad=math.radians(args.noise_deg),
    )
    print(f"pose {args.rate_hz:g} Hz, {args.latency_ms:g} ms late, sigma {args.noise_cm:g} cm / "
          f"{args.noise_deg:g} deg; IMU and odometry as [simulator]; errors every 10 ms")
    rows: dict[str, list[tuple[float, float]]] = {}
    for seed in range(args.seeds):
        sim = cfg.simulator.model_copy(update={"pose": pose, "seed": seed})
        loc = cfg.localization.model_copy(update={"noise": cfg.localization.noise.model_copy(
            update={"pose_position_std_m": args.noise_cm / 100,
                    "pose_yaw_std_rad": math.radians(args.noise_deg)})})
        for name, (p, y, _) in errors(steps, sim, loc, cfg.simulator.vehicle.lr_m).items():
            rows.setdefault(name, []).append((p, y))
    head = f"{'variant':34s} {'position RMS [cm]':>18s} {'yaw RMS [deg]':>14s}"
    print(f"\n{head}  (mean (min-max) over {args.seeds} seeds)")
    for name, vals in rows.items():
        p = np.array([v[0] for v in vals]) * 100
        y = np.array([v[1] for v in vals])
        print(f"{name:34s} {p.mean():12.2f} ({p.min():.2f}-{p.max():.2f}) {y.mean():8.2f} "
              f"({y.min():.2f}-{y.max():.2f})")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
