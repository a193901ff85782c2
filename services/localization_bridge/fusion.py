"""The transport-free core of the localization bridge (minimal: pass-through fusion).

``StateAssembler`` keeps the newest IMU and odometry and, for each new pose, builds the
``State`` the planner consumes: position and yaw from the pose (rear axle, map frame), speed
and steering from the wheel odometry, yaw rate from the IMU (or odometry). The state's
``source_stamp_s`` is the pose's capture stamp, so consumers can judge its age. A pose is
the only trigger; odometry or IMU older than ``max_input_age_s`` is not used. The tuning is
the ``[localization]`` section (``shared.config.localization.LocalizationSettings``).

Latency compensation: a pose describes the car at its capture instant, which is already
20-50 ms old when it arrives (localiser latency plus its rate). The state is the pose
predicted forward to the bridge's clock with the kinematic unicycle
``x += v cos(yaw) dt``, ``y += v sin(yaw) dt``, ``yaw += r dt`` (v from odometry, r the yaw
rate), ``dt = now - pose.stamp_s`` clipped to ``[0, max_prediction_s]``. ``source_stamp_s``
stays the pose's capture stamp, so consumers still see how old the information is.
The predicted position is kept inside the contract's position limits (a pose at the edge
of them may not be pushed beyond) and the yaw is wrapped into [-pi, pi)
(``shared.angles.wrap_angle``). This is ``[localization] filter = "passthrough"``; the
default EKF (``ekf.py``, ``estimator.py``) fuses all three.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from shared.angles import wrap_angle
from shared.config.localization import LocalizationSettings
from shared.messages import Imu, Odom, Pose, State
from shared.messages.records import MAX_POS_M

_DEFAULTS = LocalizationSettings()


@dataclass
class StateAssembler:
    """Combines the newest inputs into a State on every pose.

    Attributes:
        max_input_age_s: odometry/IMU older than this (against the pose stamp) is stale [s].
        max_prediction_s: longest forward prediction of a pose [s] (0 disables it).
    """

    max_input_age_s: float = _DEFAULTS.max_input_age_s
    max_prediction_s: float = _DEFAULTS.max_prediction_s
    odom: Odom | None = None
    imu: Imu | None = None

    @classmethod
    def from_settings(cls, settings: LocalizationSettings) -> StateAssembler:
        """An assembler tuned by the ``[localization]`` section."""
        return cls(
            max_input_age_s=settings.max_input_age_s, max_prediction_s=settings.max_prediction_s
        )

    def on_odom(self, msg: Odom) -> None:
        """Remember the newest wheel odometry."""
        self.odom = msg

    def on_imu(self, msg: Imu) -> None:
        """Remember the newest IMU sample."""
        self.imu = msg

    def on_pose(self, pose: Pose, stamp_s: float) -> State:
        """The state at this pose, stamped `stamp_s` (the bridge's clock) [s]."""
        odom_ok = self.odom is not None and pose.stamp_s - self.odom.stamp_s <= self.max_input_age_s
        imu_ok = self.imu is not None and pose.stamp_s - self.imu.stamp_s <= self.max_input_age_s
        speed = self.odom.speed_mps if odom_ok and self.odom else 0.0
        steering = self.odom.steering_rad if odom_ok and self.odom else 0.0
        if imu_ok and self.imu:
            yaw_rate = self.imu.yaw_rate_radps
        elif odom_ok and self.odom and self.odom.yaw_rate_radps is not None:
            yaw_rate = self.odom.yaw_rate_radps
        else:
            yaw_rate = 0.0
        dt = min(max(stamp_s - pose.stamp_s, 0.0), self.max_prediction_s)
        # second-order (midpoint) unicycle prediction over dt
        yaw_mid = pose.yaw_rad + 0.5 * yaw_rate * dt
        x = min(max(pose.x_m + speed * math.cos(yaw_mid) * dt, -MAX_POS_M), MAX_POS_M)
        y = min(max(pose.y_m + speed * math.sin(yaw_mid) * dt, -MAX_POS_M), MAX_POS_M)
        yaw = wrap_angle(pose.yaw_rad + yaw_rate * dt)
        return State(
            stamp_s=stamp_s,
            x_m=x,
            y_m=y,
            yaw_rad=yaw,
            speed_mps=speed,
            yaw_rate_radps=yaw_rate,
            steering_rad=steering,
            source_stamp_s=pose.stamp_s,
            valid=True,
        )
