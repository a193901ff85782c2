"""Settings of the localization bridge (``[localization]``): how it turns pose, odometry and
IMU into the ``state`` the planner starts from (``services/localization_bridge``)."""

from __future__ import annotations

from pydantic import Field

from shared.config.base import Section


class LocalizationSettings(Section):
    """The bridge's tuning; the defaults are the values it always had.

    Attributes:
        max_input_age_s: odometry or IMU older than this against the pose's stamp is not
            used (speed, steering and yaw rate then count as 0) [s].
        max_prediction_s: longest forward prediction of a pose to the bridge's clock
            (latency compensation; 0 disables it) [s].
        pose_queue: poses kept waiting for the worker; 1 = only the newest (older ones
            are dropped and show up as sequence gaps) [messages].
        check_period_s: period of the main thread's watchdog: drop and fault reports on
            ``events/log`` [s].
    """

    max_input_age_s: float = Field(0.25, gt=0.0, le=10.0, allow_inf_nan=False)
    max_prediction_s: float = Field(0.1, ge=0.0, le=1.0, allow_inf_nan=False)
    pose_queue: int = Field(1, ge=1, le=1000)
    check_period_s: float = Field(0.2, gt=0.0, le=10.0, allow_inf_nan=False)
