"""Pose (external, or from the bridge's own lidar particle filter), IMU and wheel odometry
in; one fused, latency-compensated ``state`` out.

What tools (the bench, benchmarks, tests) use (``__all__``): the EKF over a measurement
history (``FusedEstimator`` -> ``Estimate``, ``Verdict``), the lidar pose source
(``LidarPoseSource``, ``start_pose``, ``ScanPose``), the scan checks (``scan_problem``,
``ScanLayout``), the particle filter (``ParticleFilter``, ``PfEstimate``) and the opponents'
detector and tracker (``OpponentDetector``, ``OpponentTracker``).
"""

from services.localization_bridge.estimator import Estimate, FusedEstimator, Verdict
from services.localization_bridge.lidar_pose import LidarPoseSource, ScanPose, start_pose
from services.localization_bridge.opponents import OpponentDetector, OpponentTracker, ScanView
from services.localization_bridge.particle_filter import (
    FilterMap,
    ParticleFilter,
    PfEstimate,
    map_settings,
)
from services.localization_bridge.scan_check import ScanLayout, scan_problem

__all__ = [
    "Estimate",
    "FilterMap",
    "FusedEstimator",
    "LidarPoseSource",
    "OpponentDetector",
    "OpponentTracker",
    "ParticleFilter",
    "PfEstimate",
    "ScanLayout",
    "ScanPose",
    "ScanView",
    "Verdict",
    "map_settings",
    "scan_problem",
    "start_pose",
]
