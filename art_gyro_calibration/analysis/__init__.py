"""The offline tools behind ``calibrate``: fit, trace, the calibration loop, simulation, reports, plots.

They need the pip extra ``analysis`` (scipy, matplotlib, threadpoolctl, rosbags) besides the node's runtime;
the runtime (:mod:`art_gyro_calibration` outside this subpackage) never imports from here.
"""
