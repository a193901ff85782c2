"""Head to head in the bench (issue #24): a method races an opponent car in one process.

``racestack bench --opponent METHOD[:SPEED_SCALE]`` races every ``--methods`` method (the ego,
car 0) against an opponent (car 1) on the same track, each in its own dynamic ``Simulator``,
over ``--seeds`` seeded starts:

- start: both at standstill, the ego ``OUT_LAP_START_M`` past the line, the opponent a random
  gap ahead (uniform in ``HeadToHeadOptions.gap_m``, seeded);
- each planner tick (``planner.dt_s``) both planners see the true rear-axle poses; the ego
  (when its planner takes opponents, ``set_opponents``: ``raceline``) gets the opponent from
  the simulator's truth or, with ``source = "lidar"``, from the simulated lidar
  (``LidarScanner`` with the other car as a box, ``cast_on_boxes``) through the bridge's
  ``OpponentDetector`` and ``OpponentTracker``; the opponent gets the ego only with
  ``opponent_aware``;
- both cars are driven over the tick with the bench's timing (the previous command during the
  compute delay); after every integration step ``ContactMonitor`` checks the footprints and a
  touching pair gets a physical response (``contact_response``: pushed apart along the
  contact normal, an inelastic impulse between equal masses): a collision costs speed;
- the race ends when the ego has driven ``laps`` laps from its start (or gives up).

Reported per method (``summarise``): overtakes (the ego's centre passing a car length ahead
of the opponent's, counted each time), the laps driven to the first one, the time lost over
the ego's distance against its solo run over the same distance, contacts (with the striker),
off-track events of each car and, with the lidar, the tracker's id changes on the opponent.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from services.planner import OpponentEstimate, PlannerLike, SolveResult
from services.simulator import (
    Command,
    LapTimer,
    LidarScanner,
    Simulator,
    centreline_pose,
    rear_axle,
)
from shared.car import CAR
from shared.config.simulator import SimulatorSettings
from shared.evaluation.results import OUT_LAP_START_M
from shared.track import Track, occupancy_for
from shared.vehicle.contact import ContactMonitor, box_contact

#: Where the opponent comes from: the simulator's truth or the lidar tracker.
SOURCES = ("truth", "lidar")
#: Restitution of a car-to-car contact along its normal [1].
RESTITUTION = 0.2
#: The lidar's range noise [m] (the simulator's default sensor).
LIDAR_NOISE_M = 0.01
#: A tracked opponent matches the truth within this distance [m] (id bookkeeping).
MATCH_M = 0.5
#: Give up after this long without the ego progressing [s].
STALL_S = 10.0


@dataclass(frozen=True)
class OpponentSpec:
    """The opponent of ``--opponent METHOD[:SPEED_SCALE]``."""

    method: str
    speed_scale: float = 1.0

    @classmethod
    def parse(cls, text: str) -> OpponentSpec:
        """``"raceline:0.85"`` -> ("raceline", 0.85); ``"raceline"`` -> scale 1."""
        name, _, scale = text.strip().partition(":")
        if not name:
            raise ValueError("--opponent needs a method, e.g. raceline:0.85")
        try:
            value = float(scale) if scale else 1.0
        except ValueError:
            raise ValueError(f"--opponent speed scale must be a number, got {scale!r}") from None
        if not 0.0 < value <= 1.0:
            raise ValueError(f"--opponent speed scale must be in (0, 1], got {value:g}")
        return cls(name, value)


@dataclass(frozen=True)
class HeadToHeadOptions:
    """How to race head to head.

    Attributes:
        laps: laps the ego drives from its start (the out lap counts) per seed.
        seeds: seeded starts; first_seed: the first seed.
        gap_m: (min, max) of the opponent's start gap ahead [m].
        source: the ego's view of the opponent ("truth" or "lidar").
        opponent_aware: the opponent also plans around the ego (when it can).
        compute_delay_s: the previous command acts this long into each tick [s].
        stop_lead_m: end a start early once the ego has overtaken and leads by this much
            [m] (None: race all the laps; the rest is the ego's solo lap, so a long track
            can be raced over many seeds: the figures then cover the start to there).
    """

    laps: int = 2
    seeds: int = 10
    first_seed: int = 0
    gap_m: tuple[float, float] = (2.0, 6.0)
    source: str = "truth"
    opponent_aware: bool = False
    compute_delay_s: float = 0.002
    stop_lead_m: float | None = None


@dataclass
class SeedResult:
    """One seeded start."""

    seed: int
    gap_m: float
    overtakes: int = 0
    first_overtake_laps: float | None = None
    ego_distance_m: float = 0.0
    ego_time_s: float = 0.0
    contacts: int = 0
    ego_strikes: int = 0
    ego_off_track: int = 0
    opponent_off_track: int = 0
    id_changes: int | None = None
    aborted: str = ""
    stopped_at_lead: bool = False
    times_s: list[float] = field(default_factory=list, repr=False)


class SimCar:
    """One car of the bench's closed loops: its simulator (at rest on the centreline at
    `s0_m`), lap timer, off-track count and the command acting."""

    def __init__(self, track: Track, settings: SimulatorSettings, s0_m: float) -> None:
        self.sim = Simulator(settings)
        self.sim.reset(centreline_pose(track, s0_m), speed_mps=0.0)
        veh = settings.vehicle
        self.lr = veh.lr_m
        self.timer = LapTimer(track, width_m=veh.width_m, length_m=veh.length_m)
        st = self.sim.state
        self.timer.update(self.sim.t_s, st.x_m, st.y_m, st.yaw_rad, st.v_mps)
        self.cmd = Command(0.0, 0.0)
        self.off = 0

    def rear_pose(self) -> tuple[float, float, float]:
        st = self.sim.state
        return rear_axle(st.x_m, st.y_m, st.yaw_rad, self.lr)

    def centre(self) -> np.ndarray:
        st = self.sim.state
        return np.array([st.x_m, st.y_m, st.yaw_rad])

    def velocity(self) -> np.ndarray:
        st = self.sim.state
        ang = st.yaw_rad + st.slip_rad
        return st.v_mps * np.array([math.cos(ang), math.sin(ang)])

    def estimate(self, car_id: int) -> OpponentEstimate:
        """This car as the other's truth."""
        c, v = self.centre(), self.velocity()
        return OpponentEstimate(car_id, c[0], c[1], v[0], v[1], c[2])

    def step(self, cmd: Command, dt_s: float) -> None:
        out = self.sim.step(cmd, dt_s)
        s = out.state
        for ev in self.timer.update(out.t_s, s.x_m, s.y_m, s.yaw_rad, s.v_mps):
            self.off += ev.kind == "off_track"


