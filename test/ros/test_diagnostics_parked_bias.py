"""``ros.diagnostics``: the ``parked bias`` status (taken, the last one's age, refusals by reason), without DDS."""

from __future__ import annotations

import math
from typing import Any

import pytest

pytest.importorskip('rclpy')

from test_diagnostics import OK, StandInNode  # noqa: E402

from art_gyro_calibration.parked import REFUSALS  # noqa: E402
from art_gyro_calibration.ros.bias_service import ParkedState  # noqa: E402
from art_gyro_calibration.ros.diagnostics import Diagnostics  # noqa: E402


def parked_status(node: StandInNode) -> dict[str, Any]:
    node.timer()
    (status,) = [s for s in node.reports[-1].status if s.name == '/gyro: parked bias']
    return {'level': status.level, 'message': status.message, **{kv.key: kv.value for kv in status.values}}


def test_no_status_unless_enabled_then_the_updates_their_age_and_refusals_by_reason() -> None:
    node = StandInNode()
    Diagnostics(node)
    node.timer()
    assert not [s for s in node.reports[-1].status if s.name.endswith('parked bias')]
    refused = dict.fromkeys(REFUSALS, 0)
    node.bias_service.parked_state = lambda: ParkedState(True, True, 0, math.inf, refused, '')
    status = parked_status(node)
    assert (status['level'], status['message']) == (OK, '0 taken (none yet), 0 refused, collecting')
    assert (status['parked'], status['state'], status['age_s']) == ('True', 'collecting', 'none')
    refused.update(moved=2, mean=1)
    node.bias_service.parked_state = lambda: ParkedState(
        False, False, 3, 42.4, refused, 'mean: mean compensated rate +0.04880 deg/s exceeds 0.00913 deg/s')
    status = parked_status(node)
    assert status['message'] == '3 taken (last 42 s ago), 3 refused'
    assert (status['updates'], status['age_s'], status['refused'], status['refused_moved'],
            status['refused_mean'], status['refused_stale']) == ('3', '42', '3', '2', '1', '0')
    assert status['last_refusal'].startswith('mean: ')
