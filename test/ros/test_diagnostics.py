"""``ros.diagnostics``: each status's level and message from the node's parts, without DDS.

A stand-in node (the :class:`~art_gyro_calibration.ros.diagnostics.DiagnosedNode` protocol) holds the real
calibration, frame corrector and signal feed; the reports are the messages its timer would publish.
"""

from __future__ import annotations

import math
from dataclasses import replace
from types import SimpleNamespace
from typing import Any

import pytest

pytest.importorskip('rclpy')

from builtin_interfaces.msg import Time  # noqa: E402
from diagnostic_msgs.msg import DiagnosticStatus  # noqa: E402

from art_gyro_calibration.calibration import load_packaged_calibration  # noqa: E402
from art_gyro_calibration.compensation import CLIPPED, IMPLAUSIBLE_TEMPERATURE, FrameCorrector  # noqa: E402
from art_gyro_calibration.driver import DriverStats  # noqa: E402
from art_gyro_calibration.frame import ProtocolDescription  # noqa: E402
from art_gyro_calibration.protocols import describe  # noqa: E402
from art_gyro_calibration.protocols.kvh_fog import KvhFogConfig  # noqa: E402
from art_gyro_calibration.ros.diagnostics import Diagnostics, SinceLastReport  # noqa: E402
from art_gyro_calibration.ros.parameters import ExtraSignal  # noqa: E402
from art_gyro_calibration.signals import SignalFeed  # noqa: E402
from art_gyro_calibration.static_bias import StaticBias  # noqa: E402

OK, WARN, ERROR, STALE = DiagnosticStatus.OK, DiagnosticStatus.WARN, DiagnosticStatus.ERROR, DiagnosticStatus.STALE


class StandInNode:
    """The parts and rclpy calls :class:`Diagnostics` reads; the published reports and console errors kept."""

    def __init__(self, description: ProtocolDescription = ProtocolDescription(),
                 extra: tuple[ExtraSignal, ...] = ()) -> None:
        self.settings = SimpleNamespace(log_path='', bias_samples=100)
        self.description = description
        self.calibration = load_packaged_calibration('NAVC4058')   # temperature_warn_range_c 10..50 degC
        self.corrector = FrameCorrector(self.calibration)
        self.driver = SimpleNamespace(stats=DriverStats(frames=0, rejected=0, rejected_by_reason={}, bytes_skipped=0,
                                                        reopens=0, connected=True, last_error='', port='/dev/ttyUSB0'))
        self.bias_service = SimpleNamespace(state=lambda: ('none', StaticBias(0.0, 0.0, 0, 0.0), '', 0.0, 0),
                                            signal_problems=lambda: '', parked_state=lambda: None)
        self.raw_log = None
        self.published = 0
        self.last_temp_c = math.nan
        self.extra_signals = extra
        self.clock_s = 100.0
        self.feeds = tuple(SignalFeed(e.signal, e.max_age_s, lambda: self.clock_s) for e in extra)
        self.extra_topics = tuple(f'/{e.topic}' for e in extra)
        self.reports: list[Any] = []
        self.errors: list[str] = []
        self.timer: Any = None

    def get_clock(self) -> Any:
        return SimpleNamespace(now=lambda: SimpleNamespace(to_msg=Time))

    def get_logger(self) -> Any:
        return SimpleNamespace(error=lambda message, **_: self.errors.append(message))

    def get_fully_qualified_name(self) -> str:
        return '/gyro'

    def create_publisher(self, *args: Any, **kwargs: Any) -> Any:
        return SimpleNamespace(publish=self.reports.append)

    def create_timer(self, period_s: float, callback: Any, **kwargs: Any) -> Any:
        self.timer = callback
        return None

    def get_publishers_info_by_topic(self, topic_name: str) -> list[Any]:
        return []

    def link(self, **changes: Any) -> None:
        """The driver's next snapshot of its counters and link state."""
        self.driver.stats = replace(self.driver.stats, **changes)

    def report(self) -> dict[str, tuple[bytes, str]]:
        """One report as the timer publishes it: (level, message) by status name, without the node's prefix."""
        self.timer()
        return {s.name.removeprefix('/gyro: '): (s.level, s.message) for s in self.reports[-1].status}


def frames(node: StandInNode, count: int) -> None:
    node.link(frames=node.driver.stats.frames + count)
    node.published += count