def contact_response(a: Simulator, b: Simulator, normal: np.ndarray, depth_m: float) -> None:
    """Two touching cars (equal masses): each pushed half the depth apart along the contact
    `normal` (from a to b), then an impulse that takes ``1 + RESTITUTION`` of their closing
    speed along it; each car's speed and slip angle follow its new velocity (``beta``
    clipped to +-0.5 rad) and its yaw rate is kept."""
    n = np.asarray(normal, dtype=float)
    states = []
    for sim in (a, b):
        st = sim.state
        ang = st.yaw_rad + st.slip_rad
        states.append([st.x_m, st.y_m, st.v_mps * math.cos(ang), st.v_mps * math.sin(ang)])
    sa, sb = np.array(states[0]), np.array(states[1])
    push = 0.5 * (depth_m + 1e-3) * n
    sa[:2] -= push
    sb[:2] += push
    closing = float((sb[2:] - sa[2:]) @ n)
    if closing < 0.0:
        j = -0.5 * (1.0 + RESTITUTION) * closing
        sa[2:] -= j * n
        sb[2:] += j * n
    for sim, s in ((a, sa), (b, sb)):
        _x, _y, delta, _v, yaw, r, _beta = sim.state_tuple
        v = float(math.hypot(s[2], s[3]))
        beta = math.remainder(math.atan2(s[3], s[2]) - yaw, 2 * math.pi) if v > 1e-6 else 0.0
        beta = min(max(beta, -0.5), 0.5)
        sim._s = (float(s[0]), float(s[1]), delta, v, yaw, r, beta)  # the bench moves the car


