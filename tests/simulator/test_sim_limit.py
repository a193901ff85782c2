"""The car at and beyond the limit of grip: it stops when commands stop, sliding dissipates
energy, slip stays bounded, and no state or input makes the tyres create energy.

Physical tyre models: ``linear_saturated`` (the default) and ``pacejka`` (both presets).
The gym's ``linear`` model is kept exactly as the gym has it (small-angle, unbounded
forces): it must still brake to rest in a turn, but it is excluded from the energy
properties (its small-angle forces can do positive work at large slip; shown below).
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from services.simulator.dynamics import SingleTrackModel
from services.simulator.integrate import rk4_step
from services.simulator.state import Command, Pose2D, StateIndex
from services.simulator.vehicle import Simulator
from shared.config.simulator import SimulatorSettings
from shared.config.vehicle import DynamicVehicleParams, vehicle_preset
from shared.vehicle import FLOAT_OPS, make_dynamic_derivatives

S = StateIndex

#: (preset, tyre model) of every car the simulator can be.
CARS = [
    ("f1tenth_gym", "linear"),
    ("f1tenth_gym", "linear_saturated"),
    ("f1tenth_gym", "pacejka"),
    ("real_car_identified", "pacejka"),
    ("real_car_identified", "linear_saturated"),
]
PHYSICAL = [c for c in CARS if c[1] != "linear"]


def _params(preset: str, tyre: str) -> DynamicVehicleParams:
    return vehicle_preset(preset, tyre_model=tyre)  # type: ignore[arg-type]


def _energy(p: DynamicVehicleParams, v: float, r: float) -> float:
    """Kinetic plus rotational energy [J]."""
    return 0.5 * p.mass_kg * v * v + 0.5 * p.yaw_inertia_kgm2 * r * r


def _energy_rate(p: DynamicVehicleParams, s: tuple, ds: tuple) -> float:
    """d/dt of the energy [W] at state `s` with derivative `ds`."""
    return p.mass_kg * s[S.V] * ds[S.V] + p.yaw_inertia_kgm2 * s[S.PSI_DOT] * ds[S.PSI_DOT]


@pytest.mark.parametrize(("preset", "tyre"), CARS, ids=[f"{p}-{t}" for p, t in CARS])
def test_braking_in_a_turn_comes_to_rest(preset: str, tyre: str) -> None:
    """Cruise 1 s in a turn, then commands stop (the timeout brakes): at rest within 2 s."""
    p = _params(preset, tyre)
    failures = []
    for v0 in (3.0, 4.0, 5.0, 6.0):
        for steer in (0.1, 0.2, 0.3):
            sim = Simulator(SimulatorSettings(vehicle=p))
            sim.reset(Pose2D(0.0, 0.0, 0.0), speed_mps=v0, steering_rad=steer)
            for _ in range(100):  # 1 s of cruising at the command
                sim.step(Command(v0, steer), 0.01)
            e_prev = math.inf
            rest_at = None
            for k in range(200):  # 2 s with no command
                st_ = sim.step(None, 0.01).state
                e = _energy(p, st_.v_mps, st_.yaw_rate_radps)
                # braking (no drive): the energy only falls once the timeout acts
                if k >= 15:
                    assert e <= e_prev + 1e-9, (v0, steer, k)
                e_prev = e
                if rest_at is None and abs(st_.v_mps) < 0.02 and abs(st_.yaw_rate_radps) < 1.0:
                    rest_at = (k + 1) * 0.01
            st_ = sim.state
            if not (abs(st_.v_mps) < 0.02 and abs(st_.yaw_rate_radps) < 1.0):
                failures.append((v0, steer, st_.v_mps, st_.yaw_rate_radps))
            assert abs(st_.slip_rad) <= math.pi / 2
    assert not failures, f"not at rest 2 s after the commands stopped: {failures}"


@pytest.mark.parametrize(("preset", "tyre"), PHYSICAL, ids=[f"{p}-{t}" for p, t in PHYSICAL])
@pytest.mark.parametrize("delta", [0.0, 0.2])
def test_a_sideways_slide_dissipates(preset: str, tyre: str, delta: float) -> None:
    """A car sliding at 75 deg and spinning at 20 rad/s, no drive, steering held: the energy
    falls monotonically while it slides. With straight wheels the slide ends and it rolls on
    (no rolling resistance: the energy then stays); with the wheels at 0.2 rad it ends up
    reversing, which is directionally unstable, and keeps sliding and losing energy."""
    p = _params(preset, tyre)
    model = SingleTrackModel(p)
    sim = Simulator(SimulatorSettings(vehicle=p))
    sim._s = (0.0, 0.0, delta, 5.0, 0.0, 20.0, 1.3)
    s = sim.state_tuple
    e0 = e_prev = _energy(p, s[S.V], s[S.PSI_DOT])
    for _ in range(2000):  # 4 s
        s, _ = rk4_step(lambda z: model.rhs(z, 0.0, 0.0), s, 0.002)
        s = sim._sanitise(s, s, -1.0, 1.0, -50.0, 50.0)  # canonical slip, as the simulator
        e = _energy(p, s[S.V], s[S.PSI_DOT])
        assert e <= e_prev * (1.0 + 1e-9) + 1e-12
        e_prev = e
    assert e_prev < 0.6 * e0  # most of the energy went into the slide
    d = make_dynamic_derivatives(p, FLOAT_OPS)(s[S.V], s[S.BETA], s[S.PSI_DOT], s[S.DELTA], 0.0)
    if delta == 0.0:
        assert abs(d.front.alpha_rad) < 0.02 and abs(d.rear.alpha_rad) < 0.02  # rolling again
    else:
        assert _energy_rate(p, s, model.rhs(s, 0.0, 0.0)) < 0.0  # still sliding, still losing


def test_the_gym_linear_model_is_not_dissipative_at_large_slip() -> None:
    """Why ``linear`` is not in the energy properties: its small-angle forces gain energy."""
    p = _params("f1tenth_gym", "linear")
    model = SingleTrackModel(p)
    s = (0.0, 0.0, -0.41, 19.0, 0.0, -14.0, -1.2)
    assert _energy_rate(p, s, model.rhs(s, 0.0, 0.0)) > 1.0


def test_identified_car_does_not_speed_up_in_a_turn() -> None:
    """Pacejka tyres used to push the car along its slide (2.0 -> 2.85 m/s at 1.5 m/s)."""
    sim = Simulator(SimulatorSettings(vehicle=vehicle_preset("real_car_identified")))
    sim.reset(Pose2D(0.0, 0.0, 0.0), speed_mps=2.0, steering_rad=0.35)
    speeds = [sim.step(Command(1.5, 0.35), 0.01).state.v_mps for _ in range(300)]
    assert max(speeds) <= 2.01  # (the reset's kinematic yaw rate settles in 10 ms)
    assert speeds[-1] == pytest.approx(1.5, abs=0.05)


_angles = st.floats(-math.pi / 2, math.pi / 2)


@st.composite
def _states(draw: st.DrawFn) -> tuple:
    """Random states: any speed sign and size, any slip, spins, at the steering limits."""
    delta = draw(st.floats(-0.42, 0.42))
    v = draw(st.one_of(st.floats(-5.0, 20.0), st.floats(-1.0, 1.0)))
    r = draw(st.one_of(st.floats(-60.0, 60.0), st.floats(-1.0, 1.0)))
    beta = draw(st.one_of(_angles, st.floats(-0.1, 0.1)))
    return (0.0, 0.0, delta, v, draw(st.floats(-10.0, 10.0)), r, beta)


@pytest.mark.parametrize(("preset", "tyre"), PHYSICAL, ids=[f"{p}-{t}" for p, t in PHYSICAL])
@settings(max_examples=400, deadline=None)
@given(s=_states(), sv=st.floats(-10.0, 10.0))
def test_no_energy_gain_without_drive(preset: str, tyre: str, s: tuple, sv: float) -> None:
    """For any state and any steering rate, with no drive (a = 0): dE/dt <= 0."""
    p = _params(preset, tyre)
    model = SingleTrackModel(p)
    ds = model.rhs(s, sv, 0.0)
    assert all(math.isfinite(x) for x in ds)
    e = _energy(p, s[S.V], s[S.PSI_DOT])
    assert _energy_rate(p, s, ds) <= 1e-9 * (1.0 + e)


@pytest.mark.parametrize(("preset", "tyre"), CARS, ids=[f"{p}-{t}" for p, t in CARS])
@settings(max_examples=150, deadline=None)
@given(
    s=_states(),
    cmd_v=st.floats(-5.0, 20.0),
    cmd_d=st.floats(-1.0, 1.0),
    a=st.floats(-20.0, 20.0),
)
def test_dynamics_finite_and_slip_bounded(
    preset: str, tyre: str, s: tuple, cmd_v: float, cmd_d: float, a: float
) -> None:
    """Random states and inputs: finite derivatives, bounded tyre slip, a step keeps
    ``|beta| <= pi/2`` and the state finite."""
    p = _params(preset, tyre)
    model = SingleTrackModel(p)
    ds = model.rhs(s, cmd_d * 10.0, a)
    assert all(math.isfinite(x) for x in ds)
    if tyre != "linear":
        f = make_dynamic_derivatives(p, FLOAT_OPS)
        v = s[S.V] if s[S.V] != 0.0 else 1e-6
        d = f(v, s[S.BETA], s[S.PSI_DOT], s[S.DELTA], a, a * v < 0.0)
        for axle in (d.front, d.rear):
            assert abs(axle.alpha_rad) <= math.pi / 2
            assert math.hypot(axle.fx_n, axle.fy_n) <= axle.fy_max_n + abs(axle.fx_n) + 1e-9
            assert abs(axle.fy_n) <= axle.fy_max_n + 1e-9
    sim = Simulator(SimulatorSettings(vehicle=p))
    sim.reset(Pose2D(0.0, 0.0, 0.0))
    sim._s = s  # any state, also ones a reset cannot make
    for _ in range(20):
        res = sim.step(Command(cmd_v, cmd_d), 0.01)
        assert all(math.isfinite(x) for x in res.state.as_tuple())
        assert abs(res.state.slip_rad) <= math.pi / 2 + 1e-12


def test_saturated_and_smooth_laws_agree_inside_the_limit() -> None:
    """The optimiser's smooth laws are the simulator's laws wherever forces are inside."""
    rng = np.random.default_rng(3)
    for preset, tyre in PHYSICAL:
        p = _params(preset, tyre)
        hard = make_dynamic_derivatives(p, FLOAT_OPS, saturate=True)
        smooth = make_dynamic_derivatives(p, FLOAT_OPS, saturate=False)
        n = 0
        while n < 200:
            v, beta = rng.uniform(1.0, 8.0), rng.uniform(-0.05, 0.05)
            r, delta, a = rng.uniform(-3, 3), rng.uniform(-0.4, 0.4), rng.uniform(-5, 5)
            d = hard(v, beta, r, delta, a)
            inside = all(
                abs(x.fy_n) < 0.99 * x.fy_max_n and abs(x.alpha_rad) < 0.05
                for x in (d.front, d.rear)
            )
            if not inside:
                continue
            n += 1
            e = smooth(v, beta, r, delta, a)
            np.testing.assert_allclose(d[:3], e[:3], rtol=1e-12, atol=1e-12)


def test_a_denormal_speed_keeps_the_derivatives_finite() -> None:
    """A speed a rounding error away from standing still (found by Hypothesis: 5e-324 m/s)
    while the car yaws: the kinematic blend's yaw-energy term must not divide by it."""
    for preset, tyre in PHYSICAL:
        model = SingleTrackModel(_params(preset, tyre))
        s = (0.0, 0.0, 0.2, 5e-324, 0.0, 0.5, 0.0)
        assert all(math.isfinite(x) for x in model.rhs(s, 1.0, 1.0)), (preset, tyre)
