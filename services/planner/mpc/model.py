"""The kinematic bicycle of the paper (eq. 12), written once for CasADi and numpy.

State ``zeta = [X, Y, phi, s]`` (rear-axle position [m], yaw [rad], progress [m]);
input ``u = [v_l, delta, v_p]`` (speed [m/s], steering [rad], progress speed [m/s]).

    X'   = cos(phi) v_l
    Y'   = sin(phi) v_l
    phi' = tan(delta) / L v_l
    s'   = v_p

``SlipModel`` extends it with the single-track car's steady-state tyre slip (linear tyres,
small angles; e.g. Rajamani, *Vehicle Dynamics and Control*, sec. 3.3): at lateral
acceleration ``a_y = v_l^2 kappa`` the axles slip by ``alpha_i = a_y / (g C_i)`` (C_i: the
axle's cornering stiffness per unit load), so the same steering turns less,
``tan(delta) = kappa (L + K_us v_l^2)`` with ``K_us = (1/C_f - 1/C_r) / g``, and the rear
axle moves at ``-alpha_r`` to the car's heading (it slides outwards)::

    kappa = tan(delta) / (L + K_us v_l^2)        beta_r = -c_r v_l^2 kappa,  c_r = 1 / (g C_r)
    X'    = cos(phi + beta_r) v_l
    Y'    = sin(phi + beta_r) v_l
    phi'  = kappa v_l
    s'    = v_p

With ``K_us = c_r = 0`` it is the paper's model (and ``kinematic_bicycle`` builds exactly
that expression then).

``SpeedLoop`` (``cimpcc-line``) adds the car's speed ``v`` [m/s] as a fifth state, index
``SPEED``: ``v_l`` is then the speed COMMAND and the car follows it through its proportional
speed loop (the simulator's and the gym's, ``services/simulator/actuators.py``); the
position moves at ``v``, not at ``v_l``::

    e  = v_l - v
    a  = k_a e + (k_b - k_a) (e - sqrt(e^2 + e_s^2)) / 2   (k_a speeding up, k_b braking:
                                                            the min(e, 0) smoothed over e_s)
    v' = a / (1 + (a / a_max)^4)^(1/4)                      (smooth clip at +-a_max)

and ``v`` replaces ``v_l`` in the equations above (the smooth switch settles ``v`` about
``(k_b - k_a) e_s / (k_a + k_b)`` = 0.03 m/s under a held command). The tyres' drag in a
bend (up to about 2 m/s^2 at the limit) is not in here: the problem subtracts the reference
lap's drag at each stage (``problem.build_problem``), as a known disturbance.

``Servo`` (``cimpcc-line`` on a car with a slow servo, ``mintime.model.servo_reach``) adds
the wheels' steering angle ``delta_w`` [rad] as a further state, index ``SERVO`` (after
``SPEED``): ``delta`` is then the servo's TARGET and the wheels follow it through the
servo's proportional loop (``services/simulator/actuators.py``), the rate smoothly clipped
at the servo's rate limit ``r_max``; the bicycle turns with ``delta_w``::

    r        = (delta - delta_w) / tau
    delta_w' = r / (1 + (r / r_max)^4)^(1/4)
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import IntEnum
from typing import Any

import casadi as ca
import numpy as np

from shared.config.vehicle import DynamicVehicleParams
from shared.vehicle.steady_state import steady_state_steering
from shared.vehicle.tyres import pacejka_slip_for_share

#: Standard gravity [m/s^2].
GRAVITY_MPS2 = 9.81


class S(IntEnum):
    """Index of each element of the model state."""

    X = 0
    Y = 1
    PHI = 2
    PROGRESS = 3


class U(IntEnum):
    """Index of each element of the model input."""

    V_L = 0
    DELTA = 1
    V_P = 2


NX = len(S)
NU = len(U)
#: Speeds [m/s] and lateral accelerations (``NEAR_LIMIT_SAMPLES`` up to this fraction of
#: ``mu g``) of the near-limit slip fit (``SlipModel.for_vehicle``).
NEAR_LIMIT_SPEEDS_MPS = (2.0, 3.0, 4.0, 5.0)
NEAR_LIMIT_GRIP = 0.95
NEAR_LIMIT_SAMPLES = 12
#: Index of the car's speed in the state of a model with a ``SpeedLoop`` (5 elements).
SPEED = NX
#: Index of the wheels' steering angle in the state of a model with a ``Servo`` (6 elements,
#: after ``SPEED``).
SERVO = NX + 1
#: Width e_s [m/s] of the smooth switch between the speed loop's two gains (a sharper one,
#: 0.02 m/s with tanh, took 1.4 more solver iterations for the same laps).
E_SMOOTH_MPS = 0.05


@dataclass(frozen=True)
class SlipModel:
    """The kinematic bicycle's parameters with steady-state tyre slip (module docstring).

    Attributes:
        wheelbase_m: L [m].
        understeer_s2pm: K_us [s^2/m]: the understeer gradient, the extra steering
            ``K_us a_y`` [rad] at lateral acceleration ``a_y`` [m/s^2] (0: none).
        rear_slip_s2pm: c_r [s^2/m]: the rear axle's slip angle ``c_r a_y`` [rad]
            (0: none).
        understeer_growth_s6pm3: K_2 [s^6/m^3]: near the limit the understeer gradient
            grows to ``K_us + K_2 a_y^2`` (the drive that holds the speed against the tyres'
            drag unloads the front axle; 0: none).
        rear_slip_growth_s6pm3: c_2 [s^6/m^3]: ... and the rear slip's to ``c_r + c_2
            a_y^2`` (c_2 < 0: the rear axle, loaded, slips less).
    """

    wheelbase_m: float
    understeer_s2pm: float = 0.0
    rear_slip_s2pm: float = 0.0
    understeer_growth_s6pm3: float = 0.0
    rear_slip_growth_s6pm3: float = 0.0

    @classmethod
    def for_vehicle(cls, vehicle: DynamicVehicleParams, near_limit: bool = False) -> SlipModel:
        """The slip of `vehicle`'s tyres at small angles: ``C_i = mu C_Si`` (linear tyres)
        or ``mu D_i C_i B_i`` (the magic formula's slope at zero slip).

        With `near_limit` (linear tyres only), also ``K_2`` and ``c_2``: the least-squares
        fit of ``K_us + K_2 a_y^2`` and ``c_r + c_2 a_y^2`` to the car's steady state with
        load transfer and drag (``shared.vehicle.steady_state``: ``K = (tan(delta) /
        kappa - L) / v^2``, ``c = alpha_r / a_y``) at ``NEAR_LIMIT_SPEEDS_MPS`` and
        ``a_y`` up to ``NEAR_LIMIT_GRIP`` of ``mu g``. At 9 m/s^2 and 4 m/s the small-angle
        model alone predicts 13 % more curvature than the car turns, the fit (its ``a_y``
        the first estimate's, a little high) 8 % less.
        """
        if vehicle.tyre_model == "pacejka":
            b_f, c_f, d_f, _ = vehicle.pacejka_front
            b_r, c_r, d_r, _ = vehicle.pacejka_rear
            front, rear = vehicle.mu * b_f * c_f * d_f, vehicle.mu * b_r * c_r * d_r
        else:
            front = vehicle.mu * vehicle.cornering_stiffness_front_per_rad
            rear = vehicle.mu * vehicle.cornering_stiffness_rear_per_rad
        g = GRAVITY_MPS2
        base = cls(vehicle.wheelbase_m, (1.0 / front - 1.0 / rear) / g, 1.0 / (g * rear))
        if not near_limit:
            return base
        if vehicle.tyre_model == "pacejka":
            return cls._pacejka_near_limit(vehicle, base)
        v = np.repeat(NEAR_LIMIT_SPEEDS_MPS, NEAR_LIMIT_SAMPLES)
        a_y = np.tile(
            np.linspace(0.5, NEAR_LIMIT_GRIP * vehicle.mu * g, NEAR_LIMIT_SAMPLES),
            len(NEAR_LIMIT_SPEEDS_MPS),
        )
        kappa = a_y / v**2
        delta, beta, _ = steady_state_steering(kappa, v, np.zeros_like(v), vehicle)
        k_us = (np.tan(delta) / kappa - vehicle.wheelbase_m) / v**2
        c = (np.arctan(vehicle.lr_m * kappa) - beta) / a_y
        x = a_y**2
        k_2 = float(x @ (k_us - base.understeer_s2pm) / (x @ x))
        c_2 = float(x @ (c - base.rear_slip_s2pm) / (x @ x))
        return cls(base.wheelbase_m, base.understeer_s2pm, base.rear_slip_s2pm, k_2, c_2)

    @classmethod
    def _pacejka_near_limit(cls, vehicle: DynamicVehicleParams, base: SlipModel) -> SlipModel:
        """``K_2`` and ``c_2`` of Pacejka tyres: the least-squares fit of ``K_us + K_2 a_y^2``
        and ``c_r + c_2 a_y^2`` to the magic formula's steady state (each axle's slip the
        inverse of the curve at its share ``a_y / (mu_i g)`` of the peak; load transfer and
        drag left out, the identified car's CoG is 14 mm high) at ``a_y`` up to
        ``NEAR_LIMIT_GRIP`` of ``min_i mu_i g``. The identified car's understeer gradient
        grows by about 20 % towards its limit (the small-angle slope alone keeps it at
        0.0096 s^2/m)."""
        g = GRAVITY_MPS2
        mu_f = vehicle.mu * vehicle.pacejka_front[2]
        mu_r = vehicle.mu * vehicle.pacejka_rear[2]
        a_y = np.linspace(0.5, NEAR_LIMIT_GRIP * min(mu_f, mu_r) * g, NEAR_LIMIT_SAMPLES)
        alpha_f = pacejka_slip_for_share(vehicle, "front", a_y / (mu_f * g))
        alpha_r = pacejka_slip_for_share(vehicle, "rear", a_y / (mu_r * g))
        k_us = (alpha_f - alpha_r) / a_y  # steering beyond the kinematic, per a_y
        c = alpha_r / a_y
        x = a_y**2
        k_2 = float(x @ (k_us - base.understeer_s2pm) / (x @ x))
        c_2 = float(x @ (c - base.rear_slip_s2pm) / (x @ x))
        return cls(base.wheelbase_m, base.understeer_s2pm, base.rear_slip_s2pm, k_2, c_2)

    @property
    def is_kinematic(self) -> bool:
        """No slip: the paper's kinematic bicycle."""
        return (
            self.understeer_s2pm == 0.0
            and self.rear_slip_s2pm == 0.0
            and self.understeer_growth_s6pm3 == 0.0
            and self.rear_slip_growth_s6pm3 == 0.0
        )


@dataclass(frozen=True)
class SpeedLoop:
    """The car's proportional speed loop (module docstring).

    Attributes:
        gain_accel_per_s: k_a [1/s], while the speed grows.
        gain_brake_per_s: k_b [1/s], while it shrinks.
        accel_max_mps2: a_max [m/s^2], the drive's and the brakes' limit.
        switch_mps: e_s [m/s], the width of the smooth switch between the two gains.
    """

    gain_accel_per_s: float
    gain_brake_per_s: float
    accel_max_mps2: float
    switch_mps: float = E_SMOOTH_MPS

    @classmethod
    def for_vehicle(cls, vehicle: DynamicVehicleParams) -> SpeedLoop:
        """The speed loop of `vehicle` (its gains and acceleration limit)."""
        return cls(
            vehicle.speed_gain_accel_per_s, vehicle.speed_gain_brake_per_s, vehicle.accel_max_mps2
        )

    def accel(self, v_cmd: Any, v: Any) -> Any:
        """``v'`` [m/s^2] at command `v_cmd` and speed `v` [m/s] (module docstring); works on
        CasADi expressions and numpy arrays."""
        e = v_cmd - v
        sqrt = ca.sqrt if isinstance(e, ca.SX | ca.MX) else np.sqrt
        e_neg = (e - sqrt(e * e + self.switch_mps**2)) / 2  # min(e, 0), smoothed
        a = self.gain_accel_per_s * e + (self.gain_brake_per_s - self.gain_accel_per_s) * e_neg
        return a / (1.0 + (a / self.accel_max_mps2) ** 4) ** 0.25

    def advance(
        self, v: float, v_cmd: float, dt_s: float, substeps: int = 5
    ) -> tuple[float, float]:
        """(speed at the end [m/s], mean speed over the interval [m/s]) after holding
        `v_cmd` for `dt_s` [s] from speed `v` (RK4 with `substeps`)."""
        h = dt_s / substeps
        mean = 0.0
        for _ in range(substeps):
            k1 = self.accel(v_cmd, v)
            k2 = self.accel(v_cmd, v + h / 2 * k1)
            k3 = self.accel(v_cmd, v + h / 2 * k2)
            k4 = self.accel(v_cmd, v + h * k3)
            v_next = v + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
            mean += (v + v_next) / 2 / substeps
            v = v_next
        return float(v), float(mean)


@dataclass(frozen=True)
class Servo:
    """The car's steering servo (module docstring): a first-order lag behind its target.

    Attributes:
        time_constant_s: tau [s], ``d(delta_w)/dt = (target - delta_w) / tau``.
        rate_max_radps: r_max [rad/s], the servo's rate limit (smoothly clipped).
    """

    time_constant_s: float
    rate_max_radps: float

    @classmethod
    def for_vehicle(cls, vehicle: DynamicVehicleParams) -> Servo:
        """The servo of `vehicle` (its time constant and the smaller of its rate limits)."""
        rate = min(vehicle.steering_rate_max_radps, -vehicle.steering_rate_min_radps)
        return cls(vehicle.steering_time_constant_s, rate)

    def rate(self, target: Any, delta_w: Any) -> Any:
        """``delta_w'`` [rad/s] towards `target` from `delta_w` [rad] (CasADi or numpy)."""
        r = (target - delta_w) / self.time_constant_s
        return r / (1.0 + (r / self.rate_max_radps) ** 4) ** 0.25

    def advance(self, delta_w: float, target: float, dt_s: float, substeps: int = 5) -> float:
        """The wheels' angle [rad] after holding `target` for `dt_s` [s] from `delta_w`
        (RK4 with `substeps`)."""
        h = dt_s / substeps
        for _ in range(substeps):
            k1 = self.rate(target, delta_w)
            k2 = self.rate(target, delta_w + h / 2 * k1)
            k3 = self.rate(target, delta_w + h / 2 * k2)
            k4 = self.rate(target, delta_w + h * k3)
            delta_w = delta_w + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
        return float(delta_w)


def kinematic_bicycle(
    wheelbase_m: float,
    slip: SlipModel | None = None,
    speed_loop: SpeedLoop | None = None,
    servo: Servo | None = None,
) -> ca.Function:
    """Continuous dynamics ``f(zeta, u) -> zeta_dot`` as a CasADi Function (SX inside).

    Args:
        wheelbase_m: L [m] (of the paper's model; ignored when `slip` is given).
        slip: the steady-state slip extension (module docstring); None or no slip: the
            paper's model, eq. 12.
        speed_loop: the car's speed loop: the state gets the car's speed (index ``SPEED``)
            and ``v_l`` is its command (module docstring); None: ``v_l`` is the speed.
        servo: the car's servo (needs `speed_loop`): the state gets the wheels' angle
            (index ``SERVO``) and ``delta`` is the servo's target; None: ``delta`` steers.

    Returns:
        Function ``f(x[4], u[3]) -> xdot[4]`` (``x[5]``, ``xdot[5]`` with `speed_loop`,
        ``x[6]`` with `servo` too); callable with numpy arrays too.
    """
    if servo is not None and speed_loop is None:
        raise ValueError("a servo state needs the speed loop's state before it")
    x = ca.SX.sym("x", NX + (speed_loop is not None) + (servo is not None))
    u = ca.SX.sym("u", NU)
    v = u[U.V_L] if speed_loop is None else x[SPEED]
    delta = u[U.DELTA] if servo is None else x[SERVO]
    if slip is None or slip.is_kinematic:
        L = wheelbase_m if slip is None else slip.wheelbase_m
        xdot = ca.vertcat(
            ca.cos(x[S.PHI]) * v,
            ca.sin(x[S.PHI]) * v,
            ca.tan(delta) / L * v,
            u[U.V_P],
        )
    else:
        kappa = ca.tan(delta) / (slip.wheelbase_m + slip.understeer_s2pm * v**2)
        c_r = slip.rear_slip_s2pm
        if slip.understeer_growth_s6pm3 != 0.0 or slip.rear_slip_growth_s6pm3 != 0.0:
            a_y2 = (kappa * v**2) ** 2  # a_y^2 at the first estimate
            k_us = slip.understeer_s2pm + slip.understeer_growth_s6pm3 * a_y2
            kappa = ca.tan(delta) / (slip.wheelbase_m + k_us * v**2)
            c_r = c_r + slip.rear_slip_growth_s6pm3 * a_y2
        course = x[S.PHI] - c_r * v**2 * kappa
        xdot = ca.vertcat(ca.cos(course) * v, ca.sin(course) * v, kappa * v, u[U.V_P])
    if speed_loop is not None:
        xdot = ca.vertcat(xdot, speed_loop.accel(u[U.V_L], x[SPEED]))
    if servo is not None:
        xdot = ca.vertcat(xdot, servo.rate(u[U.DELTA], x[SERVO]))
    return ca.Function("kinematic_bicycle", [x, u], [xdot], ["x", "u"], ["xdot"])


def discretise(f: ca.Function, dt_s: float, integrator: str = "rk4") -> ca.Function:
    """One step ``F(x_k, u_k) -> x_{k+1}`` of `f` over `dt_s` [s], input held constant.

    Args:
        f: continuous dynamics ``f(x, u)``.
        dt_s: step Ts [s].
        integrator: ``"rk4"`` (classic 4-stage Runge-Kutta), ``"rk2"`` (the midpoint rule:
            half RK4's evaluations, ``cimpcc-line``'s default) or ``"euler"`` (forward Euler, as
            the authors' code).
    """
    x = ca.SX.sym("x", f.size1_in(0))
    u = ca.SX.sym("u", f.size1_in(1))
    if integrator == "euler":
        x_next = x + dt_s * f(x, u)
    elif integrator == "rk2":  # the midpoint rule
        x_next = x + dt_s * f(x + dt_s / 2 * f(x, u), u)
    elif integrator == "rk4":
        k1 = f(x, u)
        k2 = f(x + dt_s / 2 * k1, u)
        k3 = f(x + dt_s / 2 * k2, u)
        k4 = f(x + dt_s * k3, u)
        x_next = x + dt_s / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
    else:
        raise ValueError(f"unknown integrator {integrator!r}")
    return ca.Function("F", [x, u], [x_next], ["x", "u"], ["x_next"])


def step_numpy(F: ca.Function, x: np.ndarray, u: np.ndarray) -> np.ndarray:
    """Evaluate a discrete step with numpy in and out: (4,), (5,) or (6,) state, (3,) input."""
    return np.asarray(F(x, u), dtype=float).reshape(-1)
