"""Settings of the lidar particle filter (``[localization.particle_filter]``), the car's own
localisation on the track's occupancy map (``services/localization_bridge/particle_filter.py``).

Frame: the filter estimates the REAR-AXLE pose in the map frame (the point and frame of
``vehicle/pose``). The lidar sits `lidar_x_m` ahead of the rear axle on the car's x axis; with
the simulator that is the simulated car's ``lr_m`` (``[vehicle]``, or ``[simulator.vehicle]``
when it overrides it) ``+ [simulator.lidar] mount_x_m`` (CoG to rear axle plus the mount ahead
of the CoG): 0.17145 + 0.0 m with the defaults.

Sensor model: a likelihood field (Thrun et al., Probabilistic Robotics, 6.4). Each used beam's
end point is looked up in a precomputed table of ``log(z_hit exp(-d^2 / (2 sigma^2)) + z_rand)``
with ``d`` the distance [m] from the end point to the nearest wall surface (from either side,
on a grid `field_upsample` times finer than the map); the particle's log likelihood is the sum
over the beams divided by `temperature`. Chosen over a beam model with ray casting because it
needs no ray casting at all (one table look-up per beam and particle, vectorised in numpy: no
numba and no per-map ray table to build or cache) and its log likelihood is smooth in the
pose. Beams without a return (``+inf``, >= `range_max_m`) carry no term.

The lateral noise grows with speed (`noise_lat_per_speed_rts`) because at racing lateral
accelerations the rear axle slides sideways (rear tyre slip) while the unicycle model moves it
only along its heading.
"""

from __future__ import annotations

from typing import Annotated

from pydantic import Field, model_validator

from shared.config.base import Section

Pos = Annotated[float, Field(gt=0.0, allow_inf_nan=False)]
NonNeg = Annotated[float, Field(ge=0.0, allow_inf_nan=False)]
Fraction = Annotated[float, Field(ge=0.0, le=1.0, allow_inf_nan=False)]


