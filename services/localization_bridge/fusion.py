"""The transport-free core of the localization bridge (minimal: pass-through fusion).

``StateAssembler`` keeps the newest IMU and odometry and, for each new pose, builds the
``State`` the planner consumes: position and yaw from the pose (rear axle, map frame), speed
and steering from the wheel odometry, yaw rate from the IMU (or odometry). The state's
``source_stamp_s`` is the pose's capture stamp, so consumers can judge its age. A pose is
the only trigger; odometry or IMU older than ``max_input_age_s`` is not used (the state is
then marked invalid until they return). Latency compensation and an EKF come later.
"""

from __future__ import annotations

from dataclasses import dataclass

from shared.messages import Imu, Odom, Pose, State


@dataclass
class StateAssembler:
    """Combines the newest inputs into a State on every pose.

    Attributes:
        max_input_age_s: odometry/IMU older than this (against the pose stamp) is stale [s].
    """

    max_input_age_s: float = 0.25
    odom: Odom | None = None
    imu: Imu | None = None

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
        return State(
            stamp_s=stamp_s,
            x_m=pose.x_m,
            y_m=pose.y_m,
            yaw_rad=pose.yaw_rad,
            speed_mps=speed,
            yaw_rate_radps=yaw_rate,
            steering_rad=steering,
            source_stamp_s=pose.stamp_s,
            valid=True,
        )