class LidarView:
    """The ego's view of the other car through the simulated lidar, detector and tracker."""

    def __init__(self, track: Track, seed: int) -> None:
        from services.localization_bridge import OpponentDetector, OpponentTracker

        grid = occupancy_for(track)
        self.scanner = LidarScanner(grid, beams=1080, fov_rad=4.7, range_max_m=30.0)
        self.detector = OpponentDetector(grid, track=track)
        self.tracker = OpponentTracker()
        self.rng = np.random.default_rng(seed)
        self.ids_seen: list[int] = []  #: the matched track's id at each scan it was matched

    def estimates(
        self, t_s: float, ego: np.ndarray, others: np.ndarray
    ) -> list[OpponentEstimate]:
        """Confirmed tracks as estimates, from a scan at the ego's centre `ego` (3,)."""
        sc = self.scanner
        r = sc.scan(*ego, boxes=others).astype(float)
        hit = r < sc.range_max_m
        r = np.where(hit, np.clip(r + self.rng.normal(0.0, LIDAR_NOISE_M, r.shape), 0.0,
                                  sc.range_max_m), r)
        dets = self.detector.detect(
            r, sc.angle_min_rad, sc.angle_increment_rad, sc.range_max_m, tuple(ego),
            self.tracker.predicted_centres(t_s),
        )
        from services.localization_bridge import ScanView

        view = ScanView(r, sc.angle_min_rad, sc.angle_increment_rad, sc.range_max_m, tuple(ego))
        tracks = self.tracker.update(t_s, [(d.x_m, d.y_m, d.yaw_rad) for d in dets], view,
                                     self.detector.free_at)
        near = [tr for tr in tracks
                if math.hypot(tr.x[0] - others[0, 0], tr.x[1] - others[0, 1]) <= MATCH_M]
        if near and math.hypot(*(others[0, :2] - ego[:2])) <= 5.0:
            self.ids_seen.append(near[0].track_id)
        return [
            OpponentEstimate(
                tr.track_id, float(tr.x[0]), float(tr.x[1]), float(tr.x[2]), float(tr.x[3]),
                math.atan2(tr.x[3], tr.x[2]) if math.hypot(tr.x[2], tr.x[3]) > 0.2
                else float(others[0, 2]),
                covariance=tuple(float(v) for v in tr.P.ravel()),
            )
            for tr in tracks
        ]

    @property
    def id_changes(self) -> int:
        """Times the opponent's matched track id changed."""
        return sum(a != b for a, b in zip(self.ids_seen, self.ids_seen[1:], strict=False))


def _takes_opponents(planner: PlannerLike) -> bool:
    return callable(getattr(planner, "set_opponents", None))


def race_seed(
    ego: PlannerLike,
    opponent: PlannerLike,
    track: Track,
    settings: SimulatorSettings,
    opts: HeadToHeadOptions,
    seed: int,
) -> SeedResult:
    """One seeded start (module docstring)."""
    rng = np.random.default_rng(seed)
    gap = float(rng.uniform(*opts.gap_m))
    res = SeedResult(seed, round(gap, 3))
    cars = [SimCar(track, settings, s0) for s0 in (OUT_LAP_START_M, OUT_LAP_START_M + gap)]
    planners = [ego, opponent]
    for p in planners:
        p.reset()
        if _takes_opponents(p):
            p.set_opponents([])
    monitor = ContactMonitor(2, length_m=CAR.length_m, width_m=CAR.width_m)
    view = LidarView(track, seed) if opts.source == "lidar" else None
    period = ego.settings.dt_s
    step_s = settings.integration_step_s
    L = track.length_m
    start = cars[0].timer.progress_m
    goal = opts.laps * L
    ahead = False
    best, best_t = 0.0, 0.0
    t = 0.0
    while True:
        dist = cars[0].timer.progress_m - start
        if dist >= goal:
            break
        if dist > best + 0.5:
            best, best_t = dist, t
        if t - best_t > STALL_S:
            res.aborted = f"no progress for {STALL_S:.0f} s"
            break
        lead = cars[0].timer.progress_m - cars[1].timer.progress_m
        if not ahead and lead > CAR.length_m:
            ahead = True
            res.overtakes += 1
            if res.first_overtake_laps is None:
                res.first_overtake_laps = round(dist / L, 3)
        elif ahead and lead < -CAR.length_m:
            ahead = False
        if ahead and opts.stop_lead_m is not None and lead >= opts.stop_lead_m:
            res.stopped_at_lead = True
            break
        if _takes_opponents(ego):
            if view is not None:
                ego.set_opponents(view.estimates(t, cars[0].centre(), cars[1].centre()[None]))
            else:
                ego.set_opponents([cars[1].estimate(1)])
        if opts.opponent_aware and _takes_opponents(opponent):
            opponent.set_opponents([cars[0].estimate(0)])
        results: list[SolveResult] = [p.step(*c.rear_pose()) for p, c in zip(planners, cars,
                                                                             strict=True)]
        delay = min(max(opts.compute_delay_s, 0.0), period)
        new = [Command(r.command.speed_mps, r.command.steering_rad) for r in results]
        chunks: list[tuple[int, float]] = [(0, delay)] if delay > 0 else []
        rest = period - delay
        n = max(1, math.ceil(rest / step_s - 1e-9))
        chunks += [(1, rest / n)] * n
        for which, dt in chunks:
            for car, cmd_new in zip(cars, new, strict=True):
                car.step(car.cmd if which == 0 else cmd_new, dt)
            t += dt
            poses = np.stack([c.centre() for c in cars])
            vels = np.stack([c.velocity() for c in cars])
            for inc in monitor.update(t, poses, vels):
                res.contacts += 1
                res.ego_strikes += inc.striker == 0
            con = box_contact(poses[0], poses[1], CAR.length_m, CAR.width_m)
            if con.overlapping[0]:
                contact_response(cars[0].sim, cars[1].sim, con.normal[0], float(con.depth_m[0]))
        for car, cmd_new in zip(cars, new, strict=True):
            car.cmd = cmd_new
        res.times_s.append(t)
    res.ego_distance_m = round(cars[0].timer.progress_m - start, 3)
    res.ego_time_s = round(t, 3)
    res.ego_off_track, res.opponent_off_track = cars[0].off, cars[1].off
    if view is not None:
        res.id_changes = view.id_changes
    res.times_s = []
    return res


