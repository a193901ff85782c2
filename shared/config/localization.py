"""Settings of the localization bridge (``[localization]``): how it turns pose (external or
from its own lidar particle filter), odometry and IMU into the ``state`` the planner starts
from (``services/localization_bridge``: ``ekf.py``, ``estimator.py``, ``service.py``)."""

from __future__ import annotations

from typing import Literal

from pydantic import Field, model_validator

from shared.config.base import Section
from shared.config.particle_filter import ParticleFilterSettings


class EkfNoise(Section):
    """Noise of the EKF (``[localization.noise]``): process noise as white-noise spectral
    densities (the variance added per second of prediction), measurement noise as standard
    deviations.

    Attributes:
        accel_psd: longitudinal acceleration noise q_a: var(v) grows q_a dt [m^2/s^3].
        yaw_accel_psd: yaw acceleration noise q_r: var(r) grows q_r dt [rad^2/s^3].
        position_psd: unmodelled lateral motion (slip): var(x), var(y) grow q_p dt [m^2/s].
        yaw_psd: unmodelled yaw motion: var(yaw) grows q_yaw dt [rad^2/s].
        bias_psd: gyro bias random walk q_b: var(b) grows q_b dt [rad^2/s^3].
        lateral_accel_psd: rear-axle lateral velocity (slip) random walk q_vy: var(vy) grows
            q_vy dt [m^2/s^3].
        pose_position_std_m: pose position std when ``Pose.cov`` is None [m].
        pose_yaw_std_rad: pose yaw std when ``Pose.cov`` is None [rad].
        speed_std_mps: wheel-odometry speed std [m/s].
        gyro_std_radps: IMU yaw-rate std [rad/s].
        odom_yaw_rate_std_radps: odometry yaw-rate std (when the source gives one) [rad/s].
        init_position_std_m, init_yaw_std_rad, init_speed_std_mps, init_yaw_rate_std_radps,
        init_bias_std_radps, init_lateral_std_mps: the covariance a (re-)initialisation starts from.
        min_pose_std_m, min_pose_yaw_std_rad: floor on a pose's own covariance (a localiser
            claiming millimetres must not freeze the filter) [m], [rad].
    """

    accel_psd: float = Field(4.0, gt=0.0, le=1e4, allow_inf_nan=False)
    yaw_accel_psd: float = Field(9.0, gt=0.0, le=1e4, allow_inf_nan=False)
    position_psd: float = Field(1e-4, ge=0.0, le=10.0, allow_inf_nan=False)
    yaw_psd: float = Field(1e-4, ge=0.0, le=10.0, allow_inf_nan=False)
    bias_psd: float = Field(1e-6, ge=0.0, le=1.0, allow_inf_nan=False)
    lateral_accel_psd: float = Field(1.0, gt=0.0, le=1e4, allow_inf_nan=False)
    pose_position_std_m: float = Field(0.02, gt=0.0, le=10.0, allow_inf_nan=False)
    pose_yaw_std_rad: float = Field(0.035, gt=0.0, le=3.2, allow_inf_nan=False)
    speed_std_mps: float = Field(0.05, gt=0.0, le=10.0, allow_inf_nan=False)
    gyro_std_radps: float = Field(0.02, gt=0.0, le=10.0, allow_inf_nan=False)
    odom_yaw_rate_std_radps: float = Field(0.1, gt=0.0, le=10.0, allow_inf_nan=False)
    init_position_std_m: float = Field(0.05, gt=0.0, le=100.0, allow_inf_nan=False)
    init_yaw_std_rad: float = Field(0.05, gt=0.0, le=3.2, allow_inf_nan=False)
    init_speed_std_mps: float = Field(0.5, gt=0.0, le=50.0, allow_inf_nan=False)
    init_yaw_rate_std_radps: float = Field(0.5, gt=0.0, le=50.0, allow_inf_nan=False)
    init_bias_std_radps: float = Field(0.02, gt=0.0, le=1.0, allow_inf_nan=False)
    init_lateral_std_mps: float = Field(0.2, gt=0.0, le=50.0, allow_inf_nan=False)
    min_pose_std_m: float = Field(0.002, gt=0.0, le=1.0, allow_inf_nan=False)
    min_pose_yaw_std_rad: float = Field(0.002, gt=0.0, le=1.0, allow_inf_nan=False)