class ParticleFilterSettings(Section):
    """Particles, motion noise, sensor model, resampling, global initialisation and recovery.

    Motion noise is a random walk per predict step of length dt [s]: the along-track,
    lateral and yaw increments get white noise with standard deviations
    ``sqrt(dt) (a + b |v|)`` (position; v the odometry speed [m/s]) and
    ``sqrt(dt) (a + b |r|)`` (yaw; r the yaw rate [rad/s]), so the spread after a time T does
    not depend on how often `predict` is called.
    """

    particles: int = Field(
        1500, ge=100, le=100000, description="particles while tracking (after convergence)"
    )
    beams: int = Field(60, ge=4, le=2000, description="beams of each scan used (evenly spread)")
    lidar_x_m: float = Field(
        0.17145,
        ge=-2.0,
        le=2.0,
        description="lidar ahead of the rear axle along the car's x axis [m] (simulator: "
        "vehicle.lr_m + lidar.mount_x_m)",
    )
    lidar_y_m: float = Field(
        0.0, ge=-2.0, le=2.0, description="lidar left of the car's x axis [m]"
    )
    lidar_yaw_rad: float = Field(
        0.0, ge=-3.1416, le=3.1416, description="lidar x axis against the car's x axis [rad]"
    )
    range_min_m: NonNeg = Field(
        0.05, le=10.0, description="shorter ranges are not used (the car's own body) [m]"
    )
    range_max_m: Pos = Field(
        30.0, le=1000.0, description="ranges at or above are 'no return' and not used [m]"
    )
    # --- motion model (odometry speed + IMU yaw rate, unicycle at the rear axle)
    noise_long_m_rts: NonNeg = Field(
        0.005, le=10.0, description="along-track position noise a [m/sqrt(s)]"
    )
    noise_long_per_speed_rts: NonNeg = Field(
        0.01, le=10.0, description="along-track noise growth with speed b [sqrt(s)]"
    )
    noise_lat_m_rts: NonNeg = Field(
        0.005, le=10.0, description="lateral position noise a [m/sqrt(s)] (rear-axle slip)"
    )
    noise_lat_per_speed_rts: NonNeg = Field(
        0.1, le=10.0, description="lateral noise growth with speed b [sqrt(s)]"
    )
    noise_yaw_rad_rts: NonNeg = Field(
        0.01, le=10.0, description="yaw noise a [rad/sqrt(s)]"
    )
    noise_yaw_per_rate_rts: NonNeg = Field(
        0.05, le=10.0, description="yaw noise growth with the yaw rate b [sqrt(s)]"
    )
    # --- likelihood-field sensor model
    hit_sigma_m: Pos = Field(
        0.05, le=5.0, description="std of a beam end point about the wall while tracking [m]"
    )
    global_hit_sigma_m: Pos = Field(
        0.2, le=5.0, description="wider std used until the cloud has converged [m]"
    )
    z_hit: Fraction = Field(0.9, description="weight of the Gaussian hit term [-]")
    z_rand: Fraction = Field(
        0.1, description="weight of the uniform term (clutter, map errors) [-]"
    )
    temperature: float = Field(
        3.0,
        ge=1.0,
        le=1000.0,
        allow_inf_nan=False,
        description="log likelihood divided by this (beams are not independent) [-]",
    )
    field_cap_m: Pos = Field(
        1.0, le=10.0, description="distance field exact up to this; beyond reads as it [m]"
    )
    field_upsample: int = Field(
        2, ge=1, le=8, description="likelihood table cells per map cell edge (finer look-up)"
    )
    # --- resampling
    resample_n_eff_fraction: Fraction = Field(
        0.5, description="low-variance resampling when n_eff < this x particles [-]"
    )
    # --- initialisation
    init_std_xy_m: Pos = Field(0.3, le=10.0, description="init_pose cloud std of x and y [m]")
    init_std_yaw_rad: Pos = Field(0.2, le=3.2, description="init_pose cloud std of yaw [rad]")
    global_particles: int = Field(
        10000, ge=100, le=1000000, description="particles kept after a global initialisation"
    )
    global_candidates: int = Field(
        50000,
        ge=100,
        le=10000000,
        description="uniform poses scored against the first scan after init_global; the best "
        "global_particles are kept [-]",
    )
    global_beams: int = Field(
        24, ge=4, le=2000, description="beams used to score the global candidates"
    )
    free_clearance_m: NonNeg = Field(
        0.1, le=5.0, description="global / injected particles keep this from walls [m]"
    )
    unknown_is_occupied: bool = Field(True, description="unknown map cells count as walls")
    # --- convergence, lost and recovery (augmented MCL)
    converged_std_xy_m: Pos = Field(
        0.15, le=10.0, description="converged when the position std is below [m]"
    )
    converged_std_yaw_rad: Pos = Field(
        0.1, le=3.2, description="converged when the yaw std is below [rad]"
    )
    alpha_slow: float = Field(
        0.01, gt=0.0, le=1.0, allow_inf_nan=False, description="slow fitness average rate [-]"
    )
    alpha_fast: float = Field(
        0.2, gt=0.0, le=1.0, allow_inf_nan=False, description="fast fitness average rate [-]"
    )
    inject_min_fraction: Fraction = Field(
        0.1, description="random particles are injected only when 1 - fast/slow exceeds this"
    )
    inject_max_fraction: Fraction = Field(
        0.2, description="at most this fraction of particles is replaced per update [-]"
    )
    lost_fitness: Fraction = Field(
        0.5,
        description="lost when the fast fitness (the soft fraction of beams ending on a mapped "
        "wall at the estimate: mean of exp(-d^2 / (2 hit_sigma^2)), 1 = all) falls below it",
    )
    lost_reinit_scans: int = Field(
        40, ge=1, le=100000, description="lost for this many scans in a row: re-initialise "
        "(first near the last pose it tracked, local_reinit_radius_m; then init_global)"
    )
    local_reinit_radius_m: NonNeg = Field(
        2.0, le=100.0,
        description="lost: the first re-initialisation scores poses within this of the last "
        "pose the filter tracked, plus the odometry's distance since [m] (a car that spun "
        "is near where it spun; a global search on a 400 m map found another place); if it "
        "is lost again before tracking, init_global. 0: init_global at once",
    )

    @model_validator(mode="after")
    def _check(self) -> ParticleFilterSettings:
        if self.range_min_m >= self.range_max_m:
            raise ValueError("range_min_m must be below range_max_m")
        if not 0.0 < self.z_hit + self.z_rand <= 1.0 + 1e-9 or self.z_rand <= 0.0:
            raise ValueError("need z_rand > 0 and 0 < z_hit + z_rand <= 1")
        if self.alpha_slow >= self.alpha_fast:
            raise ValueError("alpha_slow must be below alpha_fast")
        if self.inject_min_fraction > self.inject_max_fraction:
            raise ValueError("inject_min_fraction must not exceed inject_max_fraction")
        return self
