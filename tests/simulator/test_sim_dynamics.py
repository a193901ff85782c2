"""The single-track model against known answers: straight rolling, kinematic cornering,
the CommonRoad equations, sliding at the friction limit, input limits, low-speed blend."""

from __future__ import annotations

import math

import numpy as np
import pytest

from services.simulator.dynamics import GRAVITY_MPS2, SingleTrackModel, blend_weight
from services.simulator.integrate import rk4_step
from services.simulator.state import Command, Pose2D, StateIndex
from services.simulator.vehicle import Simulator
from shared.config.simulator import SimulatorSettings
from shared.config.vehicle import F1TENTH_GYM, DynamicVehicleParams, vehicle_preset
from shared.vehicle import FLOAT_OPS, make_axle_force_law

S = StateIndex
P = F1TENTH_GYM
WB = P.lf_m + P.lr_m


def _sim(**vehicle: object) -> Simulator:
    return Simulator(SimulatorSettings(vehicle=DynamicVehicleParams(**vehicle)))


def _drive(sim: Simulator, cmd: Command, seconds: float, dt: float = 0.01) -> list:
    return [sim.step(cmd, dt) for _ in range(round(seconds / dt))]


def test_rolling_without_input_is_a_straight_line() -> None:
    model = SingleTrackModel(P)
    s = (1.0, -2.0, 0.0, 3.0, 0.4, 0.0, 0.0)
    for _ in range(1000):  # 10 s
        s, _ = rk4_step(lambda z: model.rhs(z, 0.0, 0.0), s, 0.01)
    assert s[S.V] == 3.0 and s[S.BETA] == 0.0 and s[S.PSI_DOT] == 0.0 and s[S.PSI] == 0.4
    assert s[S.X] == pytest.approx(1.0 + 30.0 * math.cos(0.4), abs=1e-9)
    assert s[S.Y] == pytest.approx(-2.0 + 30.0 * math.sin(0.4), abs=1e-9)


def test_simulator_holds_a_straight_line_at_constant_speed() -> None:
    sim = Simulator()
    sim.reset(Pose2D(0.0, 0.0, 0.0), speed_mps=2.5)
    res = _drive(sim, Command(2.5, 0.0), 4.0)
    st = res[-1].state
    assert st.y_m == 0.0 and st.slip_rad == 0.0 and st.yaw_rad == 0.0
    assert st.v_mps == pytest.approx(2.5, abs=1e-9)
    assert st.x_m == pytest.approx(10.0, abs=1e-6)