def test_since_last_report_tells_each_growth_once() -> None:
    told = SinceLastReport()
    assert [told.take(5), told.take(7), told.take(7), told.take(10)] == [5, 2, 0, 3]


def test_the_link_reports_frames_a_silence_a_glitch_since_the_last_report_and_a_disconnection() -> None:
    node = StandInNode()
    Diagnostics(node)
    frames(node, 10)
    level, message = node.report()['link']
    assert level == OK and message.startswith('connected, ') and message.endswith(' Hz')
    assert node.report()['link'] == (WARN, 'connected, no frames')
    frames(node, 10)
    node.corrector.dropped[CLIPPED] += 2
    level, message = node.report()['link']
    assert level == ERROR and message.endswith('frames not published since the last report: 2 clipped')
    frames(node, 10)
    assert node.report()['link'][0] == OK   # the glitch was told; the running total stays in the values only
    frames(node, 10)
    node.link(lost_frames=3)
    level, message = node.report()['link']
    assert level == WARN and message.endswith('since the last report 3 frames lost (sequence gaps), 0 flagged '
                                              'invalid by the gyro')
    node.link(connected=False, last_error='port vanished')
    assert node.report()['link'] == (ERROR, 'disconnected: port vanished')


def test_a_unit_sending_at_another_rate_than_its_parameter_is_an_error_said_on_the_console_too() -> None:
    description = describe('kvh_fog', KvhFogConfig(output_rate_hz=1000.0))
    node = StandInNode(description)
    Diagnostics(node)
    frames(node, 200)
    node.link(measured_rate_hz=200.0)
    level, message = node.report()['link']
    assert level == ERROR and message == description.rate_error(200.0) and message
    assert node.errors == [message]
    node.link(measured_rate_hz=1000.0)
    frames(node, 200)
    assert node.report()['link'][0] == OK


def test_the_temperature_stale_then_inside_outside_the_range_and_implausible() -> None:
    node = StandInNode()
    Diagnostics(node)
    assert node.report()['temperature'] == (STALE, 'no frame yet')
    node.last_temp_c = 30.0
    assert node.report()['temperature'] == (OK, '30.00 degC')
    node.corrector.compensator.outside_range += 4   # frames since the last report, now back inside
    level, message = node.report()['temperature']
    assert level == WARN and message.startswith('30.00 degC; 4 frames since the last report were outside the '
                                                'calibrated range 10.0..50.0 degC (temperature_warn_range_c')
    assert node.report()['temperature'] == (OK, '30.00 degC')
    node.last_temp_c = 60.0
    level, message = node.report()['temperature']
    assert level == WARN and message.startswith('60.00 degC is outside the calibrated range 10.0..50.0 degC')
    node.corrector.dropped[IMPLAUSIBLE_TEMPERATURE] += 2
    level, message = node.report()['temperature']
    assert level == ERROR and '2 frames since the last report claimed a temperature outside' in message
    assert message.endswith(node.description.temperature_hint)


def test_an_extra_signal_is_an_error_until_its_first_value_and_once_stale() -> None:
    node = StandInNode(extra=(ExtraSignal('supply_v', 'battery', 'battery_state', 5.0),))
    Diagnostics(node)
    level, message = node.report()['extra signal supply_v']
    assert level == ERROR and ' on /battery: its terms are left out and no static bias is taken' in message
    node.feeds[0].put(24.5)
    assert node.report()['extra signal supply_v'] == (OK, '24.5')
    node.clock_s += 6.0
    level, message = node.report()['extra signal supply_v']
    assert level == ERROR and 'the last value is applied' in message
    node.feeds[0].put(math.nan)
    node.feeds[0].put(24.0)
    level, message = node.report()['extra signal supply_v']
    assert level == WARN and message == '24 (the last finite value); 1 values not finite since the last report, ignored'


def test_every_status_names_the_node_and_the_gyro() -> None:
    node = StandInNode(replace(ProtocolDescription(), hardware='KVH DSP-1760'))
    Diagnostics(node)
    node.timer()
    statuses = node.reports[-1].status
    assert [s.name for s in statuses] == ['/gyro: link', '/gyro: static bias', '/gyro: temperature']
    assert {s.hardware_id for s in statuses} == {'KVH DSP-1760 NAVC4058'}
