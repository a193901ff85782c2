"""Spins: the rear axle's slip angle far beyond its tyres' peak for a while (pure, numpy).

Read by the robustness benchmark (a cell's ``spins``) and ``racestack tune`` (a spin makes a
trial infeasible).
"""

from __future__ import annotations

from collections.abc import Iterable

import numpy as np

from shared.config.vehicle import DynamicVehicleParams
from shared.vehicle.tyres import pacejka_peak_slip_rad

#: A spin: the rear slip angle beyond ``SPIN_SLIP_FACTOR`` x the tyres' peak slip for longer
#: than this [s].
SPIN_MIN_DURATION_S = 0.2
#: The margin over the peak slip a spin needs. ``linear_saturated`` tyres keep their force flat
#: beyond the peak, so cornering at the friction limit holds the rear slip just past it: clean
#: laps (no off-track event, no recovery) on map416 and paperlike reach 1.04-1.28 x the peak for
#: seconds, while the laps that spin off the track reach 18 x (python -m benchmarks.robustness
#: --tracks map416,paperlike --cars default,identified --poses truth, 2026-12-02).
SPIN_SLIP_FACTOR = 1.5


def rear_peak_slip_rad(car: DynamicVehicleParams, lap_rear_slip: float | None = None) -> float:
    """The slip angle [rad] at which the rear tyres give their peak lateral force: the
    magic formula's peak (``pacejka``), else ``1 / C_Sr``, where ``mu C_Sr F_z alpha``
    reaches ``mu F_z`` (``linear_saturated``'s clip).

    The gym's unbounded ``linear`` tyres have no peak: their force grows with the slip, and
    the car's own minimum-time lap (no friction limit, ``mintime.ocp``) asks for 3.6 x
    ``1 / C_Sr`` at the rear in the hairpins of gen:1 and gen:3. For them the reference is
    `lap_rear_slip` [rad] (the largest rear slip of the car's limit lap) when given and
    larger: a spin is then a slide well beyond what racing at the car's limit needs."""
    if car.tyre_model == "pacejka":
        return pacejka_peak_slip_rad(car, "rear")
    peak = 1.0 / car.cornering_stiffness_rear_per_rad
    if car.tyre_model == "linear" and lap_rear_slip is not None:
        return max(peak, float(lap_rear_slip))
    return peak


def spin_events(
    t_s: Iterable[float],
    slip_rad: Iterable[float],
    peak_rad: float,
    min_duration_s: float = SPIN_MIN_DURATION_S,
    factor: float = SPIN_SLIP_FACTOR,
) -> int:
    """Times |slip| stayed beyond `factor` x `peak_rad` for more than `min_duration_s` [s].

    A run of samples beyond the peak lasts from its first sample to the next sample after
    it (the last run of the trace: one median sample period past its last sample)."""
    t = np.asarray(list(t_s), dtype=float)
    over = np.abs(np.asarray(list(slip_rad), dtype=float)) > factor * peak_rad
    if t.size == 0 or over.size != t.size or not over.any():
        return 0
    period = float(np.median(np.diff(t))) if t.size > 1 else 0.0
    edges = np.diff(np.concatenate([[0], over.astype(np.int8), [0]]))
    starts, ends = np.flatnonzero(edges == 1), np.flatnonzero(edges == -1)  # ends exclusive
    count = 0
    for a, b in zip(starts, ends, strict=True):
        t_end = t[b] if b < t.size else t[-1] + period
        count += bool(t_end - t[a] > min_duration_s + 1e-9)
    return count