def test_linear_tyres_reproduce_the_commonroad_equations() -> None:
    """tyre_model 'linear' is exactly the F1TENTH gym's ST right-hand side (v > v_kin)."""
    p = DynamicVehicleParams(tyre_model="linear")
    model = SingleTrackModel(p)
    mu, csf, csr = p.mu, p.cornering_stiffness_front_per_rad, p.cornering_stiffness_rear_per_rad
    lf, lr, h, m, iz, g = p.lf_m, p.lr_m, p.cog_height_m, p.mass_kg, p.yaw_inertia_kgm2, 9.81
    rng = np.random.default_rng(1)
    for _ in range(20):
        x, y = rng.normal(size=2)
        delta, v, psi = rng.uniform(-0.4, 0.4), rng.uniform(1.0, 7.0), rng.uniform(-3, 3)
        r, beta = rng.uniform(-2, 2), rng.uniform(-0.2, 0.2)
        sv, a = rng.uniform(-3, 3), rng.uniform(-9, 9)
        fz_f, fz_r = g * lr - a * h, g * lf + a * h
        expected = [
            v * math.cos(beta + psi),
            v * math.sin(beta + psi),
            sv,
            a,
            r,
            -mu * m / (v * iz * (lr + lf)) * (lf**2 * csf * fz_f + lr**2 * csr * fz_r) * r
            + mu * m / (iz * (lr + lf)) * (lr * csr * fz_r - lf * csf * fz_f) * beta
            + mu * m / (iz * (lr + lf)) * lf * csf * fz_f * delta,
            (mu / (v**2 * (lr + lf)) * (csr * fz_r * lr - csf * fz_f * lf) - 1) * r
            - mu / (v * (lr + lf)) * (csr * fz_r + csf * fz_f) * beta
            + mu / (v * (lr + lf)) * (csf * fz_f) * delta,
        ]
        got = model.rhs((x, y, delta, v, psi, r, beta), sv, a)
        np.testing.assert_allclose(got, expected, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(
        model.derivative(np.array([0, 0, 0.1, 2.0, 0, 0.3, 0.01]), 1.0, 2.0),
        model.rhs((0.0, 0.0, 0.1, 2.0, 0.0, 0.3, 0.01), 1.0, 2.0),
    )


def test_low_speed_cornering_matches_the_kinematic_bicycle() -> None:
    sim = Simulator()
    delta = 0.1
    sim.reset(Pose2D(0.0, 0.0, 0.0), speed_mps=1.0, steering_rad=delta)
    st = _drive(sim, Command(1.0, delta), 5.0)[-1].state
    kinematic = st.v_mps * math.tan(delta) / WB
    assert st.yaw_rate_radps == pytest.approx(kinematic, rel=0.02)
    assert st.v_mps == pytest.approx(1.0, abs=0.01)


def test_kinematic_regime_is_exact_and_continuous() -> None:
    sim = Simulator()
    delta = 0.3
    sim.reset(Pose2D(0.0, 0.0, 0.0), speed_mps=0.3, steering_rad=delta)
    st = _drive(sim, Command(0.3, delta), 2.0)[-1].state
    beta_k = math.atan(P.lr_m * math.tan(delta) / WB)
    assert st.slip_rad == pytest.approx(beta_k, abs=1e-9)
    assert st.yaw_rate_radps == pytest.approx(
        st.v_mps * math.cos(beta_k) * math.tan(delta) / WB, rel=1e-6
    )
    # slow speed ramp through the blend: yaw rate and slip change smoothly step to step
    sim.reset(Pose2D(0.0, 0.0, 0.0), speed_mps=0.0, steering_rad=0.2)
    prev = sim.state
    jumps_r, jumps_b = [], []
    for k in range(300):
        res = sim.step(Command(0.2 + 0.005 * k, 0.2), 0.01)  # 0.2 -> 1.7 m/s
        jumps_r.append(abs(res.state.yaw_rate_radps - prev.yaw_rate_radps))
        jumps_b.append(abs(res.state.slip_rad - prev.slip_rad))
        prev = res.state
    assert prev.v_mps > 1.2
    assert max(jumps_r) < 0.05 and max(jumps_b) < 0.01


def test_blend_weight() -> None:
    assert blend_weight(0.4, 0.5, 0.2) == 0.0
    assert blend_weight(0.6, 0.5, 0.2) == pytest.approx(0.5)
    assert blend_weight(0.8, 0.5, 0.2) == 1.0
    assert blend_weight(0.5001, 0.5, 0.0) == 1.0


def _path_turn_rates(results: list, dt: float) -> tuple[np.ndarray, np.ndarray]:
    """(speed, course rate d(psi + beta)/dt) between consecutive steps."""
    chi = np.array([r.state.yaw_rad + r.state.slip_rad for r in results])
    v = np.array([r.state.v_mps for r in results])
    return v[1:], np.diff(chi) / dt


def test_too_fast_into_a_tight_turn_slides_at_mu_g() -> None:
    """5 m/s with a 0.3 rad step (kinematic radius 1.07 m, needs 23 m/s^2): it slides."""
    mu_g = P.mu * GRAVITY_MPS2
    r_kin = WB / math.tan(0.3)
    sim = Simulator()
    sim.reset(Pose2D(0.0, 0.0, 0.0), speed_mps=5.0)
    res = _drive(sim, Command(5.0, 0.3), 3.0)
    v, chi_dot = _path_turn_rates(res, 0.01)
    a_path = v * chi_dot  # acceleration normal to the path
    assert np.max(np.abs(a_path)) <= 1.01 * mu_g
    assert np.max(np.abs([r.accel_lat_mps2 for r in res])) <= 1.01 * mu_g
    steady = slice(-100, None)
    assert np.mean(a_path[steady]) > 0.75 * mu_g
    radius = np.mean(v[steady] / chi_dot[steady])
    assert radius > 2.0 * r_kin
    assert radius >= np.mean(v[steady]) ** 2 / mu_g * 0.99
    assert all(math.isfinite(x) for x in res[-1].state.as_tuple())
    # the gym's linear tyres do not saturate: far beyond mu g on the same manoeuvre
    lin = _sim(tyre_model="linear")
    lin.reset(Pose2D(0.0, 0.0, 0.0), speed_mps=5.0)
    v_l, chi_l = _path_turn_rates(_drive(lin, Command(5.0, 0.3), 3.0), 0.01)
    assert np.mean(v_l[-100:] * chi_l[-100:]) > 1.5 * mu_g


def test_ramp_steer_saturates_lateral_acceleration() -> None:
    sim = Simulator()
    sim.reset(Pose2D(0.0, 0.0, 0.0), speed_mps=4.0)
    ay = [sim.step(Command(4.0, min(0.4, 0.001 * k)), 0.01).accel_lat_mps2 for k in range(500)]
    mu_g = P.mu * GRAVITY_MPS2
    assert max(ay) <= 1.01 * mu_g
    assert max(ay) > 0.8 * mu_g
    assert ay[-1] > 0.7 * mu_g  # settles at the limit (front-limited), no spin


def test_pacejka_peak_force_is_mu_d_fz() -> None:
    p = vehicle_preset("real_car_identified")
    front = make_axle_force_law(p, "front", FLOAT_OPS)
    rear = make_axle_force_law(p, "rear", FLOAT_OPS)
    alphas = np.linspace(-0.6, 0.6, 2401)
    fzf, fzr = 17.0, 19.0
    # a patch rolling at u = 1 m/s with lateral velocity w = -tan(alpha): slip angle alpha
    forces = np.array(
        [
            (
                front(1.0, -math.tan(a), fzf, 0.0, False)[1],
                rear(1.0, -math.tan(a), fzr, 0.0, False)[1],
            )
            for a in alphas
        ]
    )
    assert forces[:, 0].max() == pytest.approx(p.mu * p.pacejka_front[2] * fzf, rel=1e-3)
    assert forces[:, 1].max() == pytest.approx(p.mu * p.pacejka_rear[2] * fzr, rel=1e-3)
    # small-slip slope is B C D per unit load
    slope = front(1.0, -1e-6, 1.0, 0.0, False)[1] / 1e-6
    assert slope == pytest.approx(np.prod(p.pacejka_front[:3]), rel=1e-3)


def test_friction_circle_shrinks_lateral_grip_under_acceleration() -> None:
    law = make_axle_force_law(P, "front", FLOAT_OPS)
    _, fy0, fmax0, _ = law(1.0, -1.0, 10.0, 0.0, False)
    fx5, fy5, fmax5, _ = law(1.0, -1.0, 10.0, 10.0 * 5.0 / GRAVITY_MPS2, False)
    assert fmax0 == pytest.approx(P.mu * 10.0) and fy0 == pytest.approx(fmax0)
    assert fx5 == pytest.approx(10.0 * 5.0 / GRAVITY_MPS2)
    assert fmax5 == pytest.approx(10.0 * math.sqrt(P.mu**2 - (5.0 / GRAVITY_MPS2) ** 2))
    assert fy5 == pytest.approx(fmax5)
    model = SingleTrackModel(P)
    ts = model.tyre_state((0.0, 0.0, 0.3, 5.0, 0.0, 0.0, 0.0), 0.0)
    assert ts.saturated_front and not ts.saturated_rear


def test_steering_rate_and_angle_limits() -> None:
    sim = Simulator()
    sim.reset(Pose2D(0.0, 0.0, 0.0), speed_mps=2.0)
    res = _drive(sim, Command(2.0, 1.0), 0.5)  # asks for far beyond the end stop
    deltas = np.array([0.0] + [r.state.delta_rad for r in res])
    rates = np.diff(deltas) / 0.01
    assert rates.max() <= P.steering_rate_max_radps + 1e-9
    assert rates.max() == pytest.approx(P.steering_rate_max_radps)  # runs at the rate limit
    assert deltas.max() == pytest.approx(P.steering_max_rad)
    # nothing moves before the actuation + steering delays (0.01 + 0.02 s)
    assert deltas[1] == 0.0 and deltas[2] == 0.0 and deltas[3] == 0.0 and deltas[4] > 0.0


def test_acceleration_limits() -> None:
    sim = Simulator()
    sim.reset(Pose2D(0.0, 0.0, 0.0))
    res = _drive(sim, Command(20.0, 0.0), 4.0)
    v = np.array([0.0] + [r.state.v_mps for r in res])
    acc = np.diff(v) / 0.01
    assert acc.max() <= P.accel_max_mps2 + 1e-9
    fast = v[:-1] > P.v_switch_mps + 0.1
    limit = P.accel_max_mps2 * P.v_switch_mps / v[:-1][fast]
    assert np.all(acc[fast] <= limit + 1e-6)
    assert v.max() <= P.v_max_mps


def test_reverse_is_stable() -> None:
    sim = Simulator()
    sim.reset(Pose2D(0.0, 0.0, 0.0))
    st = _drive(sim, Command(-2.0, 0.2), 4.0)[-1].state
    assert st.v_mps == pytest.approx(-2.0, abs=0.05)
    kin = st.v_mps * math.tan(0.2) / WB
    assert st.yaw_rate_radps == pytest.approx(kin, rel=0.1)
    assert abs(st.slip_rad) < 0.2


@pytest.mark.parametrize("preset", ["f1tenth_gym", "real_car_identified"])
def test_stiff_low_speed_range_stays_stable(preset: str) -> None:
    """Between 0.5 and 1 m/s the lateral dynamics are stiff; sub-stepping keeps RK4 stable."""
    sim = Simulator(SimulatorSettings(vehicle=vehicle_preset(preset)))
    sim.reset(Pose2D(0.0, 0.0, 0.0), speed_mps=0.7, steering_rad=0.25)
    res = _drive(sim, Command(0.7, 0.25), 3.0)
    r = np.array([x.state.yaw_rate_radps for x in res[-100:]])
    assert np.ptp(r) < 1e-3
    if preset == "real_car_identified":  # stiff rear tyre: RK4 needs split steps here
        assert max(x.substeps for x in res) >= 2