class OpponentSettings(Section):
    """Opponents from the lidar (``[localization.opponents]``): the bridge's detector and
    tracker (``services/localization_bridge/opponents.py``) on every ``vehicle/scan``, with
    the bridge's fused pose and the lidar's mount of ``[localization.particle_filter]``
    (``lidar_x_m``, ``lidar_y_m``, ``lidar_yaw_rad``); one ``opponents`` record per scan, on
    its own worker (off the pose and state path).

    Attributes:
        enabled: None (default): on when the configuration races several cars (``[[cars]]``
            lists more than one), else off: alone on the track the detector would only cost
            the bridge CPU (about 0.3 ms of every 1080-beam scan, 8.6 -> 27.6 % of a core
            seen in a single-car race); True: track opponents whenever scans arrive (no
            scan, no ``opponents``); False: never.
        unexplained_m: a beam end farther than this from every wall of the map is a
            candidate opponent point [m].
        tracked_unexplained_m: ... and within half a metre of a car already tracked, this
            far (at least one map cell): a car on the racing line runs within centimetres
            of the wall at the apexes, and would be lost there [m].
        min_points: fewest points of a cluster that is a car.
        max_range_m: beams longer than this are ignored [m].
        confirm_hits: detections before a track is published.
        max_misses: scans in a row without a detection before a track is dropped (a scan
            that could not see the track, outside its fan or range or hidden behind a nearer
            return, counts none).
        max_coast_s: the longest a confirmed track the scans cannot see is kept since its
            last detection [s] (it keeps its id when it comes back into view).
        meas_std_m: position noise of a detection [m].
        accel_std_mps2: the tracker's white-acceleration noise [m/s^2].
        max_pose_age_s: no ``opponents`` from a scan when the fused pose is older than this
            against the scan (the map frame would be wrong) [s].
    """

    enabled: bool | None = None
    unexplained_m: float = Field(0.15, gt=0.0, le=2.0, allow_inf_nan=False)
    tracked_unexplained_m: float = Field(0.05, gt=0.0, le=2.0, allow_inf_nan=False)
    min_points: int = Field(4, ge=2, le=1000)
    max_range_m: float = Field(10.0, gt=0.0, le=100.0, allow_inf_nan=False)
    confirm_hits: int = Field(3, ge=1, le=100)
    max_misses: int = Field(8, ge=0, le=1000)
    max_coast_s: float = Field(1.0, ge=0.0, le=10.0, allow_inf_nan=False)
    meas_std_m: float = Field(0.02, gt=0.0, le=1.0, allow_inf_nan=False)
    accel_std_mps2: float = Field(8.0, gt=0.0, le=100.0, allow_inf_nan=False)
    max_pose_age_s: float = Field(0.25, gt=0.0, le=10.0, allow_inf_nan=False)


