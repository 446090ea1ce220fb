"""Unit conversions, named once: the package counts time in seconds and rates in deg/s.

People read a gyro's bias in deg/h and a log's length in hours; these turn one into the other.
"""

SECONDS_PER_HOUR = 3600.0
# A rate in deg/s times this is the rate in deg/h.
DEG_PER_H_PER_DPS = SECONDS_PER_HOUR
