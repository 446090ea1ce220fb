"""Calibrated yaw rate from a KVH E-Core RD2100 fibre optic gyro, after ART's calibration report.

The runtime a robot installs (model, calibration files, static bias, compensation, signals,
terms, frames, driver, node, monitor, the simulated gyro) needs only rclpy, the ROS messages,
numpy, pyyaml and pyserial; the offline tools live in :mod:`art_gyro_calibration.analysis`.
"""
