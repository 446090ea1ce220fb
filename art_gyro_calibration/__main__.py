"""``python -m art_gyro_calibration``: the ``calibrate`` command."""

import sys

from art_gyro_calibration.analysis.cli import main

sys.exit(main())
