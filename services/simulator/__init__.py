"""The simulator core: dynamic single-track car, actuation, sensors, lidar, lap timing.

No transport and no clock in here: callers pass time in. Entry points:

- ``Simulator(settings)``: ``reset(pose, speed_mps)``, ``step(command, dt_s) -> StepResult``,
  ``set_command(speed, steering, now_s)``;
- ``SensorSuite(settings, grid)``: ``update(step_result) -> SensorReadings``;
- ``LidarScanner(grid, ...)``: ``scan(x, y, yaw) -> ranges``;
- ``LapTimer(track, width_m, length_m)``: ``update(t, x, y, yaw, speed) -> [LapEvent]``.
"""

from services.simulator.actuators import CommandDelayLine, speed_control, steering_control
from services.simulator.dynamics import SingleTrackModel, TyreState
from services.simulator.integrate import rk4_step
from services.simulator.laps import LapEvent, LapTimer, centreline_pose
from services.simulator.lidar import LidarScanner, cast_on_boxes, distance_transform
from services.simulator.sensors import (
    ImuMeasurement,
    ImuSensor,
    LidarScan,
    LidarSensor,
    OdometryMeasurement,
    OdometrySensor,
    PoseMeasurement,
    PoseSensor,
    SensorReadings,
    SensorSuite,
)
from services.simulator.state import (
    NX,
    Command,
    Pose2D,
    StateIndex,
    VehicleState,
    rear_axle,
)
from services.simulator.vehicle import Simulator, StepResult

__all__ = [
    "NX",
    "Command",
    "CommandDelayLine",
    "ImuMeasurement",
    "ImuSensor",
    "LapEvent",
    "LapTimer",
    "LidarScan",
    "LidarScanner",
    "LidarSensor",
    "OdometryMeasurement",
    "OdometrySensor",
    "Pose2D",
    "PoseMeasurement",
    "PoseSensor",
    "SensorReadings",
    "SensorSuite",
    "Simulator",
    "SingleTrackModel",
    "StateIndex",
    "StepResult",
    "TyreState",
    "VehicleState",
    "cast_on_boxes",
    "centreline_pose",
    "distance_transform",
    "rear_axle",
    "rk4_step",
    "speed_control",
    "steering_control",
]
