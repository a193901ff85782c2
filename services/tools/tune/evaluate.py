"""One trial of ``racestack tune``: the method raced over a few noise seeds (the thin shell
around the bench's closed loop, ``services.tools.bench.closed_loop.run_method``).

The bench hands the planner the car's true pose, so a seed alone would change nothing. Each
seed here changes two things, identically for every trial (common random numbers, so trials
are compared on the same disturbances):

- **pose noise**: the planner sees the true rear-axle pose plus white Gaussian noise with the
  simulator's own pose-sensor deviations (``[simulator.pose]``: 1 cm per axis, 0.005 rad by
  default) times ``pose_noise``; the lap timer and the track limits judge the true car;
- **start**: the car starts ``0.3 m + U(0, start_spread_m)`` past the start line, so the out
  lap, and where the first timed lap meets the car's transient, differ.

A seed stops early, and the remaining seeds are skipped, once the trial is infeasible: at
the first tick the recovery rule drives or the rear axle is outside the track, or after a
seed with an off-track event, a missing lap or too small a margin.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np

from services.planner import (
    RECOVERING,
    PlannerLike,
    PlannerPool,
    Recovery,
    SolveResult,
    ensure_artefacts,
)
from services.tools.bench import LoopOptions, run_method
from services.tools.tune.search import (
    Overlay,
    Params,
    Score,
    SearchSpace,
    SeedResult,
    complete_overlay,
    deep_merge,
    is_infeasible,
    score,
)
from shared.config import RacestackConfig, config_from_dict
from shared.config.planner import PlannerSettings
from shared.curvature import CurvatureProfile
from shared.evaluation import MethodRun
from shared.evaluation.results import LIMIT_TOLERANCE_S
from shared.evaluation.spins import rear_peak_slip_rad, spin_events
from shared.track import Track

#: The bench's start: this far past the start line [m]; each seed adds U(0, spread).
BASE_START_OFFSET_M = 0.3


@dataclass(frozen=True)
class ObjectiveSettings:
    """How a trial is raced and judged.

    Attributes:
        laps: timed laps per seed.
        seeds: the noise seeds; every trial races all of them (until infeasible).
        margin_m: the car's body must stay this far inside the boundaries [m].
        pose_noise: pose noise as a multiple of the simulator's pose-sensor deviations.
        start_spread_m: the start offset varies by up to this much between seeds [m].
        compute_delay_s: the bench's fixed compute delay [s].
    """

    laps: int = 2
    seeds: tuple[int, ...] = (0, 1, 2)
    margin_m: float = 0.05
    pose_noise: float = 1.0
    start_spread_m: float = 1.0
    compute_delay_s: float = 0.002

    def __post_init__(self) -> None:
        if self.laps < 1:
            raise ValueError("--laps must be at least 1")
        if not self.seeds or any(s < 0 for s in self.seeds) or len(set(self.seeds)) != len(
            self.seeds
        ):
            raise ValueError("--seeds must be distinct non-negative integers")
        if not (0.0 <= self.margin_m <= 1.0 and self.pose_noise >= 0.0):
            raise ValueError("--margin must be in [0, 1] m and --pose-noise >= 0")
        if not 0.0 <= self.start_spread_m <= 10.0:
            raise ValueError("start spread must be in [0, 10] m")

    def to_json(self) -> dict[str, Any]:
        """Plain JSON values (the study records them; a resume must match)."""
        d = asdict(self)
        d["seeds"] = list(self.seeds)
        return d


@dataclass(frozen=True)
class TrialOutcome:
    """A raced trial: its score, the seeds it ran and the overlay it raced."""

    score: Score
    seeds: tuple[SeedResult, ...]
    overlay: Overlay
    details: dict[str, Any] = field(default_factory=dict)
    #: per cell of a family (``services.tools.tune.family``): track, car, limit, ratio, ...
    cells: tuple[dict[str, Any], ...] = ()


class RunAbortedError(RuntimeError):
    """A seed's run stopped early: the trial is infeasible already."""

    def __init__(self, reason: str, kind: str) -> None:
        super().__init__(reason)
        self.kind = kind  #: "recovery" or "off_track"


class NoisyPose:
    """A planner seen through a noisy pose, stopping the run when the car is lost.

    A ``PlannerLike`` (``run_method`` uses ``step``, ``reset``, ``settings``, ``recovery``).
    """

    def __init__(
        self,
        planner: PlannerLike,
        track: Track,
        rng: np.random.Generator,
        std_xy_m: float,
        std_yaw_rad: float,
    ) -> None:
        self.inner = planner
        self.track = track
        self.rng = rng
        self.std = np.array([std_xy_m, std_xy_m, std_yaw_rad])

    @property
    def settings(self) -> PlannerSettings:
        """The planner's settings."""
        return self.inner.settings

    @property
    def recovery(self) -> Recovery:
        """The planner's recovery rule."""
        return self.inner.recovery

    @property
    def profile(self) -> CurvatureProfile:
        """The planner's curvature profile."""
        return self.inner.profile

    @property
    def horizon(self) -> int:
        """The planner's horizon."""
        return self.inner.horizon

    def reset(self) -> None:
        """Reset the planner."""
        self.inner.reset()

    def prepare(self) -> None:
        """The planner's prepare."""
        self.inner.prepare()

    def step(self, x_m: float, y_m: float, yaw_rad: float, on_command=None) -> SolveResult:
        """The planner's step on the noisy pose; RunAbortedError once the car is lost."""
        n = self.rng.standard_normal(3) * self.std
        res = self.inner.step(x_m + n[0], y_m + n[1], yaw_rad + n[2], on_command)
        if res.status == RECOVERING:
            raise RunAbortedError(f"recovery rule took over at s = {res.s_m:.1f} m", "recovery")
        w_r, w_l = self.track.interp_width(res.s_m)
        if res.e_con_m > float(w_r) or res.e_con_m < -float(w_l):
            raise RunAbortedError(
                f"rear axle outside the track at s = {res.s_m:.1f} m", "off_track"
            )
        return res


