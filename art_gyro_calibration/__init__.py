"""Calibrated yaw rate from a KVH E-Core RD2100 fibre optic gyro, after ART's calibration report."""