class LocalizationSettings(Section):
    """The bridge's tuning (``[localization]``, nested ``[localization.noise]`` and
    ``[localization.particle_filter]``, ``[localization.opponents]``).

    Attributes:
        filter: "ekf" (default: the fused, latency-compensated filter of ``ekf.py``) or
            "passthrough" (the newest pose predicted to now by a unicycle, ``fusion.py``:
            no filtering).
        pose_source: "external" (``vehicle/pose`` from a localiser or the simulator) or
            "lidar" (the bridge's own particle filter on ``vehicle/scan`` and the track's
            occupancy map).
        init: lidar: "start" (the filter starts at `initial_pose`, default the track's start
            pose) or "global" (particles over the free space).
        initial_pose: lidar, init = "start": [x m, y m, yaw rad] of the rear axle; None: the
            track's centreline at arc length `start_s_m`, heading along it.
        start_s_m: where the car starts, as arc length from the start line [m] (default: the
            simulator's start, its CoG 0.3 m past the line for the out lap, and the rear
            axle lr = 0.17 m behind the CoG).
        state_output: when ``state`` goes out: "on_pose" (default: at once when a pose, or
            the lidar's pose, is fused, so the planner solves from the newest pose) or
            "fixed_rate" (every ``1 / publish_rate_hz``, predicted to now: the old bridge).
        publish_rate_hz: rate of ``state`` with ``state_output = "fixed_rate"``; with
            "on_pose" the rate of the predicted fallback state while no pose has been fused
            for `fallback_after_s` [Hz].
        fallback_after_s: "on_pose": no state for this long (no pose fused) and the bridge
            publishes the prediction at `publish_rate_hz` until a pose is fused again; above
            the pose interval (25 ms at 40 Hz, 50 ms for the 20 Hz lidar) [s].
        history_s: measurements are kept this long for re-propagation; older stamps are
            rejected as stale [s].
        future_tolerance_s: stamps at most this far ahead of the bridge's clock are taken
            (clock skew); further ones are rejected as future [s].
        degraded_after_s: newest applied pose older than this: the estimate is degraded
            (said on ``events/log``, still valid) [s].
        invalid_after_s: ... older than this: ``valid = False`` (the planner brakes); the
            next pose re-initialises the filter [s].
        gate_chi2: Mahalanobis gate on the pose innovation (3 degrees of freedom; 16.27 is
            the 99.9 % quantile): a pose beyond it is counted, not applied.
        reinit_after_gated: this many consecutive gated poses that agree with each other
            (each within `reinit_agree_m` / `reinit_agree_rad` of the previous gated one)
            re-initialise the filter at the newest: the car really is elsewhere.
        reinit_agree_m, reinit_agree_rad: see `reinit_after_gated` [m], [rad].
        latency_compensation: True: measurements are applied at their stamps and the state
            re-propagated to now; False: each is applied at its arrival (benchmark only).
        max_input_age_s: passthrough: odometry / IMU older than this against the pose is not
            used; ekf: speed and yaw rate inputs older than this against now are not
            trusted beyond the process noise (no effect on the maths) [s].
        max_prediction_s: longest prediction from the newest measurement to now [s].
        pose_queue: poses kept waiting for the worker; 1 = only the newest. When the worker
            was late, it fuses every queued pose in order and sends the newest one's state
            (so a loaded machine or a garbage flood loses no valid pose) [messages].
        check_period_s: period of the main thread's watchdog: drop and fault reports on
            ``events/log`` [s].
        noise: the EKF's noise (``EkfNoise``).
        particle_filter: the lidar particle filter (``ParticleFilterSettings``).
        opponents: opponents from the lidar (``OpponentSettings``).
    """

    filter: Literal["ekf", "passthrough"] = "ekf"
    pose_source: Literal["external", "lidar"] = "external"
    init: Literal["start", "global"] = "start"
    initial_pose: tuple[float, float, float] | None = None
    start_s_m: float = Field(0.13, ge=-1e4, le=1e4, allow_inf_nan=False)
    state_output: Literal["on_pose", "fixed_rate"] = "on_pose"
    publish_rate_hz: float = Field(100.0, gt=0.0, le=1000.0, allow_inf_nan=False)
    fallback_after_s: float = Field(0.075, gt=0.0, le=10.0, allow_inf_nan=False)
    history_s: float = Field(0.5, gt=0.0, le=10.0, allow_inf_nan=False)
    future_tolerance_s: float = Field(0.05, ge=0.0, le=10.0, allow_inf_nan=False)
    degraded_after_s: float = Field(0.1, gt=0.0, le=60.0, allow_inf_nan=False)
    invalid_after_s: float = Field(0.25, gt=0.0, le=60.0, allow_inf_nan=False)
    gate_chi2: float = Field(16.27, gt=0.0, le=1e6, allow_inf_nan=False)
    reinit_after_gated: int = Field(10, ge=1, le=10_000)
    reinit_agree_m: float = Field(0.3, gt=0.0, le=100.0, allow_inf_nan=False)
    reinit_agree_rad: float = Field(0.3, gt=0.0, le=3.2, allow_inf_nan=False)
    latency_compensation: bool = True
    max_input_age_s: float = Field(0.25, gt=0.0, le=10.0, allow_inf_nan=False)
    max_prediction_s: float = Field(0.1, ge=0.0, le=1.0, allow_inf_nan=False)
    pose_queue: int = Field(4, ge=1, le=1000)
    check_period_s: float = Field(0.2, gt=0.0, le=10.0, allow_inf_nan=False)
    noise: EkfNoise = EkfNoise()
    particle_filter: ParticleFilterSettings = ParticleFilterSettings()
    opponents: OpponentSettings = OpponentSettings()

    @model_validator(mode="after")
    def _times_in_order(self) -> LocalizationSettings:
        if not self.degraded_after_s < self.invalid_after_s:
            raise ValueError("degraded_after_s must be below invalid_after_s")
        if self.initial_pose is not None and not all(
            abs(v) < 1e4 for v in self.initial_pose
        ):
            raise ValueError("initial_pose must be finite, |value| < 1e4")
        return self
