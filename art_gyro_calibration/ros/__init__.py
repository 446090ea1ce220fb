"""The rclpy layer of ``gyro_node``: parameters, the static bias service, the raw log, diagnostics, the node.

Only what needs ROS lives here; the per-frame correction is the core's
(:class:`art_gyro_calibration.compensation.FrameCorrector`).
"""