def solo_time_s(
    planner: PlannerLike, track: Track, settings: SimulatorSettings, distance_m: float,
    compute_delay_s: float = 0.002,
) -> float:
    """Time [s] the ego alone takes from the same start over `distance_m` [m] (the bench's
    timing, the opponent's car far away and unseen)."""
    car = SimCar(track, settings, OUT_LAP_START_M)
    planner.reset()
    if _takes_opponents(planner):
        planner.set_opponents([])
    period = planner.settings.dt_s
    step_s = settings.integration_step_s
    start, t = car.timer.progress_m, 0.0
    t_limit = 10.0 * distance_m + 60.0
    while car.timer.progress_m - start < distance_m and t < t_limit:
        r = planner.step(*car.rear_pose())
        new = Command(r.command.speed_mps, r.command.steering_rad)
        delay = min(max(compute_delay_s, 0.0), period)
        if delay > 0:
            car.step(car.cmd, delay)
        rest = period - delay
        n = max(1, math.ceil(rest / step_s - 1e-9))
        for _ in range(n):
            car.step(new, rest / n)
        car.cmd = new
        t += period
    return t


def summarise(seeds: list[SeedResult], solo_s: float, laps: int) -> dict:
    """The figures of one method over its seeds (results.json's ``head_to_head``)."""
    n = len(seeds)
    within = [s for s in seeds if s.first_overtake_laps is not None
              and s.first_overtake_laps <= laps]
    firsts = [s.first_overtake_laps for s in seeds if s.first_overtake_laps is not None]
    lost = [s.ego_time_s - solo_s for s in seeds if not s.aborted and not s.stopped_at_lead]
    ids = [s.id_changes for s in seeds if s.id_changes is not None]
    return {
        "seeds": n,
        "overtakes": int(sum(s.overtakes for s in seeds)),
        "overtaken_within_laps": len(within),
        "overtake_rate": round(len(within) / max(n, 1), 4),
        "laps_to_first_overtake_median": float(np.median(firsts)) if firsts else None,
        "laps_to_first_overtake_max": float(max(firsts)) if firsts else None,
        "solo_time_s": round(solo_s, 3),
        "time_lost_s_median": round(float(np.median(lost)), 3) if lost else None,
        "time_lost_s_max": round(float(max(lost)), 3) if lost else None,
        "contacts": int(sum(s.contacts for s in seeds)),
        "contacts_struck_by_ego": int(sum(s.ego_strikes for s in seeds)),
        "off_track_ego": int(sum(s.ego_off_track for s in seeds)),
        "off_track_opponent": int(sum(s.opponent_off_track for s in seeds)),
        "aborted": int(sum(bool(s.aborted) for s in seeds)),
        "tracker_id_changes": int(sum(ids)) if ids else None,
        "per_seed": [
            {k: v for k, v in s.__dict__.items() if k != "times_s"} for s in seeds
        ],
    }


