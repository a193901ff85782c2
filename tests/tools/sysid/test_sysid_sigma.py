"""The sysid's sigmas are honest: on synthetic data whose truth is known, with correlated
errors (the model's own, not white noise) and a measurement stamped at the end of the step
it averages, the reported 1-sigma (block jackknife plus the grid's and the timing's
floors) covers the truth within 3 sigma where the curvature-only sigma does not; the
jackknife itself recovers the spread of a block-correlated mean."""

from __future__ import annotations

import math

import numpy as np
import pytest

from shared.config.vehicle import F1TENTH_GYM
from shared.vehicle.identification import (
    Grid,
    fit_speed,
    jackknife_blocks,
    jackknife_sigma,
    timing_sigma,
)

#: The speed loop of the synthetic runs: gains [1/s] and delay [s] (off the 10 ms grid).
TRUTH = {"speed_gain_accel_per_s": 5.0, "speed_gain_brake_per_s": 15.0, "speed_delay_s": 0.034}


def _ar1(rng: np.random.Generator, n: int, rho: float) -> np.ndarray:
    """Unit-variance AR(1) noise of lag-1 correlation `rho`."""
    w = np.empty(n)
    x = 0.0
    for k in range(n):
        x = rho * x + math.sqrt(1.0 - rho * rho) * rng.normal()
        w[k] = x
    return w


def speed_run(seed: int, n: int = 3000, dt: float = 0.01, sub: int = 10) -> Grid:
    """`n` grid samples of a speed loop ``v' = k (v_cmd(t - T) - v)`` (``TRUTH``)
    integrated on `sub` sub-steps per grid step; the acceleration measured as the mean over
    the step that ends at its stamp (as the simulator's IMU) plus AR(1) errors (rho 0.98,
    0.3 m/s^2: a model error, not white noise); the speed with 2 mm/s white noise."""
    rng = np.random.default_rng(seed)
    h = dt / sub
    cmd = np.repeat(rng.uniform(2.0, 5.0, n // 100 + 1), 100)[:n]
    cmd_f = np.repeat(cmd, sub)
    lag = round(TRUTH["speed_delay_s"] / h)
    v = np.empty(n * sub + 1)
    v[0] = 3.0
    for k in range(n * sub):
        e = cmd_f[max(k - lag, 0)] - v[k]
        gain = TRUTH["speed_gain_accel_per_s"] if e > 0 else TRUTH["speed_gain_brake_per_s"]
        v[k + 1] = v[k] + h * gain * e
    v_end, v_start = v[sub::sub][:n], v[:-1:sub][:n]
    ax = (v_end - v_start) / dt + 0.3 * _ar1(rng, n, 0.98)
    z = np.zeros(n)
    return Grid(dt * np.arange(1, n + 1), cmd, z, v_end + 0.002 * rng.normal(size=n), z, z,
                ax, z, np.ones(n, dtype=bool), {"ax_mps2": dt, "speed_mps": dt})


@pytest.fixture(scope="module")
def speed_fits() -> list[dict]:
    base = F1TENTH_GYM.model_copy(update={"v_switch_mps": 100.0})  # no acceleration limit
    return [fit_speed(speed_run(seed), base)[0] for seed in range(3)]


def test_the_speed_loops_sigma_covers_the_truth(speed_fits: list[dict]) -> None:
    z_curv = []
    for est in speed_fits:
        for name, true in TRUTH.items():
            e = est[name]
            assert e.identifiable, name
            err = abs(e.value - true)
            assert err <= 3.0 * e.sigma, (name, e.value, e.sigma)
            z_curv.append(err / e.sigma_curvature)
            if name != "speed_delay_s":  # not absurdly large either: a few % of the gain
                assert e.sigma < 0.08 * true, (name, e.sigma)
    assert max(z_curv) > 3.0  # the curvature alone (the former sigma) claims too much


def test_the_delays_floor_is_the_grid_and_the_timing() -> None:
    g = speed_run(0, n=200)
    q = timing_sigma(g, "ax_mps2", "speed_mps", grid=True)
    assert q == pytest.approx(0.01 * math.sqrt(3.0 / 12.0))
    assert timing_sigma(g, "ax_mps2") == pytest.approx(0.01 / math.sqrt(12.0))


def test_the_block_jackknife_tells_the_spread_of_a_correlated_mean() -> None:
    """The mean of 2000 samples of AR(1) noise (rho 0.95): white-noise statistics claim a
    sigma 6 x too small; the 10-block jackknife's is right (median |mean| / sigma near
    0.67, 3 sigma covers nearly all)."""
    rng = np.random.default_rng(7)
    n, rho = 2000, 0.95
    blocks = jackknife_blocks(n)
    assert blocks[0] == 0 and blocks[-1] == 9 and np.all(np.diff(blocks) >= 0)
    z_jack, z_white = [], []
    for _ in range(300):
        x = _ar1(rng, n, rho)
        reps = np.array([x[blocks != b].mean() for b in range(10)])
        z_jack.append(abs(x.mean()) / float(jackknife_sigma(reps)))
        z_white.append(abs(x.mean()) / (x.std() / math.sqrt(n)))
    assert 0.5 < float(np.median(z_jack)) < 0.85
    assert np.mean(np.array(z_jack) <= 3.0) >= 0.97
    assert float(np.median(z_white)) > 3.0