def min_clearance_m(run: MethodRun, track: Track, half_width_m: float) -> float | None:
    """The smallest distance of the car's body to a boundary over the run [m] (per tick:
    the CoG's distance to the nearer boundary minus half the car's width)."""
    s = np.asarray(run.trace.s_m, dtype=float)
    e = np.asarray(run.trace.e_con_m, dtype=float)
    if s.size == 0:
        return None
    w_r, w_l = track.interp_width(s)
    room = np.minimum(np.asarray(w_r) - e, np.asarray(w_l) + e)
    return float(np.min(room) - half_width_m)


def start_offset_m(seed: int, spread_m: float) -> float:
    """Where seed `seed` starts past the line [m] (the same for every trial)."""
    u = np.random.default_rng([seed, 1]).uniform()
    return BASE_START_OFFSET_M + spread_m * float(u)


class Evaluator:
    """Races points of a search space: ``evaluator(params) -> TrialOutcome``.

    Args:
        space: the method's search space.
        track: the track.
        base_data: the base configuration as TOML tables (``--config``, or {}).
        settings: how a trial is raced and judged.
        limit_s: the simulated car's minimum-time lap on `track` [s]: a lap faster than it
            (by more than ``LIMIT_TOLERANCE_S``) is counted (``below_limit_laps``); None:
            not checked.
    """

    def __init__(
        self,
        space: SearchSpace,
        track: Track,
        base_data: dict[str, Any],
        settings: ObjectiveSettings,
        limit_s: float | None = None,
    ) -> None:
        self.space = space
        self.track = track
        self.base_data = base_data
        self.settings = settings
        self.limit_s = limit_s
        self.base_cfg = config_from_dict(base_data, "--config")
        self._pool = PlannerPool(track, self.base_cfg.vehicle)

    def config_for(self, params: Params) -> tuple[Overlay, RacestackConfig]:
        """The overlay of `params` (method weight tables in full, ``complete_overlay``) and
        the validated configuration it races."""
        overlay = complete_overlay(self.space.overlay(params), self.base_cfg)
        cfg = config_from_dict(deep_merge(self.base_data, overlay), "trial configuration")
        return overlay, cfg

    def planner_for(self, cfg: RacestackConfig) -> PlannerLike:
        """A planner of the method with `cfg`'s settings (MPC problems of the same
        structure built once, ``PlannerPool``; the minimum-time lap it races on made first,
        once per line setting)."""
        ensure_artefacts(self.space.method, self.track, cfg.planner, cfg.vehicle)
        return self._pool.planner(cfg.planner, self.space.method, cfg.curvature)

    def run_seed(self, planner: PlannerLike, cfg: RacestackConfig, seed: int
                 ) -> SeedResult:
        """Race one seed (see the module docstring)."""
        st = self.settings
        sim = cfg.simulator.model_copy(update={"seed": seed})
        noisy = NoisyPose(
            planner,
            self.track,
            np.random.default_rng([seed, 0]),
            st.pose_noise * sim.pose.position_noise_std_m,
            st.pose_noise * sim.pose.yaw_noise_std_rad,
        )
        opts = LoopOptions(
            laps=st.laps,
            compute_delay_s=st.compute_delay_s,
            start_offset_m=start_offset_m(seed, st.start_spread_m),
        )
        done = [0]

        def progress(n: int, _total: int) -> None:
            done[0] = n

        try:
            run = run_method(
                self.space.method, noisy, self.track, sim, opts, progress  # type: ignore[arg-type]
            )
        except RunAbortedError as exc:
            return SeedResult(
                seed,
                (),
                int(exc.kind == "off_track"),
                int(exc.kind == "recovery"),
                None,
                f"{exc} (after {done[0]} timed laps)",
            )
        half_width = 0.5 * sim.vehicle.width_m
        laps = tuple(float(lap.lap_time_s) for lap in run.laps)
        below = 0
        if self.limit_s is not None:
            below = sum(t < self.limit_s - LIMIT_TOLERANCE_S for t in laps)
        return SeedResult(
            seed,
            laps,
            int(run.run_off_track_events),
            int(run.extra.get("recoveries", 0)),
            min_clearance_m(run, self.track, half_width),
            str(run.extra.get("aborted", "")),
            spin_events(run.trace.t_s, run.trace.rear_slip_rad, rear_peak_slip_rad(sim.vehicle)),
            int(below),
        )

    def __call__(self, params: Params) -> TrialOutcome:
        """Race `params` over the seeds (stopping at the first infeasible one) and score."""
        overlay, cfg = self.config_for(params)
        planner = self.planner_for(cfg)
        st = self.settings
        results: list[SeedResult] = []
        for seed in st.seeds:
            r = self.run_seed(planner, cfg, seed)
            results.append(r)
            if is_infeasible(r, st.laps, st.margin_m):
                break
        sc = score(results, st.laps, len(st.seeds), st.margin_m)
        skipped = len(st.seeds) - len(results)
        details = {"seeds_run": len(results), "seeds_skipped": skipped}
        return TrialOutcome(sc, tuple(results), overlay, details)