def format_head_to_head(track: str, opponent: OpponentSpec, doc: dict, laps: int) -> str:
    """The table of the head-to-head figures, one row per method."""
    head = (f"head to head on {track} against {opponent.method} x {opponent.speed_scale:g} "
            f"({laps} laps per start)")
    cols = (f"{'method':<14} {'seeds':>5} {'passed<=' + str(laps):>10} {'overtakes':>9} "
            f"{'laps to 1st':>11} {'lost [s]':>9} {'contacts':>8} {'off ego/opp':>11} "
            f"{'id chg':>6}")
    rows = [head, cols]
    for name, m in doc.items():
        first = m["laps_to_first_overtake_median"]
        lost = m["time_lost_s_median"]
        ids = m["tracker_id_changes"]
        rows.append(
            f"{name:<14} {m['seeds']:>5} "
            f"{m['overtaken_within_laps']:>4} ({100 * m['overtake_rate']:5.1f}%) "
            f"{m['overtakes']:>9} {'-' if first is None else f'{first:.2f}':>11} "
            f"{'-' if lost is None else f'{lost:+.2f}':>9} {m['contacts']:>8} "
            f"{m['off_track_ego']:>5}/{m['off_track_opponent']:<5} "
            f"{'-' if ids is None else ids:>6}"
        )
    return "\n".join(rows)


def opponent_planner(pool, cfg, spec: OpponentSpec) -> PlannerLike:
    """The opponent's planner: the method from `pool`, its line's speed profile scaled by
    ``spec.speed_scale`` (a tracker method: ``raceline``; an MPC method only at scale 1)."""
    from services.planner import RacelinePlanner

    base = pool.planner(cfg.planner, spec.method, cfg.curvature)
    if spec.speed_scale == 1.0:
        return base
    if not isinstance(base, RacelinePlanner):
        raise ValueError(
            f"--opponent {spec.method}:{spec.speed_scale:g}: a speed scale needs a method "
            "that tracks a line's speed profile (raceline); an MPC method races at scale 1"
        )
    return RacelinePlanner(
        pool.track, cfg.planner, cfg.curvature, method=f"{spec.method}x{spec.speed_scale:g}",
        vehicle=cfg.vehicle, raceline=base.raceline, speed_scale=spec.speed_scale,
    )


def run_head_to_head(
    cfg,
    track: Track,
    methods: list[str],
    spec: OpponentSpec,
    opts: HeadToHeadOptions,
    progress=None,
) -> dict:
    """Every method against the opponent over the seeds; returns ``{method: summary}``."""
    from services.planner import PlannerPool, ensure_artefacts

    for name in {*methods, spec.method}:
        ensure_artefacts(name, track, cfg.planner, cfg.vehicle, progress=progress)
    pool = PlannerPool(track, cfg.vehicle)
    opponent = opponent_planner(pool, cfg, spec)
    out: dict = {}
    for name in methods:
        ego = pool.planner(cfg.planner, name, cfg.curvature)
        seeds = []
        for k in range(opts.seeds):
            r = race_seed(ego, opponent, track, cfg.simulator, opts, opts.first_seed + k)
            seeds.append(r)
            if progress is not None:
                progress(
                    f"{name} vs {spec.method}x{spec.speed_scale:g} seed {r.seed}: gap "
                    f"{r.gap_m:.2f} m, overtakes {r.overtakes} (first at lap "
                    f"{r.first_overtake_laps}), contacts {r.contacts}, off-track "
                    f"{r.ego_off_track}/{r.opponent_off_track}"
                    + (f", id changes {r.id_changes}" if r.id_changes is not None else "")
                    + (f", aborted: {r.aborted}" if r.aborted else "")
                )
        distance = opts.laps * track.length_m
        solo = solo_time_s(ego, track, cfg.simulator, distance, opts.compute_delay_s)
        out[name] = summarise(seeds, solo, opts.laps)
    return out
