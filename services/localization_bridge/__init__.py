"""Pose, IMU and wheel odometry in; one fused ``state`` out."""
