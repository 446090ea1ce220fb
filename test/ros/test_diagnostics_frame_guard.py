"""``ros.diagnostics``: frames the frame guard refused are an ERROR of the link when they are a large share."""

from __future__ import annotations

import pytest

pytest.importorskip('rclpy')

from test_diagnostics import ERROR, OK, StandInNode, frames  # noqa: E402

from art_gyro_calibration.frame_guard import RATE_JUMP, TEMPERATURE_JUMP  # noqa: E402
from art_gyro_calibration.ros.diagnostics import Diagnostics  # noqa: E402


def test_a_large_share_of_frames_refused_by_the_guard_is_a_link_error_naming_the_count_and_share() -> None:
    """Before: 30 of 130 frames refused (23 %) left the link OK."""
    node = StandInNode()
    Diagnostics(node)
    frames(node, 100)
    node.link(rejected_by_reason={RATE_JUMP: 20, TEMPERATURE_JUMP: 10})
    level, message = node.report()['link']
    assert level == ERROR and message.endswith('30 frames since the last report (23.1 % of those read) refused by '
                                               'the frame guard (a rate or temperature jump): corrupt frames that '
                                               'passed the checksum, a noisy link'), message
    frames(node, 1000)
    node.link(rejected_by_reason={RATE_JUMP: 25, TEMPERATURE_JUMP: 10})   # 5 of 1005: 0.5 %, within the share
    assert node.report()['link'][0] == OK
    frames(node, 1000)
    node.link(rejected_by_reason={RATE_JUMP: 25, TEMPERATURE_JUMP: 21})   # 11 of 1011: 1.1 %
    level, message = node.report()['link']
    assert level == ERROR and '11 frames since the last report (1.1 % of those read)' in message, message
