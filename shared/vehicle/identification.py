"""System identification of the car from a recorded run: the fitting maths (no I/O).

Input: time series [s, value] of what the stack records while it drives (never the
simulator's truth): the drive command (``cmd/drive``: target speed [m/s] and steering
[rad]), the wheel odometry (``vehicle/odom``: speed [m/s], road-wheel angle [rad]) and the
IMU (``vehicle/imu``: yaw rate [rad/s], body-frame accelerations [m/s^2]); ``SIGNALS``
names them. ``identify(signals, base, model)`` resamples them on one grid of ``GRID_DT_S``
and fits three parts of the car, each by least squares:

Steering (``fit_steering``): the servo of ``services.simulator.actuators``, i.e. the command
acts after a delay ``T_d`` and the wheel follows it as a first-order lag (time constant
``tau``) clipped to a rate limit ``R``::

    delta[k+1] = delta[k] + clip((cmd(t_k - T_d) - delta[k]) (1 - exp(-dt / tau)), -R dt, R dt)

simulated from the first measured angle for a grid of (T_d, tau, R) at once, then on a finer
grid around the best; error: the measured road-wheel angle.

Speed loop (``fit_speed``): ``v' = k (v_cmd(t - T_v) - v)`` with ``k = k_accel`` while |v|
grows and ``k_brake`` while it shrinks, clipped to ``a_max`` (``a_max v_switch / v`` above
v_switch). For each delay on a grid, linear least squares of the measured ``v'`` (a
linear-phase derivative of the odometry speed) on the speed error, unsaturated samples only;
``a_max`` is the median acceleration where the loop asks for clearly more than it gets.

Tyres (``fit_tyres``): output error of the project's single-track model
(``shared.vehicle.single_track``, the simulator's equations) with the measured speed, road-
wheel angle (plus a fitted offset) and longitudinal acceleration as inputs (the speed
divided by ``cos(beta)``: odometry measures the wheel speed ``v cos(beta)``): slip angle and
yaw rate are integrated (midpoint rule) over windows of ``WINDOW_S`` where the car is
faster than ``MIN_SPEED_MPS``, started from the measured yaw rate and the linear model's
steady-state slip angle (``fit_tyres(fit_beta0=True)`` fits each window's start instead:
experimental, it diverged on spin-heavy runs); the first ``BURN_IN_S`` of each window are
not scored. The IMU's accelerations are taken as what the simulator's are, the mean over
the grid step that ends at their stamp: ``a_x[k + 1]`` is the input of the step ``k -> k +
1`` and ``a_y[k + 1]`` is compared with the model's at that step's midpoint (not at
``t_k``: half a step apart). The model's input is the acceleration DEMAND ``a`` (the
speed loop's, split over the axles by load), while the IMU measures ``F_X / m``, the
demand plus the tyres' drag (the front's lateral force along the body when it steers,
the friction ellipse), which depends on the tyres being fitted: each evaluation solves
``F_X(a) / m = a_x`` for ``a`` (``DEMAND_ITERATIONS`` fixed-point steps from the previous
evaluation's drag). With noise-free sensors the true tyres are then the fit's optimum
(yaw rate 0.8 mrad/s rms on the softer benchmark car, 35 mrad/s with ``a_x`` taken as the
demand). Two passes: the first takes ``a_x`` itself as the demand (a start that does not
depend on the tyres), the second starts from it with the solved demand and drops the
windows the first fitted worst (spins and recoveries, ``OUTLIER_RMS``); the speed loop is
fitted only where the drag is known.
Residuals: measured yaw rate and lateral acceleration (``F_Y / m``), each divided by its
noise level. Levenberg-Marquardt over the log of the
tyre parameters (``TYRE_PARAMETERS`` per model):

- ``linear``: ``mu C_Sf``, ``mu C_Sr`` (only the products act; ``mu`` stays the base's);
- ``linear_saturated``: ``C_Sf``, ``C_Sr``, ``mu``;
- ``pacejka``: ``B, C, D`` per axle (``E`` and ``mu = 1`` as in the base car; D is then the
  peak friction coefficient).

Geometry and mass (``m, I_z, l_f, l_r, h``) come from the base car (weighed and measured,
not fitted).

Uncertainty (``Estimate.sigma``, one standard deviation) has two parts in quadrature:

- Statistical: a delete-one-block jackknife. The grid is cut into ``JACKKNIFE_BLOCKS``
  contiguous stretches of equal length (about a lap each in a 2-minute race); each
  estimate is made again without each block in turn and ``sigma^2 = (G - 1) / G sum_g
  (x_g - mean)^2``. The residuals are correlated over seconds (the model's own error,
  lap after lap), which the curvature of the sum of squares does not see even inflated for
  their lag-1 correlation; a block's worth of data left out shows what another recording
  would. No refit: the steering's servo simulation sums its squares per block for every
  candidate of its grids at once (each replicate the vertex of its own profile); the speed
  loop keeps its sums per block for every (delay, a_max) and its gains are a linear least
  squares (refitted without each block); the tyres take one Gauss-Newton step from the
  optimum on the other blocks' rows of the Jacobian the fit already has (linearised:
  a block is a tenth of the data).
- Systematic, what no resampling of this recording shows (``Estimate.sigma_systematic``):
  the grid and the timing. A delay is fitted on the grid's steps and its signals are
  stamped only to within their sample period (a sample may stand for any instant of it:
  the simulator's IMU gives the mean acceleration over its step, stamped at the end; a
  real one filters), so its floor is ``sqrt(dt^2 + sum T_s^2) / sqrt 12``
  (``timing_sigma``: the grid's step, the period of each signal in it). A parameter that
  trades off against a delay (the servo's time constant and rate limit, the speed loop's
  gains and acceleration limit) gets ``|d x / d delay|`` (its optimum at the neighbouring
  delays) times that floor. The tyres: each signal (yaw rate, lateral acceleration,
  steering angle, speed, longitudinal acceleration) shifted by one grid step, the fit's linear
  response ``-(J^T J)^-1 J^T dr`` scaled to the signal's ``T / sqrt 12``, the signals'
  responses independent (one simulation each for the inputs).

``Estimate.sigma_curvature`` keeps the former, curvature-only sigma (Gauss-Newton
``s^2 (J^T J)^-1`` or a parabola through a grid parameter's profile, scaled by ``n /
n_eff`` for the lag-1 correlation) for comparison; the Pacejka B-C correlation below is
that curvature's (the shape of the sum of squares, not a spread of ten replicates).
A delay is identifiable when its sigma is at most ``DELAY_SIGMA_MAX_S`` (a relative sigma
means little for a delay near 0); a rate limit only when the fit without it (the fastest
rate tried) is worse by ``LIMIT_SIGNIFICANCE`` jackknife sigmas of that difference. A
parameter whose relative uncertainty exceeds ``IDENTIFIABLE_REL_SIGMA``, whose grid optimum
sits at the grid's edge, or whose effect the run never shows (a rate limit never reached,
friction never used up, an acceleration limit never hit) is reported as not identifiable
from this run; its value is then a bound or the base car's, and an overlay keeps the base.
A Pacejka B and C correlated beyond ``BC_CORRELATION_MAX`` are not identifiable each (only
their product is): the overlay writes them as fitted, since the product holds. A Pacejka D
whose friction the run never used up is not identifiable either, but when the curve below
the peak still tells it (relative sigma within ``IDENTIFIABLE_REL_SIGMA``) the overlay
writes the fit too, an extrapolation (the base car's neutral guess would be worse).
A steering rate limit the run does not tell is at least the fastest road-wheel rate the run
measured (``Estimate.lower_bound``): the overlay writes that rate when it is below the base
car's limit, so that a car is never planned to steer faster than it has been seen to (the
gym's 3.2 rad/s kept for a servo that slews at 2.24 planned lines the car could not follow:
the grippier benchmark car spun in paperlike's S-bend and raced at 1.16 x its limit, 1.02
told its true rate).

Bad input raises ``SysidError`` with one line naming what is missing (too short, no
cornering, a signal absent or too sparse).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field, replace
from typing import Any, NamedTuple

import numpy as np

from shared.config.vehicle import GRAVITY_MPS2, DynamicVehicleParams
from shared.vehicle.ops import Ops
from shared.vehicle.single_track import make_dynamic_derivatives
from shared.vehicle.tyres import axle_peak_friction, pacejka_peak_slip_rad

#: The signals ``identify`` needs, each ``(t [s], value)``.
SIGNALS: tuple[str, ...] = (
    "cmd_speed_mps",
    "cmd_steering_rad",
    "speed_mps",
    "steering_rad",
    "yaw_rate_radps",
    "ax_mps2",
    "ay_mps2",
)
#: Resampling grid step [s].
GRID_DT_S = 0.01
#: Shortest usable run (overlap of all signals) [s].
MIN_DURATION_S = 20.0
#: "Cornering": at least MIN_CORNER_SHARE of the samples with |a_y| above this [m/s^2].
CORNER_AY_MPS2 = 1.5
MIN_CORNER_SHARE = 0.05
#: A gap in one signal longer than this [s] makes the samples inside it unusable.
MAX_GAP_S = 0.25
#: Tyre fit windows: length, unscored start, slowest speed, most windows used.
WINDOW_S = 1.5
BURN_IN_S = 0.25
MIN_SPEED_MPS = 1.5
MAX_WINDOWS = 160
#: Pacejka B and C correlated beyond this: only their product (the small-slip stiffness
#: with D) is told; each is then "not identifiable" but written as fitted (the product holds).
BC_CORRELATION_MAX = 0.9
PRODUCT_ONLY = "only B*C is told"
#: The note of a friction parameter the run never used up (module docstring).
FRICTION_UNUSED = "friction never used up"
#: Fixed-point steps that solve each evaluation's acceleration demand from the measured
#: a_x (``simulate_lateral``; started from the previous evaluation's drag, half a step old).
DEMAND_ITERATIONS = 1
#: Finite-difference step of the windows' initial slip angles [rad].
BETA0_STEP_RAD = 1e-4
#: Pass 2 of the tyre fit drops windows whose rms residual exceeds this x the median.
OUTLIER_RMS = 3.0
#: Levenberg-Marquardt iterations of pass 2 (it starts from pass 1's optimum).
PASS2_ITERATIONS = 30
#: Contiguous blocks of the recording the delete-one-block jackknife leaves out in turn.
JACKKNIFE_BLOCKS = 10
#: A delay is identifiable when its 1-sigma is at most this [s] (and its optimum interior).
DELAY_SIGMA_MAX_S = 0.02
#: A rate limit is "reached" when the fit without it is worse by this many jackknife
#: sigmas of that difference (the data prefer the limit beyond chance).
LIMIT_SIGNIFICANCE = 3.0
#: A parameter is identifiable when its 1-sigma is at most this share of its value.
IDENTIFIABLE_REL_SIGMA = 0.25
#: Steering grids: delay [s], time constant [s], rate limit [rad/s].
STEER_DELAYS_S = np.arange(-0.03, 0.2001, GRID_DT_S)
STEER_TAUS_S = np.geomspace(0.005, 0.5, 15)
STEER_RATES_RADPS = np.geomspace(0.5, 20.0, 15)
#: Speed-loop delays tried [s].
SPEED_DELAYS_S = np.arange(-0.05, 0.2001, GRID_DT_S)
#: Acceleration limits tried [m/s^2].
SPEED_AMAX_MPS2 = np.geomspace(1.0, 30.0, 36)
#: Fitted tyre parameters per model (overlay field names; ``steering_offset_rad`` extra).
TYRE_PARAMETERS: dict[str, tuple[str, ...]] = {
    "linear": ("mu_cornering_stiffness_front_per_rad", "mu_cornering_stiffness_rear_per_rad"),
    "linear_saturated": (
        "cornering_stiffness_front_per_rad", "cornering_stiffness_rear_per_rad", "mu"),
    "pacejka": ("pacejka_front_B", "pacejka_front_C", "pacejka_front_D",
                "pacejka_rear_B", "pacejka_rear_C", "pacejka_rear_D"),
}
#: Bounds of the tyre parameters (clipped in the search).
_TYRE_BOUNDS = {"B": (0.5, 100.0), "C": (0.3, 2.9), "D": (0.05, 3.0), "k": (0.1, 200.0),
                "mu": (0.05, 3.0)}

NUMPY_OPS = Ops(cos=np.cos, sin=np.sin, tan=np.tan, atan=np.arctan, atan2=np.arctan2,
                sqrt=np.sqrt, fmin=np.minimum, fmax=np.maximum, fabs=np.abs)


class SysidError(ValueError):
    """A recording that cannot be identified; the message is one line naming why."""


@dataclass(frozen=True)
class Estimate:
    """One identified parameter.

    Attributes:
        name: the ``[vehicle]`` field (or a sysid-only name such as ``steering_delay_s``).
        value: the estimate (a bound or the base car's value when not identifiable).
        sigma: its 1-sigma uncertainty (inf: the run does not tell).
        identifiable: whether this run tells it (module docstring).
        unit: its unit.
        note: why not identifiable, or what bounds it.
    """

    name: str
    value: float
    sigma: float
    identifiable: bool
    unit: str = ""
    note: str = ""
    #: the sigma from the curvature of the sum of squares alone (inflated for the
    #: residuals' lag-1 correlation): what ``sigma`` was before the jackknife, kept for
    #: comparison (NaN: not computed)
    sigma_curvature: float = math.nan
    #: the part of ``sigma`` from the grid's and the timing's floors (module docstring,
    #: "Uncertainty"); the rest, ``sqrt(sigma^2 - sigma_systematic^2)``, is the jackknife's
    sigma_systematic: float = 0.0
    #: what the run shows the parameter is at least (a limit never reached: the largest
    #: value measured), in ``unit``; NaN when the run gives no bound
    lower_bound: float = math.nan


def _with_curvature(out: dict[str, Estimate], curv: Mapping[str, float],
                    systematic: Mapping[str, float] | None = None) -> dict[str, Estimate]:
    """`out` with each estimate's ``sigma_curvature`` from `curv` and its
    ``sigma_systematic`` from `systematic` (by name; finite sigmas only)."""
    systematic = systematic or {}
    res = {}
    for k, e in out.items():
        upd: dict[str, float] = {}
        if k in curv:
            upd["sigma_curvature"] = float(curv[k])
        if k in systematic and math.isfinite(e.sigma):
            upd["sigma_systematic"] = float(systematic[k])
        res[k] = replace(e, **upd) if upd else e
    return res


@dataclass
class SysidResult:
    """All estimates plus what the figure shows (grid time and measured / predicted)."""

    model: str
    estimates: dict[str, Estimate]
    duration_s: float
    t_s: np.ndarray
    curves: dict[str, tuple[np.ndarray, np.ndarray]] = field(default_factory=dict)
    fit_info: dict[str, Any] = field(default_factory=dict)

    def vehicle_overlay(self, base: DynamicVehicleParams) -> dict[str, Any]:
        """The ``[vehicle]`` fields of the identified car: the identifiable estimates, the
        base car's values for the rest (``tyre_model`` the fitted model); a Pacejka axle's
        B, C and D all as fitted once any of them is written; a steering rate limit the run
        does not tell as the fastest rate it saw when that is below the base's."""
        e = {k: v for k, v in self.estimates.items()
             if v.identifiable or v.note.startswith(PRODUCT_ONLY) or _extrapolated_d(v)}
        out: dict[str, Any] = {"tyre_model": self.model}
        if base.preset != "f1tenth_gym":
            out["preset"] = base.preset
        for name in ("speed_gain_accel_per_s", "speed_gain_brake_per_s", "accel_max_mps2",
                     "steering_time_constant_s"):
            if name in e:
                out[name] = _round(e[name].value)
        rate_est = self.estimates.get("steering_rate_max_radps")
        if "steering_rate_max_radps" in e:
            rate = _round(e["steering_rate_max_radps"].value)
            out["steering_rate_max_radps"] = rate
            out["steering_rate_min_radps"] = -rate
        elif rate_est is not None and math.isfinite(rate_est.lower_bound) and \
                rate_est.lower_bound < min(base.steering_rate_max_radps,
                                           -base.steering_rate_min_radps):
            # not told, but never seen faster than this: plan no faster than seen
            rate = _round(rate_est.lower_bound)
            out["steering_rate_max_radps"] = rate
            out["steering_rate_min_radps"] = -rate
        if self.model == "linear":
            for axle in ("front", "rear"):
                k = e.get(f"mu_cornering_stiffness_{axle}_per_rad")
                if k is not None:
                    out[f"cornering_stiffness_{axle}_per_rad"] = _round(k.value / base.mu)
        elif self.model == "linear_saturated":
            for name in TYRE_PARAMETERS["linear_saturated"]:
                if name in e:
                    out[name] = _round(e[name].value)
        else:
            out["mu"] = 1.0
            for axle in ("front", "rear"):
                coeffs = list(base.pacejka_front if axle == "front" else base.pacejka_rear)
                names = [f"pacejka_{axle}_{letter}" for letter in "BCD"]
                # an axle's B, C and D are one fit: once any of them is written, all are
                # (the base's neutral B = 10 beside a fitted C and D is a curve neither
                # the data nor the base tells: the identified car's rear B, "uncertainty
                # 60 %", kept at 10 beside C 1.6 halved its stiffness and doubled the slip
                # the line planned; raceline raced paperlike at 1.25 x the limit, 1.04
                # with the fitted B)
                if any(n in e for n in names):
                    for i, n in enumerate(names):
                        est = self.estimates.get(n)
                        if est is not None and math.isfinite(est.value):
                            coeffs[i] = _round(est.value)
                out[f"pacejka_{axle}"] = coeffs
        return out


def _extrapolated_d(e: Estimate) -> bool:
    """A Pacejka D the run never used up but whose curve below the peak tells it (its
    relative sigma within ``IDENTIFIABLE_REL_SIGMA``): the overlay writes the fit, since
    the base car's guess (the neutral 1.0) would tell the planner far more grip."""
    return (e.name.endswith("_D") and e.note.startswith(FRICTION_UNUSED)
            and math.isfinite(e.sigma) and e.sigma <= IDENTIFIABLE_REL_SIGMA * abs(e.value))


def _round(x: float) -> float:
    """4 significant digits (what the data can tell, at best)."""
    return float(f"{x:.4g}")


# ------------------------------------------------------------------ resampling and checks
@dataclass(frozen=True)
class Grid:
    """The signals on one uniform grid (``GRID_DT_S``); `ok` marks samples with every
    measured signal present (no gap longer than ``MAX_GAP_S``)."""

    t: np.ndarray
    cmd_v: np.ndarray
    cmd_d: np.ndarray
    v: np.ndarray
    d: np.ndarray
    r: np.ndarray
    ax: np.ndarray
    ay: np.ndarray
    ok: np.ndarray
    #: each measured signal's median sample spacing [s] (``SIGNALS`` names; the timing
    #: floors of the sigmas, module docstring)
    periods: Mapping[str, float] = field(default_factory=dict)


def _clean(name: str, series: Any) -> tuple[np.ndarray, np.ndarray]:
    try:
        t, v = (np.asarray(x, dtype=float).ravel() for x in series)
    except (TypeError, ValueError):
        raise SysidError(f"signal {name} is not a (time, value) pair of arrays") from None
    keep = np.isfinite(t) & np.isfinite(v)
    t, v = t[keep], v[keep]
    order = np.argsort(t, kind="stable")
    t, v = t[order], v[order]
    if len(t) < 2:
        raise SysidError(f"signal {name} has {len(t)} samples (needs a series)")
    return t, v


def resample(signals: Mapping[str, Any], dt: float = GRID_DT_S) -> Grid:
    """The signals on a uniform grid over the time all of them cover: measurements
    linearly interpolated, commands held (zero-order hold: the last command at or before
    each grid time).

    Raises:
        SysidError: a signal missing or too short, or their overlap under MIN_DURATION_S.
    """
    missing = [k for k in SIGNALS if k not in signals]
    if missing:
        raise SysidError(f"missing signals: {', '.join(missing)}")
    s = {k: _clean(k, signals[k]) for k in SIGNALS}
    t0 = max(t[0] for t, _ in s.values())
    t1 = min(t[-1] for t, _ in s.values())
    if t1 - t0 < MIN_DURATION_S:
        raise SysidError(f"too short: the signals overlap for {max(t1 - t0, 0.0):.1f} s, "
                         f"at least {MIN_DURATION_S:.0f} s are needed")
    t = t0 + dt * np.arange(int((t1 - t0) / dt) + 1)
    ok = np.ones(len(t), dtype=bool)

    def held(name: str) -> np.ndarray:
        ts, vs = s[name]
        i = np.searchsorted(ts, t + 1e-9, side="right") - 1
        return vs[np.clip(i, 0, len(vs) - 1)]

    def interp(name: str) -> np.ndarray:
        ts, vs = s[name]
        i = np.clip(np.searchsorted(ts, t), 1, len(ts) - 1)
        ok[(ts[i] - ts[i - 1]) > MAX_GAP_S] = False
        return np.interp(t, ts, vs)

    periods = {k: float(np.median(np.diff(ts))) for k, (ts, _v) in s.items()}
    return Grid(t, held("cmd_speed_mps"), held("cmd_steering_rad"), interp("speed_mps"),
                interp("steering_rad"), interp("yaw_rate_radps"), interp("ax_mps2"),
                interp("ay_mps2"), ok, periods)


def check_cornering(g: Grid) -> None:
    """Raise ``SysidError`` when the run has (almost) no cornering to fit tyres on."""
    share = float(np.mean(np.abs(g.ay[g.ok]) > CORNER_AY_MPS2)) if g.ok.any() else 0.0
    if share < MIN_CORNER_SHARE:
        raise SysidError(
            f"no cornering: |a_y| exceeds {CORNER_AY_MPS2:g} m/s^2 in {100 * share:.1f} % of "
            f"the run (at least {100 * MIN_CORNER_SHARE:.0f} % needed to fit the tyres)")


def noise_std(x: np.ndarray) -> float:
    """White-noise level of a smooth signal sampled densely: ``MAD(diff) / 0.6745 / sqrt 2``."""
    d = np.diff(x)
    if len(d) == 0:
        return 0.0
    return float(np.median(np.abs(d - np.median(d))) / 0.6745 / math.sqrt(2.0))


def _n_eff_factor(res: np.ndarray) -> float:
    """``n / n_eff`` of residuals from their lag-1 autocorrelation (>= 1)."""
    res = np.asarray(res, dtype=float).ravel()
    if len(res) < 3 or not np.any(res):
        return 1.0
    rho = float(np.corrcoef(res[:-1], res[1:])[0, 1])
    if not math.isfinite(rho):
        return 1.0
    rho = min(max(rho, 0.0), 0.999)
    return (1.0 + rho) / (1.0 - rho)


def _profile_sigma(x: np.ndarray, sse: np.ndarray, s2: float) -> tuple[float, float, bool]:
    """(vertex, sigma, interior) of a parabola through a profile `sse` over grid `x` at
    its minimum; sigma from ``SSE = SSE_min + (x - x0)^2 s2 / sigma^2``, inf when flat
    or at an edge (then the vertex is the grid minimum)."""
    i = int(np.argmin(sse))
    if i == 0 or i == len(x) - 1:
        return float(x[i]), math.inf, False
    x3, y3 = x[i - 1:i + 2], sse[i - 1:i + 2]
    a, b, _c = np.polyfit(x3, y3, 2)
    if not a > 0:
        return float(x[i]), math.inf, True
    x0 = float(np.clip(-b / (2 * a), x3[0], x3[2]))
    return x0, math.sqrt(s2 / a), True


def timing_sigma(g: Grid, *names: str, grid: bool = False) -> float:
    """The timing floor [s]: each of the signals `names` is stamped to within its sample
    period T (a sample may stand for any instant of its period: the IMU's accelerations
    are the mean over the simulator's step, a real one filters), ``T / sqrt 12`` each,
    plus ``dt / sqrt 12`` when `grid` (a delay fitted on the grid's steps), independent,
    in quadrature."""
    dt = float(g.t[1] - g.t[0])
    terms = [g.periods.get(n, dt) for n in names] + ([dt] if grid else [])
    return math.sqrt(sum(x * x for x in terms) / 12.0)


def jackknife_blocks(n: int, n_blocks: int = JACKKNIFE_BLOCKS) -> np.ndarray:
    """(n,) block of each grid sample: `n_blocks` contiguous stretches of equal length."""
    return (np.arange(n) * n_blocks) // max(n, 1)


def jackknife_sigma(replicates: np.ndarray) -> np.ndarray:
    """Delete-one-block jackknife standard deviation of estimates `replicates` (G, ...):
    ``sqrt((G - 1) / G * sum_g (x_g - mean)^2)`` (the spread a refit on other data shows,
    whatever the residuals' correlation within a block)."""
    x = np.asarray(replicates, dtype=float)
    n_b = x.shape[0]
    return np.sqrt((n_b - 1) / n_b * np.sum((x - x.mean(axis=0)) ** 2, axis=0))


def _vertex(x: np.ndarray, sse: np.ndarray) -> float:
    """The parabola vertex of ``_profile_sigma`` (the grid minimum at an edge)."""
    return _profile_sigma(x, sse, 1.0)[0]


def _jack_profile(x: np.ndarray, total: np.ndarray, per_block: np.ndarray,
                  axes: tuple[int, ...]) -> float:
    """Jackknife sigma of the profile vertex over grid `x`: per block g the profile
    ``min over axes of (total - per_block[g])``, its vertex; their spread."""
    reps = [_vertex(x, (total - b).min(axis=axes) if axes else total - b) for b in per_block]
    return float(jackknife_sigma(np.array(reps)))


def _delay_coupling(values: list[float], i: int, step_s: float) -> float:
    """|d value / d delay| from the values at delays ``i - 1, i, i + 1`` of a grid of step
    `step_s` (central difference, one-sided at an edge): the systematic error of a
    parameter that trades off against a delay the grid resolves only to ``dt / sqrt 12``
    is this times ``dt / sqrt 12``."""
    lo, hi = max(i - 1, 0), min(i + 1, len(values) - 1)
    if hi == lo:
        return 0.0
    slope = (values[hi] - values[lo]) / ((hi - lo) * step_s)
    return abs(slope) if math.isfinite(slope) else 0.0


# ------------------------------------------------------------------ steering
def simulate_servo(
    g: Grid, delay_s: np.ndarray, tau_s: np.ndarray, rate_radps: np.ndarray,
    blocks: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """(SSE per candidate, predicted angle of the first candidate (n,)) of the servo model
    (module docstring) for candidate arrays of equal shape (delay on the grid's steps).
    `blocks` (n,) ints in ``0..G-1`` (``jackknife_blocks``): the SSE per block instead,
    shape (G, *candidates), which sums to the total."""
    dt = float(g.t[1] - g.t[0])
    shape = np.shape(delay_s)
    lag = np.rint(np.ravel(delay_s) / dt).astype(int)
    gain = 1.0 - np.exp(-dt / np.ravel(tau_s))
    step = np.ravel(rate_radps) * dt
    n = len(g.t)
    delta = np.full(lag.shape, g.d[0])
    n_b = 1 if blocks is None else int(np.max(blocks)) + 1
    blk = np.zeros(n, dtype=int) if blocks is None else np.asarray(blocks, dtype=int)
    sse = np.zeros((n_b, *lag.shape))
    first = np.empty(n)
    cmd, meas, ok = g.cmd_d, g.d, g.ok
    idx = np.arange(n)
    for k in range(n):
        if ok[k]:
            e = delta - meas[k]
            sse[blk[k]] += e * e
        first[k] = delta[0]
        target = cmd[np.clip(idx[k] - lag, 0, n - 1)]
        delta = delta + np.clip((target - delta) * gain, -step, step)
    if blocks is None:
        return sse[0].reshape(shape), first
    return sse.reshape((n_b, *shape)), first


def fit_steering(g: Grid, base: DynamicVehicleParams) -> tuple[dict[str, Estimate], np.ndarray]:
    """Steering delay, time constant and rate limit (module docstring); also the predicted
    road-wheel angle on the grid. Sigmas: the delete-one-block jackknife of each profile's
    vertex, with the grid's systematic terms (module docstring, "Uncertainty")."""
    dt = float(g.t[1] - g.t[0])
    q = timing_sigma(g, "steering_rad", grid=True)  # the delay's grid and timing floor
    blocks = jackknife_blocks(len(g.t))
    dd, tt, rr = np.meshgrid(STEER_DELAYS_S, STEER_TAUS_S, STEER_RATES_RADPS, indexing="ij")
    sse_b, _ = simulate_servo(g, dd, tt, rr, blocks)
    sse = sse_b.sum(axis=0)
    i, j, k = np.unravel_index(int(np.argmin(sse)), sse.shape)
    # finer grid around the coarse optimum: delay on the grid step, tau and rate in log
    fd = STEER_DELAYS_S[max(i - 2, 0):i + 3]
    ft = np.geomspace(STEER_TAUS_S[max(j - 1, 0)], STEER_TAUS_S[min(j + 1, 14)], 9)
    fr = np.geomspace(STEER_RATES_RADPS[max(k - 1, 0)], STEER_RATES_RADPS[min(k + 1, 14)], 9)
    dd, tt, rr = np.meshgrid(fd, ft, fr, indexing="ij")
    sse_fb, _ = simulate_servo(g, dd, tt, rr, blocks)
    sse_f = sse_fb.sum(axis=0)
    i2, j2, k2 = np.unravel_index(int(np.argmin(sse_f)), sse_f.shape)
    best = (fd[i2], ft[j2], fr[k2])
    _, pred = simulate_servo(g, np.array([best[0]]), np.array([best[1]]), np.array([best[2]]))
    res = (pred - g.d)[g.ok]
    n = len(res)
    s2 = float(np.sum(res * res)) / max(n - 3, 1) * _n_eff_factor(res)
    out: dict[str, Estimate] = {}
    # delay: the coarse profile (min over tau, rate) around the optimum
    prof_d = sse.min(axis=(1, 2))
    d0, sd, interior = _profile_sigma(STEER_DELAYS_S, prof_d, s2)
    d0 = best[0] if abs(d0 - best[0]) > dt else d0
    curv = {"steering_delay_s": max(sd, dt / math.sqrt(12.0))}
    sysd = {"steering_delay_s": q}
    sd = math.hypot(_jack_profile(STEER_DELAYS_S, sse, sse_b, (1, 2)), q)
    sd = sd if interior else math.inf
    out["steering_delay_s"] = _estimate("steering_delay_s", d0, sd, "s",
                                        "" if interior else "at the edge of the delays tried")
    if sd <= DELAY_SIGMA_MAX_S and interior:  # a delay's relative sigma means little
        out["steering_delay_s"] = Estimate("steering_delay_s", d0, sd, True, "s")
    # tau and the rate limit trade off against the delay (on the grid's steps only): their
    # optimum at the neighbouring delays gives the systematic term (_delay_coupling)
    tau_at = [_vertex(np.log(ft), sse_f[m].min(axis=1)) for m in range(len(fd))]
    rate_at = [_vertex(np.log(fr), sse_f[m].min(axis=0)) for m in range(len(fd))]
    prof_t = sse_f.min(axis=(0, 2))
    lt, st_, interior_t = _profile_sigma(np.log(ft), prof_t, s2)
    tau_note = "" if interior_t else "the servo's lag is shorter than the data resolve"
    rel_t, jack_t = st_, _jack_profile(np.log(ft), sse_f, sse_fb, (0, 2))
    if not interior_t:
        prof_t = sse.min(axis=(0, 2))
        lt, rel_t, interior_t = _profile_sigma(np.log(STEER_TAUS_S), prof_t, s2)
        jack_t = _jack_profile(np.log(STEER_TAUS_S), sse, sse_b, (0, 2))
        tau_note = "" if interior_t else tau_note
    tau_hat = math.exp(lt)
    curv["steering_time_constant_s"] = tau_hat * rel_t
    sysd["steering_time_constant_s"] = tau_hat * _delay_coupling(tau_at, i2, dt) * q
    rel_t = math.hypot(jack_t, _delay_coupling(tau_at, i2, dt) * q) if math.isfinite(
        rel_t) else rel_t
    if tau_hat < 2.0 * dt:  # a lag of a grid step or two: an upper bound, good enough
        out["steering_time_constant_s"] = Estimate(
            "steering_time_constant_s", tau_hat, max(tau_hat * rel_t, dt), True, "s",
            f"below the data's resolution of {2 * dt:g} s: the servo is rate-limited")
    else:
        out["steering_time_constant_s"] = _estimate(
            "steering_time_constant_s", tau_hat, tau_hat * rel_t, "s", tau_note)
    # rate limit: identifiable only if the fitted servo actually runs into it
    rate = best[2]
    dt_rate = np.abs(np.diff(pred)) / dt
    at_limit = float(np.mean(dt_rate > 0.98 * rate))
    prof_r = sse_f.min(axis=(0, 1))
    lr_, sr, interior_r = _profile_sigma(np.log(fr), prof_r, s2)
    jack_r = _jack_profile(np.log(fr), sse_f, sse_fb, (0, 1))
    if not interior_r:
        prof_r = sse.min(axis=(0, 1))
        lr_, sr, interior_r = _profile_sigma(np.log(STEER_RATES_RADPS), prof_r, s2)
        jack_r = _jack_profile(np.log(STEER_RATES_RADPS), sse, sse_b, (0, 1))
    curv["steering_rate_max_radps"] = math.exp(lr_) * sr
    if math.isfinite(sr):
        sr = math.hypot(jack_r, _delay_coupling(rate_at, i2, dt) * q)
        sysd["steering_rate_max_radps"] = math.exp(lr_) * _delay_coupling(rate_at, i2, dt) * q
    seen = float(np.max(np.abs(np.diff(g.d))) / dt)
    # does the run need the limit? the gain in SSE over the fastest rate tried, against
    # its jackknife spread (each block's own share of the gain)
    gain_sse = float(sse[:, :, -1].min() - sse.min())
    gain_jack = float(jackknife_sigma(np.array(
        [(sse - b)[:, :, -1].min() - (sse - b).min() for b in sse_b])))
    needed = gain_sse > LIMIT_SIGNIFICANCE * gain_jack
    if at_limit < 0.005 or not needed:
        out["steering_rate_max_radps"] = Estimate(
            "steering_rate_max_radps", max(seen, rate), math.inf, False, "rad/s",
            f"never reached: at least {seen:.2f} rad/s seen" if at_limit < 0.005 else
            f"not needed by the data (the fit without it is worse by "
            f"{gain_sse / max(gain_jack, 1e-300):.1f} jackknife sigmas): at least "
            f"{seen:.2f} rad/s seen", lower_bound=seen)
    else:
        out["steering_rate_max_radps"] = _estimate(
            "steering_rate_max_radps", math.exp(lr_), math.exp(lr_) * sr, "rad/s",
            "" if interior_r else "at the edge of the grid")
    return _with_curvature(out, curv, sysd), pred


def _estimate(name: str, value: float, sigma: float, unit: str, note: str = "") -> Estimate:
    rel = sigma / abs(value) if value else math.inf
    ok = not note and math.isfinite(sigma) and rel <= IDENTIFIABLE_REL_SIGMA
    if not note and not ok:
        note = f"uncertainty {100 * rel:.0f} % of the value" if math.isfinite(rel) else \
            "the run does not constrain it"
    return Estimate(name, float(value), float(sigma), ok, unit, note)


# ------------------------------------------------------------------ speed loop
def derivative(x: np.ndarray, dt: float, half: int = 4) -> np.ndarray:
    """Linear-phase derivative [unit/s]: the slope of a least-squares line over
    ``2 half + 1`` samples (edges: the nearest full window's)."""
    k = np.arange(-half, half + 1, dtype=float)
    w = k / (np.sum(k * k) * dt)
    d = np.convolve(x, w[::-1], mode="same")
    d[:half], d[-half:] = d[half], d[-half - 1]
    return d


def _accel_limit(v: np.ndarray, base: DynamicVehicleParams, a_max: float) -> np.ndarray:
    return a_max * np.minimum(1.0, base.v_switch_mps / np.maximum(np.abs(v), 1e-3))


def fit_speed(g: Grid, base: DynamicVehicleParams, xdrag: np.ndarray | None = None,
              known: np.ndarray | None = None,
              ) -> tuple[dict[str, Estimate], np.ndarray, np.ndarray]:
    """Speed-loop gains, delay and acceleration limit (module docstring); also the
    measured and the predicted acceleration demand on the grid. The measured demand is
    the IMU's ``a_x`` (``F_X / m`` of the body) less `xdrag`, the tyres' part of it
    (``fit_tyres``: the front axle's lateral force along the body when it steers);
    without `xdrag`, ``a_x`` itself. `known`: the samples where `xdrag` is known (the
    others are not used).

    For each (delay, a_max) of a grid the gains are the least squares over the samples the
    loop does not saturate (two passes); the sum of squares over all samples picks both.
    """
    dt = float(g.t[1] - g.t[0])
    a = g.ax if xdrag is None else g.ax - np.nan_to_num(xdrag)
    ok = g.ok & (np.abs(g.v) > 0.3)
    if known is not None:
        ok &= known
    n = len(g.t)
    idx = np.arange(n)
    scale = np.minimum(1.0, base.v_switch_mps / np.maximum(np.abs(g.v), 1e-3))
    y = a[ok]
    bk = jackknife_blocks(n)[ok]
    n_b = JACKKNIFE_BLOCKS
    sse = np.full((len(SPEED_DELAYS_S), len(SPEED_AMAX_MPS2)), np.inf)
    sse_b = np.zeros((n_b, *sse.shape))
    fits: dict[tuple[int, int], tuple[np.ndarray, np.ndarray, np.ndarray]] = {}
    for i, delay in enumerate(SPEED_DELAYS_S):
        e = (g.cmd_v[np.clip(idx - round(delay / dt), 0, n - 1)] - g.v)[ok]
        grow = ((e > 0) & (g.v[ok] >= 0)) | ((e < 0) & (g.v[ok] <= 0))
        for j, a_max in enumerate(SPEED_AMAX_MPS2):
            lim = a_max * scale[ok]
            k = np.array([base.speed_gain_accel_per_s, base.speed_gain_brake_per_s])
            for _ in range(2):
                use = np.abs(np.where(grow, k[0], k[1]) * e) < 0.9 * lim
                X = np.stack([np.where(grow & use, e, 0.0), np.where(~grow & use, e, 0.0)], 1)
                coef = np.linalg.lstsq(X[use], y[use], rcond=None)[0]
                k = np.where(coef > 0.05, coef, k)
            pred = np.clip(np.where(grow, k[0], k[1]) * e, -lim, lim)
            res = y - pred
            sse[i, j] = float(res @ res)
            sse_b[:, i, j] = np.bincount(bk, res * res, minlength=n_b)[:n_b]
            fits[(i, j)] = (k, X[use], use)
    i, j = np.unravel_index(int(np.argmin(sse)), sse.shape)
    k, X, use = fits[(i, j)]
    delay, a_max = SPEED_DELAYS_S[i], SPEED_AMAX_MPS2[j]
    e_all = g.cmd_v[np.clip(idx - round(delay / dt), 0, n - 1)] - g.v
    grow_all = ((e_all > 0) & (g.v >= 0)) | ((e_all < 0) & (g.v <= 0))
    lim_all = a_max * scale
    pred = np.clip(np.where(grow_all, k[0], k[1]) * e_all, -lim_all, lim_all)
    res = (a - pred)[ok]
    m = len(res)
    s2 = float(res @ res) / max(m - 4, 1) * _n_eff_factor(res)
    cov = s2 * np.linalg.pinv(X.T @ X)
    q = timing_sigma(g, "ax_mps2", "speed_mps", grid=True)  # the delay's floor
    # the gains' jackknife: the final regression (its unsaturated samples) without each
    # block in turn; their systematic term: the gains at the neighbouring delays
    y_use, bk_use = y[use], bk[use]
    k_jack = np.array([np.linalg.lstsq(X[bk_use != b], y_use[bk_use != b], rcond=None)[0]
                       for b in range(n_b)])
    sig_k = jackknife_sigma(k_jack)
    k_at = [fits[(m, j)][0] for m in range(len(SPEED_DELAYS_S))]
    out: dict[str, Estimate] = {}
    curv: dict[str, float] = {}
    sysd: dict[str, float] = {"speed_delay_s": q}
    for c, name in enumerate(("speed_gain_accel_per_s", "speed_gain_brake_per_s")):
        used = int(np.sum(X[:, c] != 0))
        if used < 50:
            out[name] = Estimate(name, getattr(base, name), math.inf, False, "1/s",
                                 f"only {used} unsaturated samples")
        else:
            curv[name] = math.sqrt(max(cov[c, c], 0.0))
            sys_k = sysd[name] = _delay_coupling([float(kk[c]) for kk in k_at], int(i), dt) * q
            out[name] = _estimate(name, float(k[c]), math.hypot(float(sig_k[c]), sys_k),
                                  "1/s")
    d0, sd, interior = _profile_sigma(SPEED_DELAYS_S, sse.min(axis=1), s2)
    curv["speed_delay_s"] = max(sd, dt / math.sqrt(12.0))
    sd = math.hypot(_jack_profile(SPEED_DELAYS_S, sse, sse_b, (1,)), q) if interior \
        else math.inf
    out["speed_delay_s"] = _estimate("speed_delay_s", d0, sd, "s",
                                     "" if interior else "at the edge of the delays tried")
    if sd <= DELAY_SIGMA_MAX_S and interior:  # a delay's relative sigma means little
        out["speed_delay_s"] = Estimate("speed_delay_s", d0, sd, True, "s")
    saturated = ok & (np.abs(np.where(grow_all, k[0], k[1]) * e_all) > lim_all)
    n_sat = int(np.sum(saturated))
    la, sa, interior_a = _profile_sigma(np.log(SPEED_AMAX_MPS2), sse.min(axis=0), s2)
    curv["accel_max_mps2"] = math.exp(la) * sa
    if math.isfinite(sa):
        la_at = [_vertex(np.log(SPEED_AMAX_MPS2), sse[m]) for m in range(len(SPEED_DELAYS_S))]
        sa = math.hypot(_jack_profile(np.log(SPEED_AMAX_MPS2), sse, sse_b, (0,)),
                        _delay_coupling(la_at, int(i), dt) * q)
        sysd["accel_max_mps2"] = math.exp(la) * _delay_coupling(la_at, int(i), dt) * q
    seen = float(np.max(np.abs(a[ok]))) if ok.any() else 0.0
    if n_sat < 20 or not interior_a:
        out["accel_max_mps2"] = Estimate(
            "accel_max_mps2", max(seen, a_max if interior_a else seen), math.inf, False,
            "m/s^2", f"never reached: at least {seen:.2f} m/s^2 seen")
    else:
        out["accel_max_mps2"] = _estimate("accel_max_mps2", math.exp(la), math.exp(la) * sa,
                                          "m/s^2")
    return _with_curvature(out, curv, sysd), a, np.where(ok, pred, np.nan)


# ------------------------------------------------------------------ tyres
def _windows(g: Grid) -> np.ndarray:
    """Start indices of the tyre-fit windows (module docstring), at most MAX_WINDOWS."""
    dt = float(g.t[1] - g.t[0])
    w = round(WINDOW_S / dt)
    good = g.ok & (g.v > MIN_SPEED_MPS)
    starts, k = [], 0
    bad = np.flatnonzero(~good)
    while k + w <= len(g.t):
        nxt = bad[np.searchsorted(bad, k):]
        if len(nxt) and nxt[0] < k + w:
            k = int(nxt[0]) + 1
            continue
        starts.append(k)
        k += w
    starts = np.asarray(starts, dtype=int)
    if len(starts) > MAX_WINDOWS:
        starts = starts[np.linspace(0, len(starts) - 1, MAX_WINDOWS).round().astype(int)]
    return starts


def _params_from(theta: np.ndarray, model: str, base: DynamicVehicleParams
                 ) -> tuple[DynamicVehicleParams, float]:
    """(vehicle, steering offset [rad]) of a parameter vector (logs, then the offset)."""
    x = np.exp(theta[:-1])
    if model == "linear":
        upd = {"cornering_stiffness_front_per_rad": x[0] / base.mu,
               "cornering_stiffness_rear_per_rad": x[1] / base.mu}
    elif model == "linear_saturated":
        upd = {"cornering_stiffness_front_per_rad": x[0],
               "cornering_stiffness_rear_per_rad": x[1], "mu": x[2]}
    else:
        upd = {"mu": 1.0, "pacejka_front": (x[0], x[1], x[2], base.pacejka_front[3]),
               "pacejka_rear": (x[3], x[4], x[5], base.pacejka_rear[3])}
    return base.model_copy(update={"tyre_model": model, **upd}), float(theta[-1])


def _theta0(model: str, base: DynamicVehicleParams) -> np.ndarray:
    if model == "linear":
        x = [base.mu * base.cornering_stiffness_front_per_rad,
             base.mu * base.cornering_stiffness_rear_per_rad]
    elif model == "linear_saturated":
        x = [base.cornering_stiffness_front_per_rad, base.cornering_stiffness_rear_per_rad,
             base.mu]
    else:
        x = [*base.pacejka_front[:3], *base.pacejka_rear[:3]]
    return np.array([*np.log(x), 0.0])


def _bounds(model: str) -> tuple[np.ndarray, np.ndarray]:
    keys = {"linear": "kk", "linear_saturated": ["k", "k", "mu"],
            "pacejka": "BCDBCD"}[model]
    lo = [math.log(_TYRE_BOUNDS[k][0]) for k in keys] + [-0.1]
    hi = [math.log(_TYRE_BOUNDS[k][1]) for k in keys] + [0.1]
    return np.array(lo), np.array(hi)


def _rear_small_slip(p: DynamicVehicleParams) -> float:
    if p.tyre_model == "pacejka":
        b, c, d, _e = p.pacejka_rear
        return p.mu * b * c * d
    return p.mu * p.cornering_stiffness_rear_per_rad


class Lateral(NamedTuple):
    """``simulate_lateral``'s prediction, each (windows, w): at the samples the yaw rate
    [rad/s] and whether an axle is at its friction limit (Pacejka: past 70 % of its peak
    slip); over the grid step that ends at each sample (as the IMU's accelerations: the
    step's midpoint; the first sample at its own instant) the lateral acceleration
    [m/s^2], the tyres' drag on the speed ``v' - a`` and on the body's longitudinal
    acceleration ``F_X / m - a`` [m/s^2] and the acceleration demand ``a`` [m/s^2]."""

    r: np.ndarray
    ay: np.ndarray
    drag: np.ndarray
    xdrag: np.ndarray
    sat: np.ndarray
    demand: np.ndarray


def beta_start(g: Grid, starts: np.ndarray, p: DynamicVehicleParams) -> np.ndarray:
    """The linear model's steady-state slip angle [rad] at each window's start, from the
    measured yaw rate and speed: ``beta = l_r r / v - v r / (g k_r)``."""
    r, v = g.r[starts], g.v[starts]
    return p.lr_m * r / v - v * r / (GRAVITY_MPS2 * _rear_small_slip(p))


def _friction_accel(p: DynamicVehicleParams) -> float:
    """The largest demand [m/s^2] the tyres transmit (``mu_peak g`` of the weaker axle;
    inf for ``linear``), as the simulator clips it."""
    if p.tyre_model == "linear":
        return math.inf
    return min(axle_peak_friction(p, "front"), axle_peak_friction(p, "rear")) * GRAVITY_MPS2


def simulate_lateral(
    g: Grid, starts: np.ndarray, p: DynamicVehicleParams, offset_rad: float,
    solve_demand: bool = True, beta0: np.ndarray | None = None,
) -> Lateral:
    """The single-track model over the windows starting at `starts` (module docstring,
    "Tyres"); `beta0`: each window's initial slip angle [rad] (None: ``beta_start``).

    The IMU's accelerations are means over the step that ends at their stamp, so the
    grid sample ``k + 1`` of ``g.ax`` is the step ``k -> k + 1``'s own: it is that step's
    input (midpoint rule), and the lateral acceleration compared with ``g.ay[k + 1]`` is
    the model's at that step's midpoint. `solve_demand`: the acceleration demand ``a`` of
    each evaluation is the one at which the model's own ``F_X / m`` (the demand plus the
    tyres' drag at that state) equals the measured ``a_x`` (``DEMAND_ITERATIONS`` fixed-
    point steps from the previous evaluation's drag), so the demand follows the tyres
    being fitted; False: the demand is ``a_x`` itself (the drag neglected)."""
    dt = float(g.t[1] - g.t[0])
    w = round(WINDOW_S / dt)
    n = len(g.t)
    idx = starts[:, None] + np.arange(w)[None, :]
    v, d = g.v[idx], g.d[idx] + offset_rad
    ax_step = g.ax[np.minimum(idx + 1, n - 1)]  # column k: the mean over step k -> k + 1
    f = make_dynamic_derivatives(p, NUMPY_OPS, raw=True)
    m, linear = p.mass_kg, p.tyre_model == "linear"
    solve = solve_demand and not linear  # linear: v' = a, F_X / m = a (no drag)
    a_lim = _friction_accel(p)
    r = g.r[idx[:, 0]].copy()
    beta = beta_start(g, starts, p) if beta0 is None else np.asarray(beta0, dtype=float)
    r_out = np.empty_like(v)
    ay_out = np.empty_like(v)
    drag_out = np.empty_like(v)
    xdrag_out = np.zeros_like(v)
    sat_out = np.zeros_like(v, dtype=bool)
    dem_out = np.empty_like(v)
    if p.tyre_model == "pacejka":
        peak_f = pacejka_peak_slip_rad(p, "front")
        peak_r = pacejka_peak_slip_rad(p, "rear")

    def saturated(front: tuple, rear: tuple) -> np.ndarray:
        if linear:
            return np.zeros(len(front[1]), dtype=bool)
        if p.tyre_model == "pacejka":
            return (np.abs(front[3]) > 0.7 * peak_f) | (np.abs(rear[3]) > 0.7 * peak_r)
        return (np.abs(front[1]) >= 0.999 * front[2]) | (np.abs(rear[1]) >= 0.999 * rear[2])

    def lateral(front: tuple, rear: tuple, dk: np.ndarray) -> np.ndarray:
        if linear:
            return (front[1] + rear[1]) / m
        return (front[0] * np.sin(dk) + front[1] * np.cos(dk) + rear[1]) / m

    def body_x(front: tuple, rear: tuple, dk: np.ndarray) -> np.ndarray:
        return (front[0] * np.cos(dk) - front[1] * np.sin(dk) + rear[0]) / m

    xd = np.zeros(len(starts))  # the drag of the last evaluation: the next one's start

    def evaluate(vk: np.ndarray, bk: np.ndarray, rk: np.ndarray, dk: np.ndarray,
                 axk: np.ndarray) -> tuple[tuple, np.ndarray, np.ndarray]:
        """(derivatives, demand, F_X / m - demand) at a state for the measured a_x."""
        if not solve:
            out = f(vk, bk, rk, dk, axk)
            return out, axk, (np.zeros_like(axk) if linear else body_x(out[3], out[4], dk)
                              - axk)
        a = np.clip(axk - xd, -a_lim, a_lim)
        for _ in range(DEMAND_ITERATIONS):
            out = f(vk, bk, rk, dk, a)
            a = np.clip(axk - (body_x(out[3], out[4], dk) - a), -a_lim, a_lim)
        out = f(vk, bk, rk, dk, a)
        return out, a, body_x(out[3], out[4], dk) - a

    for k in range(w):
        # the odometry's wheel speed is v cos(beta): the model's v is the CoG speed
        vk, dk, axk = v[:, k] / np.cos(beta), d[:, k], ax_step[:, k]
        (dv, db, dr, fr, rr), ak, xd = evaluate(vk, beta, r, dk, axk)
        r_out[:, k] = r
        sat_out[:, k] = saturated(fr, rr)
        if k == 0:  # no step ends here: the sample's own instant
            ay_out[:, 0], drag_out[:, 0], xdrag_out[:, 0] = lateral(fr, rr, dk), dv - ak, xd
            dem_out[:, 0] = ak
        if k + 1 < w:
            b_mid = beta + 0.5 * dt * db
            vm = 0.5 * (v[:, k] + v[:, k + 1]) / np.cos(b_mid)
            dm = 0.5 * (dk + d[:, k + 1])
            (dv2, db2, dr2, f2, r2), am, xd = evaluate(vm, b_mid, r + 0.5 * dt * dr, dm, axk)
            ay_out[:, k + 1], drag_out[:, k + 1], xdrag_out[:, k + 1] = (
                lateral(f2, r2, dm), dv2 - am, xd)
            dem_out[:, k + 1] = am
            beta = np.clip(beta + dt * db2, -0.8, 0.8)
            r = np.clip(r + dt * dr2, -20.0, 20.0)
    return Lateral(r_out, ay_out, drag_out, xdrag_out, sat_out, dem_out)


def fit_tyres(
    g: Grid, base: DynamicVehicleParams, model: str, iterations: int = 30,
    solve_demand: bool = True, theta_start: np.ndarray | None = None,
    starts: np.ndarray | None = None, fit_beta0: bool = False,
) -> tuple[dict[str, Estimate], dict[str, np.ndarray], dict[str, Any]]:
    """The tyre parameters of `model` and the steering offset (module docstring); also the
    predicted yaw rate, lateral acceleration and drags on the grid (NaN / 0 outside the
    windows) and whether the tyres' drag is known there (``known``: inside a window, or too
    slow and straight for any). `solve_demand`: the acceleration demand solved from the
    measured a_x with the tyres being fitted (``simulate_lateral``; False: a_x itself);
    `theta_start`: the start of the search (a previous fit's ``info["theta"]``); `starts`:
    the windows (None: ``_windows``); `fit_beta0`: fit each window's initial slip angle too
    (else the linear steady state of the current parameters). ``info["window_rms"]``: each
    window's rms residual (noise units)."""
    if model not in TYRE_PARAMETERS:
        raise SysidError(f"unknown tyre model {model!r} (linear, linear_saturated, pacejka)")
    starts = _windows(g) if starts is None else starts
    dt = float(g.t[1] - g.t[0])
    w = round(WINDOW_S / dt)
    burn = round(BURN_IN_S / dt)
    if len(starts) < 5:
        raise SysidError(f"too little driving above {MIN_SPEED_MPS:g} m/s: {len(starts)} "
                         f"windows of {WINDOW_S:g} s (at least 5 needed to fit the tyres)")
    idx = starts[:, None] + np.arange(burn, w)[None, :]
    r_meas, ay_meas = g.r[idx], g.ay[idx]
    sig_r = max(noise_std(g.r[g.ok]), 0.02)
    sig_ay = max(noise_std(g.ay[g.ok]), 0.1)
    lo, hi = _bounds(model)

    n_s, n_g = w - burn, len(lo)
    n_w = len(starts) if fit_beta0 else 0
    # with fit_beta0 every window's initial slip angle is a parameter too (its columns of
    # the Jacobian come from one simulation: the windows do not interact)
    lo = np.concatenate([lo, np.full(n_w, -0.6)])
    hi = np.concatenate([hi, np.full(n_w, 0.6)])
    rows = np.arange(n_w * n_s).reshape(n_w, n_s)
    win_rows = np.concatenate([rows, rows + n_w * n_s], axis=1)  # (n_w, 2 n_s)

    def residuals(theta: np.ndarray) -> np.ndarray:
        p, off = _params_from(theta[:n_g], model, base)
        pred = simulate_lateral(g, starts, p, off, solve_demand, theta[n_g:] if n_w else None)
        r_p, ay_p = pred.r, pred.ay
        return np.concatenate([((r_p[:, burn:] - r_meas) / sig_r).ravel(),
                               ((ay_p[:, burn:] - ay_meas) / sig_ay).ravel()])

    def jacobian(theta: np.ndarray, res: np.ndarray) -> np.ndarray:
        J = np.zeros((len(res), len(theta)))
        for i in range(n_g):
            th = theta.copy()
            th[i] += steps[i]
            J[:, i] = (residuals(th) - res) / steps[i]
        if n_w:
            th = theta.copy()
            th[n_g:] += BETA0_STEP_RAD
            d = (residuals(th) - res) / BETA0_STEP_RAD
            J[win_rows, n_g + np.arange(n_w)[:, None]] = d[win_rows]
        return J

    theta_g = _theta0(model, base) if theta_start is None else theta_start
    p0, _off0 = _params_from(theta_g, model, base)
    beta0 = beta_start(g, starts, p0) if n_w else np.zeros(0)
    theta = np.clip(np.concatenate([theta_g, beta0]), lo, hi)
    res = residuals(theta)
    cost = float(res @ res)
    lam = 1e-2
    steps = np.full(n_g, 1e-3)
    steps[-1] = 1e-4
    rel = 1.0
    for _it in range(iterations):
        J = jacobian(theta, res)
        JtJ, Jtr = J.T @ J, J.T @ res
        improved = False
        for _ in range(8):
            A = JtJ + lam * np.diag(np.maximum(np.diag(JtJ), 1e-9))
            step = -np.linalg.lstsq(A, Jtr, rcond=None)[0]
            cand = np.clip(theta + step, lo, hi)
            res_c = residuals(cand)
            cost_c = float(res_c @ res_c)
            if np.isfinite(cost_c) and cost_c < cost:
                rel = (cost - cost_c) / cost
                theta, res, cost = cand, res_c, cost_c
                lam = max(lam / 3.0, 1e-7)
                improved = True
                break
            lam *= 4.0
        if not improved or rel < 1e-6:
            break
    J = jacobian(theta, res)  # at the optimum
    n_r = idx.size
    s2 = cost / max(len(res) - len(theta), 1)
    infl = max(_n_eff_factor(res[:n_r]), _n_eff_factor(res[n_r:]))
    cov = s2 * infl * np.linalg.pinv(J.T @ J, rcond=1e-10)
    sig_curv = np.sqrt(np.maximum(np.diag(cov), 0.0))
    cov_jack = _tyre_jackknife_cov(J, res, theta, starts, len(g.t), n_s)
    # the timing floors: each signal shifted by one grid step (measurements: their rows
    # of the residuals; inputs: one simulation each), the fit's linear response scaled
    # to the signal's timing sigma (timing_sigma), the responses independent
    JtJ_pinv = np.linalg.pinv(J.T @ J, rcond=1e-10)
    p_t, off_t = _params_from(theta[:n_g], model, base)
    b0 = theta[n_g:] if n_w else None
    dres: dict[str, np.ndarray] = {
        "yaw_rate_radps": np.concatenate([(g.r[idx] - g.r[idx - 1]).ravel() / sig_r,
                                          np.zeros(idx.size)]),
        "ay_mps2": np.concatenate([np.zeros(idx.size),
                                   (g.ay[idx] - g.ay[idx - 1]).ravel() / sig_ay]),
    }
    for name, fld in (("steering_rad", "d"), ("speed_mps", "v"), ("ax_mps2", "ax")):
        x = getattr(g, fld)
        x_late = np.concatenate([x[:1], x[:-1]])
        pr = simulate_lateral(replace(g, **{fld: x_late}), starts, p_t, off_t, solve_demand,
                              b0)
        dres[name] = np.concatenate([((pr.r[:, burn:] - r_meas) / sig_r).ravel(),
                                     ((pr.ay[:, burn:] - ay_meas) / sig_ay).ravel()]) - res
    cov_sys = np.zeros_like(cov_jack)
    for name, d_res in dres.items():
        dth = -JtJ_pinv @ (J.T @ d_res) * (timing_sigma(g, name) / dt)
        cov_sys += np.outer(dth, dth)
    sig = np.sqrt(np.maximum(np.diag(cov_jack + cov_sys), 0.0))
    sig_sys = np.sqrt(np.maximum(np.diag(cov_sys), 0.0))
    names = TYRE_PARAMETERS[model]
    p_hat, off = _params_from(theta[:n_g], model, base)
    pred = simulate_lateral(g, starts, p_hat, off, solve_demand,
                            theta[n_g:] if n_w else None)
    r_p, ay_p, sat = pred.r, pred.ay, pred.sat
    out: dict[str, Estimate] = {}
    sat_share = float(np.mean(sat[:, burn:]))
    with np.errstate(invalid="ignore", divide="ignore"):
        corr = cov / np.outer(sig_curv, sig_curv)  # the curvature's shape: B against C
    for i, name in enumerate(names):
        val = float(math.exp(theta[i]))
        sigma = val * float(sig[i]) if np.isfinite(sig[i]) else math.inf
        note = ""
        if theta[i] <= lo[i] + 1e-9 or theta[i] >= hi[i] - 1e-9:
            note = "at its search bound"
        elif (name == "mu" or name.endswith("_D")) and sat_share < 0.005:
            note = f"{FRICTION_UNUSED} ({100 * sat_share:.1f} % of the samples at it)"
        elif name[-2:] in ("_B", "_C"):
            j = i + 1 if name.endswith("_B") else i - 1  # its partner C or B
            rho = float(abs(corr[i, j]))
            if rho > BC_CORRELATION_MAX:
                note = f"{PRODUCT_ONLY} (correlation of B and C {rho:.2f})"
        out[name] = _estimate(name, val, sigma, "1/rad" if "stiffness" in name else "", note)
    s_off = float(sig[n_g - 1])
    out["steering_offset_rad"] = Estimate("steering_offset_rad", off, s_off, s_off < 0.01,
                                          "rad", "" if s_off < 0.01 else "not resolved")
    curv = {name: math.exp(theta[i]) * float(sig_curv[i]) for i, name in enumerate(names)}
    curv["steering_offset_rad"] = float(sig_curv[n_g - 1])
    sysd = {name: math.exp(theta[i]) * float(sig_sys[i]) for i, name in enumerate(names)}
    sysd["steering_offset_rad"] = float(sig_sys[n_g - 1])
    out = _with_curvature(out, curv, sysd)
    r_full = np.full(len(g.t), np.nan)
    ay_full = np.full(len(g.t), np.nan)
    full = starts[:, None] + np.arange(burn, w)[None, :]
    r_full[full] = r_p[:, burn:]
    ay_full[full] = ay_p[:, burn:]
    known = (np.abs(g.v) < MIN_SPEED_MPS) & (np.abs(g.ay) < CORNER_AY_MPS2)
    known[full] = True
    drag_full = np.zeros(len(g.t))
    drag_full[full] = pred.drag[:, burn:]
    xdrag_full = np.zeros(len(g.t))
    xdrag_full[full] = pred.xdrag[:, burn:]
    info = {"windows": len(starts), "rms_yaw_rate_radps": float(np.sqrt(np.mean(
        (r_p[:, burn:] - r_meas) ** 2))), "rms_ay_mps2": float(np.sqrt(np.mean(
            (ay_p[:, burn:] - ay_meas) ** 2))), "noise_yaw_rate_radps": sig_r,
            "noise_ay_mps2": sig_ay, "at_friction_limit_share": sat_share,
            "theta": theta[:n_g], "starts": starts, "window_rms": np.sqrt(np.mean(
                (((r_p[:, burn:] - r_meas) / sig_r) ** 2 + ((ay_p[:, burn:] - ay_meas)
                                                             / sig_ay) ** 2) / 2, axis=1))}
    return out, {"yaw_rate": r_full, "ay": ay_full, "drag": drag_full,
                 "xdrag": xdrag_full, "known": known}, info


def _tyre_jackknife_cov(J: np.ndarray, res: np.ndarray, theta: np.ndarray,
                        starts: np.ndarray, n_grid: int, n_s: int) -> np.ndarray:
    """Delete-one-block jackknife covariance of the tyre fit's `theta`, linearised: the
    windows grouped by the block (``jackknife_blocks`` of the grid's `n_grid` samples) of
    their start; without block g, one Gauss-Newton step from `theta` on the other windows'
    rows of `J` / `res` (rows: yaw rate then lateral acceleration, each window's `n_s`
    scored samples in turn), ``theta_g = theta - (J_-g' J_-g)^+ J_-g' r_-g``; the
    covariance ``(G - 1) / G sum_g (theta_g - mean)(theta_g - mean)'`` over the blocks
    that hold windows. No refit: the windows' simulations are already in `J`."""
    n_w = len(starts)
    win_block = jackknife_blocks(n_grid)[starts]
    row_block = np.tile(np.repeat(win_block, n_s), 2)
    if len(row_block) != len(res) or n_w == 0:
        return np.full((len(theta), len(theta)), np.inf)
    reps = []
    for b in np.unique(win_block):
        keep = row_block != b
        Jk, rk = J[keep], res[keep]
        reps.append(theta - np.linalg.pinv(Jk.T @ Jk, rcond=1e-10) @ (Jk.T @ rk))
    reps_a = np.array(reps)
    if len(reps_a) < 2:
        return np.full((len(theta), len(theta)), np.inf)
    d = reps_a - reps_a.mean(axis=0)
    return (len(reps_a) - 1) / len(reps_a) * d.T @ d


# ------------------------------------------------------------------ all together
def identify(signals: Mapping[str, Any], base: DynamicVehicleParams,
             model: str = "linear_saturated") -> SysidResult:
    """Identify the steering, the speed loop and the tyres of `model` from a run's
    `signals` (``SIGNALS``), geometry and mass from `base` (module docstring).

    Raises:
        SysidError: one line naming what the run lacks.
    """
    if model not in TYRE_PARAMETERS:
        raise SysidError(f"unknown tyre model {model!r} (linear, linear_saturated, pacejka)")
    g = resample(signals)
    check_cornering(g)
    est: dict[str, Estimate] = {}
    steer, d_pred = fit_steering(g, base)
    # pass 1 with the measured a_x as the demand (the tyres' drag neglected: a start that
    # does not depend on the tyres), pass 2 from there with the demand solved inside the
    # simulation for the tyres being fitted (the load transfer and the friction ellipse
    # follow it), without the windows pass 1 fits worst (spins, recoveries: rms over
    # OUTLIER_RMS x the median)
    _t, _lat1, info1 = fit_tyres(g, base, model, solve_demand=False)
    rms = info1["window_rms"]
    keep = info1["starts"][rms <= OUTLIER_RMS * np.median(rms)]
    tyres, lat_pred, info = fit_tyres(g, base, model, PASS2_ITERATIONS, True,
                                      info1["theta"], keep)
    info["windows_dropped"] = len(rms) - len(keep)
    for k in ("theta", "starts", "window_rms"):
        info.pop(k)
    speed, a_meas, a_pred = fit_speed(g, base, lat_pred["xdrag"], lat_pred["known"])
    est.update(steer)
    est.update(speed)
    est.update(tyres)
    curves = {
        "steering_rad": (g.d, d_pred),
        "accel_mps2": (a_meas, a_pred),
        "yaw_rate_radps": (g.r, lat_pred["yaw_rate"]),
        "ay_mps2": (g.ay, lat_pred["ay"]),
    }
    return SysidResult(model, est, float(g.t[-1] - g.t[0]), g.t - g.t[0], curves, info)
