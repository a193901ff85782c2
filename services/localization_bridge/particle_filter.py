"""Lidar particle filter (Monte Carlo localisation) on the track's occupancy map; no I/O.

State: N particles ``(x, y, psi)``, the REAR-AXLE pose in the map frame (the point and frame of
``vehicle/pose``), with normalised weights ``w`` (N,). The caller owns time and data:

- ``predict(dt, v, r)``: the motion model (``motion_model.py``: odometry speed, IMU yaw rate,
  random-walk noise);
- ``update(scan)``: up to ``beams`` valid beams evenly spread over the scan, each beam end
  point ``p + R(psi) (lidar + range (cos a, sin a))`` scored in the likelihood field
  (``likelihood_field.py``), ``w_i <- w_i exp(log L_i / temperature)``; the estimate; then
  low-variance resampling when ``n_eff = 1 / sum w^2`` falls below
  ``resample_n_eff_fraction N`` (``resampling.py``), with random particles over the free space
  injected while the fast average of the fitness drops below the slow one (augmented MCL,
  Thrun et al. Table 8.3);
- ``init_pose`` (a Gaussian cloud) or ``init_global`` (uniform over the free space: the first
  scan afterwards scores ``global_candidates`` uniform poses and keeps the best
  ``global_particles``).

Annealing: the sensor model's sigma is the smallest of ``hit_sigma 2^k`` (capped at
``global_hit_sigma``) not below the cloud's position std, so a wide cloud sees a smooth
likelihood and a converged one the sharp one. Fitness = the mean over the used beams of
``exp(-d^2 / (2 hit_sigma^2))`` at the estimated pose, a soft fraction of beams ending on a
mapped wall (1: all, 0: none; robust to a few beams on unmapped obstacles); the estimate
is ``lost`` while its fast average is below ``lost_fitness`` once the cloud had converged
(not while it is still converging after an initialisation), and after ``lost_reinit_scans``
lost scans in a row the filter starts a global initialisation by itself.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from services.localization_bridge.likelihood_field import LikelihoodField, wall_distance_m
from services.localization_bridge.motion_model import MotionNoise, propagate
from services.localization_bridge.poses import PoseIndex
from services.localization_bridge.resampling import effective_sample_size, low_variance_indices
from shared.angles import wrap_angle_shifted
from shared.config.particle_filter import ParticleFilterSettings
from shared.messages import Scan
from shared.track.occupancy import OccupancyGrid
from shared.track.raycast import blocked_cells

#: Converged once both stds are below the settings' thresholds; unconverged again above
#: this multiple of them (hysteresis).
UNCONVERGE_FACTOR = 2.0
#: Candidates scored per chunk after init_global (bounds the memory: chunk x beams floats).
CANDIDATE_CHUNK = 20000

__all__ = ["FilterMap", "ParticleFilter", "PfEstimate", "map_settings"]


@dataclass(frozen=True)
class PfEstimate:
    """The filter's pose estimate.

    Attributes:
        x_m, y_m: rear-axle position [m], map frame (weighted mean of the particles).
        yaw_rad: heading [rad] in [-pi, pi) (weighted circular mean).
        cov: (3, 3) weighted covariance of [x m, y m, yaw rad] (yaw deviations wrapped).
        n_eff: effective sample size ``1 / sum w^2`` [particles].
        converged: the cloud is tight (stds below the settings' thresholds, with hysteresis).
        lost: the fast fitness average is below ``lost_fitness`` after the cloud had
            converged (never while it is still converging after an initialisation).
        fitness: fast average of the fitness (see the module docstring) [-].
        particles: number of particles.
    """

    x_m: float
    y_m: float
    yaw_rad: float
    cov: np.ndarray
    n_eff: float
    converged: bool
    lost: bool
    fitness: float = 0.0
    particles: int = 0


def map_settings(settings: ParticleFilterSettings) -> tuple:
    """The settings a ``FilterMap`` depends on (hashable): its sigma ladder, mixture, cap,
    upsampling, unknown cells and free-space clearance."""
    st = settings
    return (st.hit_sigma_m, st.global_hit_sigma_m, st.z_hit, st.z_rand, st.field_cap_m,
            st.field_upsample, st.unknown_is_occupied, st.free_clearance_m)


@dataclass(frozen=True)
class FilterMap:
    """What the filter reads from its map and never changes: the likelihood field and the
    free cells it samples global poses from. Building it takes the distance transforms (about
    2-7 s on a 400 m F1TENTH map), so a process racing one map many times (the robustness
    benchmark) builds it once and hands it to every filter (read-only).

    Attributes:
        grid: the map it was built on.
        settings: ``map_settings`` of the settings it was built for.
        field: the likelihood field for the sigma ladder of the module docstring.
        free_rc: (M, 2) int (row, col) of the free cells at least ``free_clearance_m`` from
            walls.
    """

    grid: OccupancyGrid
    settings: tuple
    field: LikelihoodField
    free_rc: np.ndarray

    @classmethod
    def build(cls, grid: OccupancyGrid, settings: ParticleFilterSettings) -> FilterMap:
        """The map data of `grid` for `settings`; ValueError if no cell is free enough."""
        st = settings
        sigmas = [st.hit_sigma_m]
        while sigmas[-1] * 2.0 < st.global_hit_sigma_m:
            sigmas.append(sigmas[-1] * 2.0)
        if st.global_hit_sigma_m > sigmas[-1]:
            sigmas.append(st.global_hit_sigma_m)
        field = LikelihoodField(
            grid,
            tuple(sigmas),
            st.z_hit,
            st.z_rand,
            st.field_cap_m,
            st.field_upsample,
            st.unknown_is_occupied,
        )
        # free space for global init and injection: free cells with clearance from walls
        blocked = blocked_cells(grid, st.unknown_is_occupied)
        r = float(grid.resolution_m)
        clear = wall_distance_m(blocked, r, st.free_clearance_m + r)
        rows, cols = np.nonzero(~blocked & (clear >= st.free_clearance_m))
        if rows.size == 0:
            raise ValueError(
                f"map {grid.source} has no free cell {st.free_clearance_m} m from walls"
            )
        return cls(grid, map_settings(st), field, np.stack([rows, cols], axis=1))


class ParticleFilter:
    """Monte Carlo localisation of the rear axle on `grid` (see the module docstring).

    Args:
        grid: the occupancy map.
        settings: the filter's settings.
        seed: seed of the filter's own random generator (same seed, same inputs: same output).
        filter_map: the map data built for `grid` and `settings` (``FilterMap.build``; None:
            built here). ValueError if it was built for another grid or settings.

    Starts with a global initialisation (call ``init_pose`` when the pose is known).
    """

    def __init__(
        self,
        grid: OccupancyGrid,
        settings: ParticleFilterSettings,
        *,
        seed: int = 0,
        filter_map: FilterMap | None = None,
    ) -> None:
        st = settings
        self.settings = st
        self.grid = grid
        self._rng = np.random.default_rng(seed)
        if filter_map is None:
            filter_map = FilterMap.build(grid, st)
        elif filter_map.grid is not grid or filter_map.settings != map_settings(st):
            raise ValueError("filter_map was built for another grid or other settings")
        self._field = filter_map.field
        self._noise = MotionNoise(
            st.noise_long_m_rts,
            st.noise_long_per_speed_rts,
            st.noise_lat_m_rts,
            st.noise_lat_per_speed_rts,
            st.noise_yaw_rad_rts,
            st.noise_yaw_per_rate_rts,
        )
        self._free_rc = filter_map.free_rc
        self._poses = np.zeros((1, 3))
        self._weights = np.ones(1)
        self._global_pending = False
        self._converged = False
        self._tracking = False  # converged at least once since the last initialisation
        self._fit_slow = self._fit_fast = -1.0  # < 0: not started
        self._lost_scans = 0
        self._std_xy = math.inf
        self.updates = 0  #: scans used
        self.skipped_scans = 0  #: scans without a usable beam
        self.rejected_inputs = 0  #: predict calls with non-finite values
        self.global_inits = 0  #: global initialisations (asked for or after being lost)
        self.local_inits = 0  #: re-initialisations near the last tracked pose (when lost)
        #: the last pose the filter tracked (converged, not lost) and the odometry's
        #: distance since [m]
        self._good_pose: tuple[float, float] | None = None
        self._travel_m = 0.0
        self._near: tuple[float, float, float] | None = None  # pending local search
        self._near_search = False  # searching near since init_local, not yet tracking
        self._free_mask: np.ndarray | None = None
        self.init_global()

    # ---------------------------------------------------------------- initialisation
    def init_pose(
        self,
        x_m: float,
        y_m: float,
        yaw_rad: float,
        std_xy_m: float | None = None,
        std_yaw_rad: float | None = None,
    ) -> None:
        """A Gaussian cloud of ``particles`` around a known rear-axle pose [m, m, rad]."""
        st = self.settings
        sxy = st.init_std_xy_m if std_xy_m is None else float(std_xy_m)
        syaw = st.init_std_yaw_rad if std_yaw_rad is None else float(std_yaw_rad)
        vals = (x_m, y_m, yaw_rad, sxy, syaw)
        if not all(math.isfinite(float(v)) for v in vals) or sxy < 0.0 or syaw < 0.0:
            raise ValueError(f"init_pose needs finite values and stds >= 0, got {vals}")
        n = st.particles
        z = self._rng.standard_normal((n, 3))
        p = np.empty((n, 3))
        p[:, PoseIndex.X] = float(x_m) + sxy * z[:, 0]
        p[:, PoseIndex.Y] = float(y_m) + sxy * z[:, 1]
        p[:, PoseIndex.YAW] = wrap_angle_shifted(float(yaw_rad) + syaw * z[:, 2])
        self._reset(p, global_pending=False)
        self._std_xy = sxy
        self._converged = sxy < st.converged_std_xy_m and syaw < st.converged_std_yaw_rad
        self._tracking = self._converged

    def init_global(self) -> None:
        """Uniform over the free space; the next scan picks the best global candidates."""
        self._near = None
        self._near_search = False
        self._good_pose = None  # injections over the whole map until it tracks again
        self._reset(self._sample_free(self.settings.global_particles), global_pending=True)
        self.global_inits += 1

    def init_local(self, x_m: float, y_m: float, radius_m: float) -> None:
        """Uniform over the free space within `radius_m` [m] of (x, y) [m], any yaw; the next
        scan picks the best candidates there, as ``init_global`` does over the whole map."""
        self._near = (float(x_m), float(y_m), float(radius_m))
        self._near_search = True
        self._reset(self._sample_near(self.settings.global_particles, *self._near),
                    global_pending=True)
        self.local_inits += 1

    def _reset(self, poses: np.ndarray, global_pending: bool) -> None:
        self._poses = poses
        self._weights = np.full(poses.shape[0], 1.0 / poses.shape[0])
        self._global_pending = global_pending
        self._converged = False
        self._tracking = False
        self._std_xy = math.inf
        self._fit_slow = self._fit_fast = -1.0
        self._lost_scans = 0

    def _sample_free(self, n: int) -> np.ndarray:
        """(n, 3) poses uniform over the free cells (uniform inside a cell), yaw uniform."""
        g = self.grid
        rc = self._free_rc[self._rng.integers(0, self._free_rc.shape[0], n)]
        u = self._rng.random((n, 3))
        r = float(g.resolution_m)
        gx = (rc[:, 1] + u[:, 0]) * r
        gy = (rc[:, 0] + u[:, 1]) * r
        c, s = math.cos(g.origin_yaw_rad), math.sin(g.origin_yaw_rad)
        out = np.empty((n, 3))
        out[:, PoseIndex.X] = g.origin_xy_m[0] + c * gx - s * gy
        out[:, PoseIndex.Y] = g.origin_xy_m[1] + s * gx + c * gy
        out[:, PoseIndex.YAW] = (u[:, 2] - 0.5) * 2.0 * math.pi
        return out

    def _sample_near(self, n: int, x_m: float, y_m: float, radius_m: float) -> np.ndarray:
        """(<= n, 3) poses uniform over the free cells within `radius_m` [m] of (x, y), yaw
        uniform (the whole free space if none is that near)."""
        if self._free_mask is None:
            mask = np.zeros(self.grid.cells.shape, dtype=bool)
            mask[self._free_rc[:, 0], self._free_rc[:, 1]] = True
            self._free_mask = mask
        u = self._rng.random((2 * n, 3))
        r = radius_m * np.sqrt(u[:, 0])
        a = 2.0 * math.pi * u[:, 1]
        xy = np.stack([x_m + r * np.cos(a), y_m + r * np.sin(a)], axis=1)
        rc = self.grid.world_to_cell(xy)
        rows, cols = self._free_mask.shape
        ok = (rc[:, 0] >= 0) & (rc[:, 0] < rows) & (rc[:, 1] >= 0) & (rc[:, 1] < cols)
        ok[ok] = self._free_mask[rc[ok, 0], rc[ok, 1]]
        k = np.flatnonzero(ok)[:n]
        if k.size == 0:
            return self._sample_free(n)
        out = np.empty((k.size, 3))
        out[:, PoseIndex.X] = xy[k, 0]
        out[:, PoseIndex.Y] = xy[k, 1]
        out[:, PoseIndex.YAW] = (u[k, 2] - 0.5) * 2.0 * math.pi
        return out

    # ---------------------------------------------------------------- motion update
    def predict(
        self,
        dt_s: float,
        speed_mps: float,
        yaw_rate_radps: float,
        steering_rad: float | None = None,
    ) -> None:
        """Move every particle by `dt_s` [s] at the odometry speed [m/s] and IMU yaw rate
        [rad/s], with the settings' noise. `steering_rad` is accepted for the interface and
        not used (the yaw rate comes from the IMU). Non-finite values are counted in
        ``rejected_inputs`` and ignored; ``dt_s <= 0`` does nothing."""
        vals = (dt_s, speed_mps, yaw_rate_radps)
        if not all(math.isfinite(float(v)) for v in vals):
            self.rejected_inputs += 1
            return
        if dt_s <= 0.0:
            return
        self._travel_m += abs(float(speed_mps)) * float(dt_s)
        propagate(self._poses, float(dt_s), speed_mps, yaw_rate_radps, self._noise, self._rng)

    # ---------------------------------------------------------------- sensor update
    def _beams(self, scan: Scan, count: int) -> tuple[np.ndarray, np.ndarray] | None:
        """Car-frame end points (K,), (K,) [m] of up to `count` valid beams, evenly spread."""
        st = self.settings
        ranges = np.asarray(scan.ranges_m, dtype=np.float64)
        ok = np.isfinite(ranges) & (ranges >= st.range_min_m) & (ranges < st.range_max_m)
        idx = np.flatnonzero(ok)
        if idx.size == 0:
            return None
        if idx.size > count:
            idx = idx[np.unique(np.linspace(0, idx.size - 1, count).round().astype(np.intp))]
        ang = scan.angle_min_rad + scan.angle_increment_rad * idx + st.lidar_yaw_rad
        rng_m = ranges[idx]
        return st.lidar_x_m + rng_m * np.cos(ang), st.lidar_y_m + rng_m * np.sin(ang)

    def _level(self) -> int:
        """Sigma ladder index: the smallest sigma not below the cloud's position std."""
        sig = self._field.sigmas_m
        for i, s in enumerate(sig):
            if s >= self._std_xy:
                return i
        return len(sig) - 1

    def update(self, scan: Scan) -> PfEstimate:
        """Weight the particles by `scan` (a validated ``shared.messages.Scan``; +inf and
        out-of-range beams are skipped), estimate, resample if needed; returns the estimate."""
        st = self.settings
        if self._global_pending:
            beams = self._beams(scan, st.global_beams)
            if beams is None:
                self.skipped_scans += 1
                return self.estimate()
            self._score_global_candidates(*beams)
            beams = self._beams(scan, st.beams)
        else:
            beams = self._beams(scan, st.beams)
            if beams is None:
                self.skipped_scans += 1
                return self.estimate()
            ll = self._field.log_likelihood(self._poses, beams[0], beams[1], self._level())
            logw = np.log(np.maximum(self._weights, 1e-300)) + ll / st.temperature
            w = np.exp(logw - logw.max())
            self._weights = w / w.sum()
        self.updates += 1
        m = self._moments()
        pose = np.array([m.x_m, m.y_m, m.yaw_rad])
        fit = self._field.hit_fraction(pose, beams[0], beams[1])
        if self._fit_slow < 0.0:
            self._fit_slow = self._fit_fast = fit
        else:
            self._fit_slow += st.alpha_slow * (fit - self._fit_slow)
            self._fit_fast += st.alpha_fast * (fit - self._fit_fast)
        est = self._refresh(m)
        if est.n_eff < st.resample_n_eff_fraction * self._weights.size:
            self._resample()
        searching = self._near_search and not self._tracking  # since a local init
        if est.lost or searching:  # a local search that does not converge is lost too
            self._lost_scans += 1
            if self._lost_scans >= st.lost_reinit_scans:
                self._reinitialise()
        else:
            self._lost_scans = 0
            if est.converged:
                self._good_pose = (est.x_m, est.y_m)
                self._travel_m = 0.0
                self._near_search = False
        return est

    def _injected(self, k: int) -> np.ndarray:
        """(<= k, 3) random poses for augmented MCL: near the last pose tracked (the local
        re-initialisation's radius) once the filter has tracked, else over the whole map
        (a spin's scans dip the fitness, and on a 400 m map a few uniform particles in a
        look-alike corridor took the cloud 8 m away within 0.3 s)."""
        r = self.settings.local_reinit_radius_m
        if self._good_pose is None or r <= 0.0:
            return self._sample_free(k)
        return self._sample_near(k, *self._good_pose, r + self._travel_m)

    def _reinitialise(self) -> None:
        """Lost: search near the last pose tracked (its radius plus the odometry's distance
        since), once; lost again before tracking: the whole map."""
        st = self.settings
        # (a global restart forgets the good pose: after it, only the whole map again)
        if self._good_pose is not None and st.local_reinit_radius_m > 0.0 and not (
            self._near_search
        ):
            self.init_local(*self._good_pose, st.local_reinit_radius_m + self._travel_m)
        else:
            self.init_global()

    def _score_global_candidates(self, bx: np.ndarray, by: np.ndarray) -> None:
        """Score ``global_candidates`` uniform poses (widest sigma); keep the best ones."""
        st = self.settings
        top = len(self._field.sigmas_m) - 1
        keep_p: list[np.ndarray] = []
        keep_ll: list[np.ndarray] = []
        left = st.global_candidates
        while left > 0:
            n = min(CANDIDATE_CHUNK, left)
            left -= n
            cand = self._sample_free(n) if self._near is None else self._sample_near(
                n, *self._near)
            ll = self._field.log_likelihood(cand, bx, by, top)
            keep_p.append(cand)
            keep_ll.append(ll)
            if sum(x.size for x in keep_ll) > 2 * st.global_particles:  # trim as we go
                p_all, ll_all = np.concatenate(keep_p), np.concatenate(keep_ll)
                best = np.argpartition(-ll_all, st.global_particles - 1)[: st.global_particles]
                keep_p, keep_ll = [p_all[best]], [ll_all[best]]
        p_all, ll_all = np.concatenate(keep_p), np.concatenate(keep_ll)
        k = min(st.global_particles, ll_all.size)
        best = np.argpartition(-ll_all, k - 1)[:k]
        self._poses = p_all[best]
        logw = ll_all[best] / st.temperature
        w = np.exp(logw - logw.max())
        self._weights = w / w.sum()
        self._global_pending = False
        self._near = None

    def _resample(self) -> None:
        """Low-variance resampling (fewer particles once converged) plus augmented-MCL
        injection of uniform free-space particles."""
        st = self.settings
        m = st.particles if self._converged else self._weights.size
        idx = low_variance_indices(self._weights, m, self._rng)
        poses = self._poses[idx]
        if self._fit_slow > 0.0:
            p_inject = 1.0 - self._fit_fast / self._fit_slow
            if p_inject > st.inject_min_fraction:
                k = round(min(p_inject, st.inject_max_fraction) * m)
                if k > 0:
                    new = self._injected(k)
                    where = self._rng.choice(m, size=new.shape[0], replace=False)
                    poses[where] = new
        self._poses = poses
        self._weights = np.full(m, 1.0 / m)

    # ---------------------------------------------------------------- estimate
    def _refresh(self, est: PfEstimate) -> PfEstimate:
        """The estimate from the moments `est` of the weighted cloud; updates the convergence
        state."""
        st = self.settings
        sxy = math.sqrt(max(float(np.linalg.eigvalsh(est.cov[:2, :2])[-1]), 0.0))
        syaw = math.sqrt(max(float(est.cov[2, 2]), 0.0))
        self._std_xy = sxy
        if self._converged:
            self._converged = not (
                sxy > UNCONVERGE_FACTOR * st.converged_std_xy_m
                or syaw > UNCONVERGE_FACTOR * st.converged_std_yaw_rad
            )
        else:
            self._converged = sxy < st.converged_std_xy_m and syaw < st.converged_std_yaw_rad
        self._tracking |= self._converged
        return self._finish(est)

    def _moments(self) -> PfEstimate:
        w = self._weights
        p = self._poses
        x = float(np.dot(w, p[:, PoseIndex.X]))
        y = float(np.dot(w, p[:, PoseIndex.Y]))
        yaw_p = p[:, PoseIndex.YAW]
        yaw = math.atan2(float(np.dot(w, np.sin(yaw_p))), float(np.dot(w, np.cos(yaw_p))))
        d = np.stack(
            [p[:, PoseIndex.X] - x, p[:, PoseIndex.Y] - y, wrap_angle_shifted(yaw_p - yaw)],
            axis=1,
        )
        cov = (d * w[:, None]).T @ d
        return PfEstimate(
            x_m=x,
            y_m=y,
            yaw_rad=float(wrap_angle_shifted(yaw)),
            cov=cov,
            n_eff=effective_sample_size(w),
            converged=False,
            lost=False,
            particles=int(w.size),
        )

    def estimate(self) -> PfEstimate:
        """The current estimate (weighted mean and covariance of the particles)."""
        return self._finish(self._moments())

    def _finish(self, m: PfEstimate) -> PfEstimate:
        """`m` (the moments) with the convergence, lost and fitness fields filled in."""
        fit = max(self._fit_fast, 0.0)
        lost = self._tracking and self._fit_fast >= 0.0 and fit < self.settings.lost_fitness
        return PfEstimate(
            x_m=m.x_m,
            y_m=m.y_m,
            yaw_rad=m.yaw_rad,
            cov=m.cov,
            n_eff=m.n_eff,
            converged=self._converged and not lost,
            lost=lost,
            fitness=fit,
            particles=m.particles,
        )

    @property
    def poses(self) -> np.ndarray:
        """(N, 3) copy of the particles [x m, y m, yaw rad] (PoseIndex columns)."""
        return self._poses.copy()

    @property
    def weights(self) -> np.ndarray:
        """(N,) copy of the normalised weights."""
        return self._weights.copy()
