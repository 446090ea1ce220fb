"""``imu_echo``'s stamps read as UTC time, not as an epoch float."""

from __future__ import annotations

import pytest

pytest.importorskip('rclpy')

from art_gyro_calibration.ros.monitor import stamp_text  # noqa: E402


def test_a_stamp_reads_as_utc_time_not_an_epoch_float() -> None:
    assert stamp_text(1_795_819_011, 137_907_979) == '2026-11-27T22:36:51.137907Z'
    assert stamp_text(0, 5_000) == '1970-01-01T00:00:00.000005Z'
