"""The CiMPCC / MPCC planner: one solve per tick, warm started, never an unsafe command.

``Planner.step(x, y, yaw)`` projects the car onto the track, sets beta (paper eq. 11: once at
the car's position, or per predicted stage), solves the problem built once by
``problem.build_problem`` and returns a ``SolveResult``. A failed solve falls back to the
previous plan shifted by one step; ``max_consecutive_failures`` failures in a row give a
braking command (speed 0). Commands are always finite and inside the input bounds.

Methods (``shared.config.methods``; the planner reads only the resolved ``MethodSetup``):
the paper's ``cimpcc`` and ``mpcc`` contour the track's centreline. A method whose spec
follows the minimum-time line (``cimpcc-line``) contours the car's minimum-time line with the
same problem builder: its velocity pulls (paper eq. 11) take beta = 1 and ``v_up,k`` = the
minimum-time profile's speed command at each stage's predicted progress; its model may have
the car's steady-state tyre slip (``model.SlipModel``) and speed loop; and it may plan from
the pose predicted ``lead_s`` ahead with the acting command (the actuation and steering
delays). On a line that is not the centreline the car is projected twice: onto the track
(the result's ``s_m`` and ``e_con_m``, the off-track cap and the recovery rule, as for every
method) and onto the line (the problem's progress).

Latency: only what needs the new pose runs between the pose and the command (projection,
aligning the warm start, the solve). ``Planner.prepare()`` does the rest of the next tick's
work ahead of time (the previous plan shifted and extrapolated, per-stage beta); a service
calls it after publishing, ``step`` calls it itself when nobody did. ``step(...,
on_command=f)`` hands the command to ``f`` before the result record is assembled.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass

import casadi as ca
import numpy as np

from services.planner.interface import (
    BRAKING,
    FALLBACK,
    RECOVERING,
    SOLVED,
    DriveCommand,
    SolveResult,
)
from services.planner.mintime.model import friction_circle_mps2, servo_reach
from services.planner.mintime.requests import line_request
from services.planner.mintime.store import load_min_time_lap
from services.planner.mpc.model import NU, NX, S, Servo, SlipModel, SpeedLoop, U, discretise
from services.planner.mpc.problem import UA, XA, XA_SERVO, XA_SPEED, OcpProblem, build_problem
from services.planner.mpc.solver import SolverHandle, make_solver
from services.planner.recovery import (
    TELEPORT_JUMP_M,
    HandOver,
    Recovery,
    RecoveryCommand,
    StallWatch,
    handover_accel_mps2,
    ramps_from_rest,
)
from services.planner.reference import ReferencePath, centreline_path, min_time_path
from shared.angles import wrap_angle
from shared.config.methods import CIMPCC_LINE, MethodSetup, method_setup
from shared.config.planner import (
    CurvatureSettings,
    MethodWeights,
    PlannerSettings,
    SolverSettings,
)
from shared.config.vehicle import F1TENTH_GYM, DynamicVehicleParams
from shared.curvature import CurvatureProfile, track_profile
from shared.track import Track

#: Half-width of the arc-length window searched around the previous projection when the
#: nearby search (``Track.project_near``, +-1 m) finds its minimum at its edge [m]
#: (0.5 s at 10 m/s).
PROJECTION_WINDOW_M = 5.0
#: Speed [m/s] of the rollout that seeds the very first solve.
INITIAL_GUESS_SPEED_MPS = 1.0
#: Below the cap, the speed over which the speed command's lead for the tyres' drag fades out
#: [m/s] (``Planner._command_limit``).
COMMAND_CAP_FADE_MPS = 0.05
#: ... ending this far above the cap [m/s] (the rule counts a car over it by 1 %, 0.04 m/s
#: at 4.18; faded out below the cap, the car kept 4.175 m/s and lost 0.7 % on map416).
COMMAND_CAP_OVER_MPS = 0.02
#: The least share of the traction budget left to the drive however hard the plan corners
#: (``Planner._traction_cap``).
TRACTION_FLOOR_SHARE = 0.1
#: Half-width [m] of the search on the line around the hint from the track's progress.
LINE_HINT_WINDOW_M = 2.0


def problem_settings(settings: PlannerSettings, method: str) -> PlannerSettings:
    """The settings that fix the structure of `method`'s problem (its own N and integrator
    when its spec has its own structure; else `settings`)."""
    return method_setup(settings, method).structure


def solver_settings(settings: PlannerSettings, method: str) -> SolverSettings:
    """The solver settings of `method` (its own tolerances laid over ``[planner.solver]``
    when its spec has its own structure; else ``[planner.solver]``)."""
    return method_setup(settings, method).solver


def min_time_reference(
    track: Track,
    settings: PlannerSettings,
    vehicle: DynamicVehicleParams | None = None,
    cache_dir: str | None = None,
) -> ReferencePath:
    """The ``cimpcc-line`` reference: the minimum-time line of `vehicle` on `track`.

    The lap (``mintime.requests.line_request``: the car, default the F1TENTH gym's, with
    its friction ``mu`` times ``grip_fraction``, its steering within the planner's bounds,
    top speed ``v_max_mps`` and footprint margin ``line_margin_m``, all
    ``settings.cimpcc_line``) is read from the cache in `cache_dir` (default the solver
    cache's; ``mintime.store.load_min_time_lap``: never solved here, the tools make it,
    ``mintime.store.ensure_artefacts``); then ``reference.min_time_path`` with the speed
    loop's lead times (default: ``1 / speed_gain_accel_per_s`` and ``1 /
    speed_gain_brake_per_s`` of the car).

    Raises:
        MinTimeArtefactMissingError: the lap is not in the cache (names the command).
    """
    car = vehicle or F1TENTH_GYM
    line = settings.cimpcc_line
    lap = load_min_time_lap(track, *line_request(settings, car), cache_dir, use=CIMPCC_LINE)
    accel_lead = line.accel_lead_s
    brake_lead = line.brake_lead_s
    return min_time_path(
        track,
        lap,
        car.lr_m,
        1.0 / car.speed_gain_accel_per_s if accel_lead is None else accel_lead,
        1.0 / car.speed_gain_brake_per_s if brake_lead is None else brake_lead,
    )


def method_reference(
    track: Track, setup: MethodSetup, vehicle: DynamicVehicleParams | None = None
) -> ReferencePath:
    """The path an MPC method contours: the centreline, or the minimum-time line of
    `vehicle` (``min_time_reference``)."""
    if setup.spec.reference == "min_time_line":
        return min_time_reference(track, setup.structure, vehicle)
    return centreline_path(track)


def method_problem(
    reference: ReferencePath, setup: MethodSetup, vehicle: DynamicVehicleParams | None = None
) -> OcpProblem:
    """The MPC problem of a method on `reference`: its model (the paper's kinematic bicycle,
    or with the tyre slip of `vehicle`, or also its speed loop, and its servo when that is
    slow, ``model_servo``), structure and layout."""
    car = vehicle or F1TENTH_GYM
    slip = speed_loop = None
    if setup.model != "kinematic":
        slip = SlipModel.for_vehicle(car, near_limit=setup.has_speed_state)
    if setup.has_speed_state:
        speed_loop = SpeedLoop.for_vehicle(car)
    return build_problem(
        reference, setup.structure, slip, speed_loop, setup.speed_cap_mps, lifted=setup.lifted,
        servo=model_servo(setup, car),
    )


def model_servo(setup: MethodSetup, vehicle: DynamicVehicleParams) -> Servo | None:
    """The servo a method's model holds as a state: `vehicle`'s, for a model with the car's
    speed whose method asks for it (``[planner.cimpcc_line] servo_state``), when the servo is
    slow enough for its reach to bound the steering (``mintime.model.servo_reach``: the
    identified car's 0.158 s; the gym car's 0.01 s servo is left out); else None."""
    if not (setup.has_speed_state and setup.servo_state) or servo_reach(vehicle) is None:
        return None
    return Servo.for_vehicle(vehicle)


@dataclass
class _Prepared:
    """The next tick's measurement-independent work (see ``Planner.prepare``).

    Attributes:
        w: (n_w,) the decision vector of the previous solution shifted one stage, its last
            stage extrapolated with the model, slack zeroed (progress and heading not yet
            aligned with the next pose).
        beta: (N,) per-stage beta at the shifted progress, or None (beta at the car only).
        v_ref: (N, 2) per-stage velocity reference [v_l, v_p] [m/s] at the shifted
            progress (paths with a speed profile), else None.
        drag: (N,) per-stage drag [m/s^2] (a model with the car's speed), else None.
    """

    w: np.ndarray
    beta: np.ndarray | None
    v_ref: np.ndarray | None = None
    drag: np.ndarray | None = None


class Planner:
    """One planner instance: problem and solver built once, per-tick solve with warm start."""

    def __init__(
        self,
        track: Track,
        settings: PlannerSettings,
        curvature: CurvatureSettings | None = None,
        *,
        method: str | None = None,
        weights: MethodWeights | None = None,
        timer: Callable[[], float] = time.perf_counter,
        problem: OcpProblem | None = None,
        solver: SolverHandle | None = None,
        reference: ReferencePath | None = None,
        vehicle: DynamicVehicleParams | None = None,
    ) -> None:
        """Build (or reuse) the problem and solver.

        Args:
            track: the track to race.
            settings: planner settings.
            curvature: curvature-mapping settings (default: the paper's).
            method: an MPC method of the registry (``shared.config.methods``; default
                settings.method); its spec decides the line, model, structure, solver
                settings and pose lead (``MethodSetup``).
            weights: explicit weights (overrides the method's; e.g. a tuned MPCC).
            timer: clock for solve-time measurement [s].
            problem, solver: an already built pair to share between planners on one track
                (the problem's reference path is then the planner's).
            reference: the path to contour (default: the method's, ``method_reference``).
            vehicle: the car the minimum-time line is solved for and whose tyre slip and
                speed loop the model has (default the F1TENTH gym's, the
                default ``[vehicle]``); unused by the paper's kinematic methods.
        """
        self.track = track
        self.settings = settings
        setup = method_setup(settings, method)
        #: what the method is built from (its spec resolved against `settings`)
        self.setup: MethodSetup = setup
        self.method = setup.spec.name
        self.weights = weights or settings.weights(self.method)
        curvature = curvature or CurvatureSettings()
        self.profile: CurvatureProfile = track_profile(track, curvature)
        car = vehicle or F1TENTH_GYM
        if problem is None:
            if reference is None:
                reference = method_reference(track, setup, car)
            problem = method_problem(reference, setup, car)
        self.problem = problem
        #: the car's speed loop of a model that holds the car's speed (None: no speed state)
        self._speed_loop = SpeedLoop.for_vehicle(car) if problem.has_speed else None
        #: the car's servo of a model that holds the wheels' angle (None: no servo state)
        self._servo = Servo.for_vehicle(car) if problem.has_servo else None
        self._model_index = np.array(problem.model_index)
        #: what the problem contours; its progress is the problem's s
        self.reference: ReferencePath = problem.reference
        self.path: Track = self.reference.path
        if setup.spec.reference == "min_time_line" and self.reference.speed is None:
            raise ValueError(f"{self.method} needs a reference path with a speed profile")
        self.solver = solver or make_solver(self.problem, setup.solver)
        lead = setup.lead_s
        #: the model over the pose lead, ``F(x, u)`` (None: no lead)
        self._lead = discretise(problem.dynamics, lead, "rk4") if lead > 0 else None
        self._timer = timer
        b = settings.bounds
        self._u_lo = np.array([b.v_l_mps[0], b.delta_rad[0], b.v_p_mps[0]])
        self._u_hi = np.array([b.v_l_mps[1], b.delta_rad[1], b.v_p_mps[1]])
        self._slack_w = (settings.slack_weight_linear, settings.slack_weight_quadratic)
        pr = self.problem
        # constant solver arguments, converted once
        self._bounds = {
            "lbx": ca.DM(pr.lbw),
            "ubx": ca.DM(pr.ubw),
            "lbg": ca.DM(pr.lbg),
            "ubg": ca.DM(pr.ubg),
        }
        self._p_cache: tuple[MethodWeights, np.ndarray] | None = None
        # where progress and heading of every stage, and xa_0, sit in the decision vector
        self._w_progress = np.array([pr.state_index(k).start for k in range(pr.horizon + 1)])
        self._w_phi = self._w_progress + XA.PHI
        self._w_progress += XA.PROGRESS
        self._w_first = pr.state_index(0)
        #: (w_right, w_left) [m] of the narrowest section (the off-track check's shortcut)
        self._narrowest = (float(np.min(track.w_right_m)), float(np.min(track.w_left_m)))
        self.recovery = Recovery(
            track, settings.recovery, settings.wheelbase_m, min(-b.delta_rad[0], b.delta_rad[1])
        )
        self._stall = StallWatch()
        line = setup.spec.reference == "min_time_line"
        #: the near-limit method's start: ramped from rest for peaky tyres (recovery.py)
        self._ramp_start = line and ramps_from_rest(car)
        self._handover = HandOver(handover_accel_mps2(car) if line else car.accel_max_mps2)
        #: a slow servo's time constant [s] whose lag the command inverts (None: no lead;
        #: only on the minimum-time line, the paper's methods stay as they are; a model
        #: with the servo as a state plans the servo's target itself)
        self._servo_tau = servo_reach(car) if line and self._servo is None else None
        #: the speed command's cap [m/s] beside the drag's lead (None: none; ``_command_cap``)
        self._command_cap = (
            setup.speed_cap_mps
            if problem.has_speed and settings.cimpcc_line.cap_command
            else None
        )
        #: the speed command's traction budget [m/s^2] (None: no cap; ``_traction_cap``)
        own = settings.cimpcc_line
        frac = own.traction_fraction if car.tyre_model == "pacejka" else own.traction_fraction_gym
        self._traction_mps2 = (
            frac * friction_circle_mps2(car)
            if line and problem.has_speed and frac is not None
            else None
        )
        self.reset()

    # ------------------------------------------------------------------ lifecycle
    def reset(self) -> None:
        """Forget the previous plan (next step starts cold)."""
        self._w_prev: np.ndarray | None = None
        self._s_prev: float | None = None
        self._s_path_prev: float | None = None  #: the last progress on the line
        self._u_applied = np.zeros(NU)
        self._failures = 0
        self._prepared: _Prepared | None = None
        self._stall.reset()
        self._handover.active = False
        if self._ramp_start:
            self._handover.start(0.0)
        self._drove = False  #: the last tick's command was the method's own (solved)
        self._pose_prev: tuple[float, float, float] | None = None
        self._v_est = 0.0  #: the car's estimated speed at the last pose [m/s] (speed model)
        self._delta_est = 0.0  #: the wheels' estimated angle at the last pose [rad] (servo)
        self._last_xy: tuple[float, float] | None = None  #: the last pose's position [m]
        self.recovery.reset()

    @property
    def horizon(self) -> int:
        """N."""
        return self.problem.horizon

    # ------------------------------------------------------------------ one tick
    def prepare(self) -> None:
        """Do the next tick's work that needs no new pose, now (e.g. after publishing).

        Shifts the last solution by one stage, extrapolates its last stage with the model
        and (``beta_mode = "per_stage"``) evaluates beta along it, or (a path with a speed
        profile) the velocity references. Idempotent; ``step`` calls it when it was not
        called since the last solve.
        """
        if self._prepared is not None or self._w_prev is None:
            return
        pr = self.problem
        xs_prev, us_prev = pr.unpack(self._w_prev)
        xs = np.vstack([xs_prev[1:], xs_prev[-1:]])
        us = np.vstack([us_prev[1:], us_prev[-1:]])
        mi = self._model_index
        xs[-1, mi] = np.asarray(pr.step(xs[-2, mi], us[-1, :NU])).reshape(-1)
        xs[-1, NX : NX + NU] = us[-1, :NU]
        us[:, UA.SLACK] = 0.0
        beta = v_ref = drag = None
        if self.reference.speed is not None:  # periodic in s: no lap alignment needed
            beta, v_ref, drag = self._speed_refs(xs[:, XA.PROGRESS])
        elif self.settings.beta_mode == "per_stage":
            beta = np.asarray(self.profile.beta_at(xs[: pr.horizon, XA.PROGRESS]), dtype=float)
        self._prepared = _Prepared(pr.pack(xs, us), beta, v_ref, drag)

    def step(
        self,
        x_m: float,
        y_m: float,
        yaw_rad: float,
        on_command: Callable[[DriveCommand], None] | None = None,
    ) -> SolveResult:
        """Plan from the car's pose (rear axle [m], yaw [rad]); see the module docstring.

        Args:
            x_m, y_m, yaw_rad: the pose.
            on_command: called with the command as soon as it is known, before the result
                record is assembled (a service publishes it there); exceptions propagate.
        """
        pr = self.problem
        N = pr.horizon
        if not all(math.isfinite(v) for v in (x_m, y_m, yaw_rad)):
            return self._failed(
                np.zeros(NU + 1), 0.0, 0.0, "non-finite pose", 0, 0.0, None, on_command
            )
        last, self._last_xy = self._last_xy, (x_m, y_m)
        if last is not None and math.hypot(x_m - last[0], y_m - last[1]) > TELEPORT_JUMP_M:
            self._relocate()
        if self._s_prev is None:
            s0, e0 = (float(v) for v in self.track.project(np.array([x_m, y_m])))
        else:  # near the last projection, falling back to PROJECTION_WINDOW_M and beyond
            s0, e0 = self.track.project_near(
                x_m, y_m, self._s_prev, fallback_window_m=PROJECTION_WINDOW_M
            )
        self._s_prev = s0
        x0 = np.empty(pr.nxa)
        x0[XA.X], x0[XA.Y], x0[XA.PHI], x0[XA.PROGRESS] = x_m, y_m, yaw_rad, s0
        x0[XA.V_L_PREV : XA.V_P_PREV + 1] = self._u_applied
        if self._speed_loop is not None:
            x0[XA_SPEED] = self._estimate_speed(x_m, y_m, yaw_rad)
        if self._servo is not None:  # the wheels after a period of the last target
            self._delta_est = self._servo.advance(
                self._delta_est, float(self._u_applied[U.DELTA]), self.settings.dt_s
            )
            x0[XA_SERVO] = self._delta_est
        was_recovering = self.recovery.active
        stalled = self._stall.update(x_m, y_m, self.settings.dt_s, counts=self._drove)
        self._drove = False
        rec = self.recovery.update(x_m, y_m, yaw_rad, s0, e0, stalled)
        if rec is not None:
            self._stall.reset()
            s0 = x0[XA.PROGRESS] = self._s_prev = self.recovery.s_m
            self._s_path_prev = None
            return self._recovering(x0, s0, e0, rec, on_command)
        if was_recovering:  # resume where the rule brought the car back, at its speed
            self._handover.start(float(self._u_applied[U.V_L]))
            s0, e0 = (float(v) for v in self.track.project(
                np.array([x_m, y_m]), s_hint=self.recovery.s_m, window_m=1.0))
            x0[XA.PROGRESS] = self._s_prev = s0
        if not self.reference.is_centreline:
            if self._lead is not None:  # the pose when this plan's first input acts
                mi = self._model_index
                x0[mi] = np.asarray(self._lead(x0[mi], self._u_applied)).reshape(-1)
            x0[XA.PROGRESS] = self._path_progress(float(x0[XA.X]), float(x0[XA.Y]), s0)

        self.prepare()
        prep, self._prepared = self._prepared, None
        v_ref = drag = None
        if prep is None:
            xs_ws, us_ws = self._cold_guess(x0)
            w0, beta, s_pred = pr.pack(xs_ws, us_ws), None, xs_ws[:, XA.PROGRESS]
        else:
            w0, beta, s_pred = self._align(prep.w, x0), prep.beta, None
            v_ref, drag = prep.v_ref, prep.drag
        if self.reference.speed is not None and v_ref is None:
            beta, v_ref, drag = self._speed_refs(s_pred)
        if beta is None:
            beta = self._beta(s0, None if s_pred is None else s_pred[:N])
        p = self._parameters(x0, beta, v_ref, drag)

        t0 = self._timer()
        try:
            sol = self.solver.solve(x0=w0, p=p, **self._bounds)
            stats = self.solver.solve.stats()
            w = np.asarray(sol["x"], dtype=float).reshape(-1)
            ok = bool(stats.get("success", False)) and bool(np.all(np.isfinite(w)))
            status_text = str(stats.get("return_status", "unknown"))
            iters = int(stats.get("iter_count", -1))
        except RuntimeError as exc:  # CasADi raises on evaluation errors
            w, ok, status_text, iters = None, False, f"error: {exc}", 0
        solve_time = self._timer() - t0

        if not ok:
            return self._failed(x0, s0, e0, status_text, iters, solve_time, beta, on_command)
        self._failures = 0
        self._w_prev = w
        u0 = np.clip(w[pr.input_index(0)][:NU], self._u_lo, self._u_hi)
        if self._handover.active:  # ramp up from the car's speed after a recovery
            u0[U.V_L] = self._handover.cap(float(u0[U.V_L]), self.settings.dt_s)
        if self._traction_mps2 is not None:
            u0[U.V_L] = self._traction_cap(float(u0[U.V_L]), float(x0[XA_SPEED]), w)
        if self._command_cap is not None:
            u0[U.V_L] = min(float(u0[U.V_L]), self._command_limit(drag, float(x0[XA_SPEED])))
        self._u_applied = u0
        speed, limited = self._safe_speed(float(u0[U.V_L]), s0, e0)
        self._drove = True
        command = DriveCommand(speed, self._servo_lead(u0, w))
        if on_command is not None:
            on_command(command)
        xs, us = pr.unpack(w)
        return SolveResult(
            command=command,
            states=xs[:, : len(S)].copy(),
            inputs=us[:, :NU].copy(),
            status=SOLVED,
            solver_status=status_text,
            iterations=iters,
            solve_time_s=solve_time,
            beta=np.asarray(beta, dtype=float).copy(),
            s_m=s0,
            e_con_m=e0,
            consecutive_failures=0,
            method=self.method,
            speed_limited=limited,
        )

    # ------------------------------------------------------------------ helpers
    def _command_limit(self, drag: np.ndarray | None, v: float) -> float:
        """The largest speed command [m/s] that keeps the car at the cap, at the car's
        speed `v` [m/s] (the model's, stage 0, when the command acts).

        Two leads over the cap ``c``: the command under which the speed loop (gain k_a)
        brings the car from `v` just to the cap in one period Ts, ``(c - v e) / (1 - e)``
        with ``e = exp(-k_a Ts)`` (so it still speeds up as fast as it can below the cap),
        plus what the loop needs to hold the car against the reference lap's tyre drag at
        stage 0, ``drag_0 / k_a``, that lead faded out over ``COMMAND_CAP_FADE_MPS`` up to
        ``COMMAND_CAP_OVER_MPS`` above the cap (the car's own drag may be less than the
        line's: with the whole lead it went to 4.23 m/s in map416's fast bend). At the cap
        the command is the cap, and the loop never passes its command.
        """
        assert self._command_cap is not None and self._speed_loop is not None
        cap = self._command_cap
        k_a = self._speed_loop.gain_accel_per_s
        e = math.exp(-k_a * self.settings.dt_s)
        reach = (cap - v * e) / (1.0 - e) if v < cap else cap
        d0 = 0.0 if drag is None else max(float(drag[0]), 0.0)
        fade = min(max((cap + COMMAND_CAP_OVER_MPS - v) / COMMAND_CAP_FADE_MPS, 0.0), 1.0)
        return reach + fade * d0 / k_a

    def _traction_cap(self, v_cmd: float, v: float, w: np.ndarray) -> float:
        """The speed command [m/s] within the traction budget (``traction_fraction`` for
        Pacejka tyres, ``traction_fraction_gym`` for the gym's).

        The plan's lateral acceleration over its first step, ``a_y = v psi'`` (``psi'``
        the heading change from stage 0 to 1 over Ts), leaves ``a_x = sqrt(A^2 - a_y^2)``
        of the budget ``A`` (``traction_fraction`` of the friction circle) to the drive
        (at least ``TRACTION_FLOOR_SHARE`` of ``A``); the speed loop accelerates by ``k_a
        (v_cmd - v)``, so the command is at most ``v + a_x / k_a`` [m/s] (`v`: the model's
        speed at stage 0).
        Braking is not capped.
        """
        assert self._traction_mps2 is not None and self._speed_loop is not None
        if v_cmd <= v:
            return v_cmd
        pr = self.problem
        phi0 = float(w[pr.state_index(0)][XA.PHI])
        phi1 = float(w[pr.state_index(1)][XA.PHI])
        a_y = abs(v * wrap_angle(phi1 - phi0) / self.settings.dt_s)
        budget = self._traction_mps2
        a_x = math.sqrt(max(budget**2 - a_y**2, (TRACTION_FLOOR_SHARE * budget) ** 2))
        return min(v_cmd, v + a_x / self._speed_loop.gain_accel_per_s)

    def _servo_lead(self, u0: np.ndarray, w: np.ndarray) -> float:
        """The steering command [rad]: the plan's first steering, led by a slow servo's lag.

        The simulator's servo follows its target with ``d(delta)/dt = (target - delta) /
        tau``; the model steers at once. With ``tau`` (``servo_reach``) the target is
        ``delta_0 + tau (delta_1 - delta_0) / dt`` (the plan's first two stages), within the
        steering bounds, so that the wheels move as planned instead of ``tau`` late.
        """
        delta0 = float(u0[U.DELTA])
        if self._servo_tau is None or self.problem.horizon < 2:
            return delta0
        delta1 = float(w[self.problem.input_index(1)][U.DELTA])
        lead = delta0 + self._servo_tau * (delta1 - delta0) / self.settings.dt_s
        return float(np.clip(lead, self._u_lo[U.DELTA], self._u_hi[U.DELTA]))

    def _relocate(self) -> None:
        """The car was moved (``TELEPORT_JUMP_M``): forget where it was and what it did (the
        next solve starts cold from a search of the whole track, the recovery rule lets go),
        keeping the run's counts."""
        self._s_prev = self._s_path_prev = None
        self._w_prev = None
        self._prepared = None
        self._pose_prev = None
        self._v_est = 0.0
        self._delta_est = 0.0
        self._u_applied = np.zeros(NU)
        self._failures = 0
        self._stall.reset()
        self._handover.active = False
        self._drove = False
        self.recovery.active = False

    def _recovering(
        self,
        x0: np.ndarray,
        s0: float,
        e0: float,
        rec: RecoveryCommand,
        on_command: Callable[[DriveCommand], None] | None,
    ) -> SolveResult:
        """The recovery rule's command; the method starts cold once the car is back."""
        self._w_prev = None
        self._prepared = None
        self._failures = 0
        self._u_applied = np.array([rec.speed_mps, rec.steering_rad, rec.speed_mps])
        command = DriveCommand(rec.speed_mps, rec.steering_rad)
        if on_command is not None:
            on_command(command)
        N = self.horizon
        us = np.zeros((N, NU))
        us[0] = self._u_applied
        return SolveResult(
            command=command,
            states=np.tile(x0[: len(S)], (N + 1, 1)),
            inputs=us,
            status=RECOVERING,
            solver_status=f"recovery: {rec.reason}",
            iterations=0,
            solve_time_s=0.0,
            beta=np.full(N, float(self.profile.beta_at(s0))),
            s_m=s0,
            e_con_m=e0,
            consecutive_failures=0,
            method=self.method,
            speed_limited=True,
        )

    def _safe_speed(self, speed: float, s0: float, e0: float) -> tuple[float, bool]:
        """Cap |speed| at off_track_speed_mps while the car is outside the track boundaries.

        The kinematic model knows no tyre limit, so from outside the track it would ask for
        ever more speed to get back sooner; a real car would slide further. Not part of the
        paper's method; applies to every method alike.
        """
        cap = self.settings.off_track_speed_mps
        if abs(speed) <= cap or -self._narrowest[1] <= e0 <= self._narrowest[0]:
            return speed, False  # inside even the narrowest section: no lookup needed
        w_r, w_l = self.track.interp_width(s0)
        if e0 > float(w_r) or e0 < -float(w_l):
            return float(np.clip(speed, -cap, cap)), True
        return speed, False

    def _path_progress(self, x_m: float, y_m: float, s_track: float) -> float:
        """The car's progress [m] on the reference path (not the centreline): near the last
        one, or (cold, after recovery) near the path point that matches the track's
        progress `s_track` [m], so a line that passes close to another stretch of itself
        cannot capture the car."""
        if self._s_path_prev is None:
            hint = self.reference.path_s_near(s_track, self.track.length_m)
            s, _ = self.path.project(np.array([x_m, y_m]), s_hint=hint,
                                     window_m=LINE_HINT_WINDOW_M)
            s = float(s)
        else:
            s, _ = self.path.project_near(
                x_m, y_m, self._s_path_prev, fallback_window_m=PROJECTION_WINDOW_M
            )
        self._s_path_prev = s
        return s

    def _speed_refs(
        self, s_pred: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
        """(beta (N,), v_ref (N, 2), drag (N,) or None) of a path with a speed profile
        from the predicted progress of the N+1 stages `s_pred` [m]: beta = 1 and both
        speeds [v_l, v_p] [m/s] the profile's command at stage k's progress; with the car's
        speed in the model (its ``v_l`` pull weighs the speed of stage k+1), the profile's
        speed at stage k+1, for v_p the mean of the profile's speeds at stages k and k+1,
        and the profile's drag [m/s^2] at stage k."""
        speed = self.reference.speed
        assert speed is not None  # only called for paths with a profile
        N = self.horizon
        if self._speed_loop is None:
            v = np.asarray(speed.command_at(s_pred[:N]), dtype=float)
            return np.ones(N), np.column_stack([v, v]), None
        v = np.asarray(speed.speed_at(s_pred[: N + 1]), dtype=float)
        drag = np.asarray(speed.drag_at(s_pred[:N]), dtype=float)
        return np.ones(N), np.column_stack([v[1:], (v[:-1] + v[1:]) / 2]), drag

    def _estimate_speed(self, x_m: float, y_m: float, yaw_rad: float) -> float:
        """The car's speed [m/s] at this pose (a model with its speed loop; the pose
        carries no speed): the pose's displacement since the last one along the mean
        heading over the period ``dt_s`` (the mean speed over the period, ``v_mean``), plus
        what the speed loop, driven by the last command, adds from the period's mean to its
        end: ``v = d / Ts + (v_end - v_mean)`` with ``(v_end, v_mean)`` the loop's
        prediction from the last estimate. No previous pose: the prediction alone (0 at
        the start). With ``[planner.cimpcc_line] speed_estimate_gain`` g < 1 (filtered
        poses: ``mintime.requests.for_pose_source``) the estimate is the loop's prediction
        plus g of the displacement's correction, ``v = v_end + g (d / Ts + v_end - v_mean -
        v_end)``, a fixed-gain (complementary) filter: a pose noise of sigma [m] gives
        about ``sqrt(2) sigma / Ts`` of speed noise at g = 1 (1.5 cm: 0.4 m/s, which the
        command cap's lead ``e / (1 - e)``, about 3.8, turned into 4.24 m/s at a 4.18 m/s
        cap). Clipped to the speed command's bounds."""
        loop = self._speed_loop
        assert loop is not None
        dt = self.settings.dt_s
        v_end, v_mean = loop.advance(self._v_est, float(self._u_applied[U.V_L]), dt)
        v = v_end
        if self._pose_prev is not None:
            x_p, y_p, yaw_p = self._pose_prev
            heading = yaw_p + wrap_angle(yaw_rad - yaw_p) / 2
            d = (x_m - x_p) * math.cos(heading) + (y_m - y_p) * math.sin(heading)
            v = d / dt + (v_end - v_mean)
            gain = self.settings.cimpcc_line.speed_estimate_gain
            if gain != 1.0:  # exactly the displacement at 1 (the true pose)
                v = v_end + gain * (v - v_end)
        self._pose_prev = (x_m, y_m, yaw_rad)
        self._v_est = float(np.clip(v, self._u_lo[U.V_L], self._u_hi[U.V_L]))
        return self._v_est

    def _beta(self, s0: float, s_pred: np.ndarray | None) -> np.ndarray:
        """beta per stage (N,): all g(NSC(s0)) (paper) or g(NSC(s_k)) of the warm start."""
        if self.settings.beta_mode == "per_stage" and s_pred is not None:
            return np.asarray(self.profile.beta_at(s_pred), dtype=float)
        return np.full(self.horizon, float(self.profile.beta_at(s0)))

    def _parameters(
        self,
        x0: np.ndarray,
        beta: np.ndarray,
        v_ref: np.ndarray | None = None,
        drag: np.ndarray | None = None,
    ) -> np.ndarray:
        """The parameter vector: weights packed once per weights object, x0 and beta set,
        and with `v_ref` (N, 2) [m/s] both per-stage velocity references (``cimpcc-line``;
        else the weights' v_up and v_low at every stage); `drag` (N,) [m/s^2] the per-stage
        drag of a model with the car's speed."""
        layout = self.problem.layout
        if self._p_cache is None or self._p_cache[0] is not self.weights:
            w_du0 = 1.0 if self.settings.delta_u_on_applied else 0.0
            template = layout.pack(x0, beta, self.weights, w_du0, self._slack_w)
            self._p_cache = (self.weights, template)
        p = self._p_cache[1].copy()
        p[layout.slices["x0"]] = x0
        p[layout.slices["beta"]] = beta
        if v_ref is not None:
            p[layout.slices["v_up"]] = p[layout.slices["v_low"]] = v_ref.ravel()
        if "drag" in layout.slices:
            p[layout.slices["drag"]] = 0.0 if drag is None else drag
        return p

    def _cold_guess(self, x0: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """First-solve guess: a model rollout from x0 at INITIAL_GUESS_SPEED_MPS."""
        pr = self.problem
        N = pr.horizon
        xs = np.empty((N + 1, pr.nxa))
        us = np.zeros((N, len(UA)))
        mi = self._model_index
        us[:, UA.V_L] = INITIAL_GUESS_SPEED_MPS
        us[:, UA.V_P] = INITIAL_GUESS_SPEED_MPS
        xs[0] = x0
        for k in range(N):
            xs[k + 1, mi] = np.asarray(pr.step(xs[k, mi], us[k, :NU])).reshape(-1)
            xs[k + 1, NX : NX + NU] = us[k, :NU]
        return xs, us

    def _align(self, w: np.ndarray, x0: np.ndarray) -> np.ndarray:
        """The shifted decision vector aligned with x0, in place: whole laps in s, whole
        turns in phi, xa_0 = x0."""
        prog, phi, first = self._w_progress, self._w_phi, self._w_first
        L = self.path.length_m
        w[prog] += L * round((x0[XA.PROGRESS] - w[prog[0]]) / L)
        w[phi] += 2 * np.pi * round((x0[XA.PHI] - w[phi[0]]) / (2 * np.pi))
        w[first] = x0
        return w

    def _failed(
        self,
        x0: np.ndarray,
        s0: float,
        e0: float,
        status_text: str,
        iters: int,
        solve_time: float,
        beta: np.ndarray | None,
        on_command: Callable[[DriveCommand], None] | None = None,
    ) -> SolveResult:
        """Fallback to the shifted previous plan; brake after too many failures in a row."""
        self._prepared = None
        self._failures += 1
        N = self.horizon
        beta_arr = np.zeros(N) if beta is None else np.asarray(beta, dtype=float)
        can_shift = self._w_prev is not None
        if can_shift and self._failures < self.settings.max_consecutive_failures:
            xs_prev, us_prev = self.problem.unpack(self._w_prev)
            xs = np.vstack([xs_prev[1:], xs_prev[-1:]])
            us = np.vstack([us_prev[1:], us_prev[-1:]])
            self._w_prev = self.problem.pack(xs, us)
            u0 = np.clip(us[0, :NU], self._u_lo, self._u_hi)
            status = FALLBACK
        else:
            nxa = self.problem.nxa
            xs = np.tile(x0, (N + 1, 1)) if x0.size == nxa else np.zeros((N + 1, nxa))
            us = np.zeros((N, len(UA)))
            u0 = np.array(
                [
                    0.0,
                    float(np.clip(self._u_applied[U.DELTA], *self._u_lo[[1]], self._u_hi[1])),
                    0.0,
                ]
            )
            us[:, U.DELTA] = u0[U.DELTA]
            self._w_prev = None
            status = BRAKING
        if not np.all(np.isfinite(u0)):
            u0 = np.zeros(NU)
        self._u_applied = u0
        speed, _limited = self._safe_speed(float(u0[U.V_L]), s0, e0)
        command = DriveCommand(speed, float(u0[U.DELTA]))
        if on_command is not None:
            on_command(command)
        return SolveResult(
            command=command,
            states=np.asarray(xs[:, : len(S)], dtype=float),
            inputs=np.asarray(us[:, :NU], dtype=float),
            status=status,
            solver_status=status_text,
            iterations=iters,
            solve_time_s=solve_time,
            beta=beta_arr,
            s_m=s0,
            e_con_m=e0,
            consecutive_failures=self._failures,
            method=self.method,
        )
