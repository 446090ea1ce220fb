"""The node's ``/diagnostics`` (1 Hz): link, static bias, temperature, each extra signal, the raw log if logging.

A glitch between two reports (frames lost, dropped, outside the calibrated range) must show
in the next one, not only in a running total: each such count is told "since the last
report" by a :class:`SinceLastReport`.
"""

from __future__ import annotations

import math
import time
from typing import Any, Protocol

# The message wheels ship no type hints.
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue   # type: ignore[import-untyped]
from rclpy.callback_groups import MutuallyExclusiveCallbackGroup
from rclpy.clock import Clock
from rclpy.publisher import Publisher
from rclpy.timer import Timer
from rclpy.topic_endpoint_info import TopicEndpointInfo

from art_gyro_calibration.calibration import PLAUSIBLE_TEMPERATURE_C, Calibration
from art_gyro_calibration.compensation import IMPLAUSIBLE_TEMPERATURE, FrameCorrector
from art_gyro_calibration.driver import DriverStats, SerialGyroDriver
from art_gyro_calibration.frame import AXIS_INVALID, NOT_FINITE, ProtocolDescription
from art_gyro_calibration.frame_guard import GUARD_REASONS
from art_gyro_calibration.ros.bias_service import ParkedState, StaticBiasService
from art_gyro_calibration.ros.parameters import EXTRA_SIGNAL_MESSAGES, ExtraSignal, Settings, ros_type_name
from art_gyro_calibration.ros.raw_log import LOG_RETRY_S, RawLog
from art_gyro_calibration.ros.rclpy_typed import Logger
from art_gyro_calibration.signals import SignalFeed

DIAGNOSTICS_PERIOD_S = 1.0
RATE_MISMATCH_CONSOLE_PERIOD_S = 60.0   # the console repeats a wrong output rate parameter this often
# Frames the frame guard refused beyond this share of those read since the last report: the link is an ERROR (a
# corrupting link whose corrupt frames pass the checksum, or motion the guard mistakes; each refused is lost).
GUARD_REFUSED_SHARE = 0.01


class DiagnosedNode(Protocol):
    """What the statuses read of the gyro node: its parts, and the rclpy calls that publish them."""

    settings: Settings
    description: ProtocolDescription    # the gyro's protocol, beyond its frames
    calibration: Calibration
    corrector: FrameCorrector
    driver: SerialGyroDriver
    bias_service: StaticBiasService
    raw_log: RawLog
    published: int
    last_temp_c: float
    extra_signals: tuple[ExtraSignal, ...]
    feeds: tuple[SignalFeed, ...]       # one per extra signal
    extra_topics: tuple[str, ...]       # their resolved topic names

    def get_clock(self) -> Clock:
        """The node's clock: the stamp of each report."""

    def get_logger(self) -> Logger:
        """The node's logger: a wrong output rate is said on the console too."""

    def get_fully_qualified_name(self) -> str:
        """The node's name with its namespace: the prefix of each status."""

    def create_publisher(self, *args: Any, **kwargs: Any) -> Publisher:
        """``/diagnostics``' publisher."""

    def create_timer(self, *args: Any, **kwargs: Any) -> Timer:
        """The 1 Hz timer of the reports."""

    def get_publishers_info_by_topic(self, topic_name: str) -> list[TopicEndpointInfo]:
        """Who publishes an extra signal's topic, and its type (a wrong extra_signals.<signal>.type)."""


class SinceLastReport:
    """A running total's part that the last report has not told yet."""

    __slots__ = ('_told',)

    def __init__(self) -> None:
        self._told = 0

    def take(self, total: int) -> int:
        """How much ``total`` grew since the last call (the first: since 0); now told."""
        new, self._told = total - self._told, total
        return new


class Diagnostics:
    """Publishes the statuses of ``node`` on a timer of its own."""

    def __init__(self, node: DiagnosedNode) -> None:
        """Reads ``node``'s settings, calibration, corrector, driver, static bias service and raw log."""
        self._node = node
        self._window_start = time.monotonic()
        self._frames = SinceLastReport()
        self._dropped = {reason: SinceLastReport() for reason in node.corrector.dropped}
        self._lost = SinceLastReport()                # gaps in the gyro's sequence numbers (kvh_fog numbers them)
        self._guarded = SinceLastReport()             # frames the frame guard refused
        self._invalid = SinceLastReport()             # frames the gyro flagged invalid (AXIS_INVALID)
        self._outside_range = SinceLastReport()       # frames outside the expected range (Compensator.outside_range)
        self._implausible = SinceLastReport()
        self._beyond_unit_range = SinceLastReport()   # corrected rates beyond the unit's range (published uncorrected)
        self._not_finite = [SinceLastReport() for _ in node.feeds]   # per extra signal: values refused
        self._pub = node.create_publisher(DiagnosticArray, '/diagnostics', 10)
        group = MutuallyExclusiveCallbackGroup()   # type: ignore[no-untyped-call]  # rclpy: __init__ unannotated
        node.create_timer(DIAGNOSTICS_PERIOD_S, self._publish, callback_group=group)

    def _publish(self) -> None:
        node = self._node
        msg = DiagnosticArray()
        msg.header.stamp = node.get_clock().now().to_msg()
        msg.status = [self._link_status(), self._bias_status(), self._temperature_status(),
                      *map(self._extra_signal_status, node.extra_signals, node.feeds, node.extra_topics,
                           self._not_finite)]
        parked = node.bias_service.parked_state()
        if parked is not None:
            msg.status.append(self._parked_status(parked))
        if node.settings.log_path:
            node.raw_log.check_file()
            msg.status.append(self._log_status())
        self._pub.publish(msg)

    def _status(self, name: str, level: bytes, message: str, values: dict[str, Any]) -> DiagnosticStatus:
        node = self._node
        # The fully qualified name: two gyros in two namespaces report apart.
        return DiagnosticStatus(level=level, name=f'{node.get_fully_qualified_name()}: {name}', message=message,
                                hardware_id=f'{node.description.hardware} {node.calibration.serial_number}',
                                values=[KeyValue(key=k, value=str(v)) for k, v in values.items()])

    def _link_status(self) -> DiagnosticStatus:
        stats = self._node.driver.stats
        corrector = self._node.corrector
        now = time.monotonic()
        then, self._window_start = self._window_start, now
        frames = self._frames.take(stats.frames)
        rate_hz = frames / (now - then) if now > then else 0.0
        values: dict[str, Any] = {
            'port': stats.port, 'connected': stats.connected, 'reopens': stats.reopens,
            'last_error': stats.last_error, 'frame_rate_hz': f'{rate_hz:.2f}', 'frames': stats.frames,
            'rejected': stats.rejected, 'bytes_skipped': stats.bytes_skipped, 'published': self._node.published,
            'lost_frames': stats.lost_frames}
        for reason, count in stats.rejected_by_reason.items():
            values[f'rejected_{reason}'] = count
        # Frames read but not published, per reason: since the last report, and in all.
        dropped = dict(corrector.dropped)
        recent = {reason: self._dropped[reason].take(count) for reason, count in dropped.items()}
        values['dropped'] = sum(dropped.values())
        for reason, count in dropped.items():
            values[f'dropped_{reason}'] = count
        if dropped[NOT_FINITE]:
            values['last_not_finite_error'] = corrector.last_drop_error or 'a non-finite compensated rate'
        # Frames the gyro numbered but that never came, and frames it flagged invalid, since the last report.
        compensator = corrector.compensator
        values['corrected_beyond_range'] = compensator.beyond_unit_range
        beyond = self._beyond_unit_range.take(compensator.beyond_unit_range)
        lost = self._lost.take(stats.lost_frames)
        flagged = self._invalid.take(stats.rejected_by_reason.get(AXIS_INVALID, 0))
        guarded = self._guarded.take(sum(stats.rejected_by_reason.get(reason, 0) for reason in GUARD_REASONS))
        if not stats.connected:
            return self._status('link', DiagnosticStatus.ERROR, f'disconnected: {stats.last_error}', values)
        mismatch = self._rate_error(stats, values)
        if mismatch:
            return self._status('link', DiagnosticStatus.ERROR, mismatch, values)
        if rate_hz == 0.0:
            return self._status('link', DiagnosticStatus.WARN, 'connected, no frames', values)
        if beyond:
            span = self._node.calibration.rate_range_dps
            return self._status('link', DiagnosticStatus.ERROR, f'connected, {rate_hz:.1f} Hz; {beyond} corrected '
                                f'rates since the last report beyond the unit\'s range +-{span:g} deg/s (the last '
                                f'{compensator.last_beyond_dps:+.6g} deg/s): published uncorrected, flagged '
                                '(covariance)', values)
        if guarded > GUARD_REFUSED_SHARE * (frames + guarded):
            return self._status('link', DiagnosticStatus.ERROR, f'connected, {rate_hz:.1f} Hz; {guarded} frames '
                                f'since the last report ({100 * guarded / (frames + guarded):.1f} % of those read) '
                                'refused by the frame guard (a rate or temperature jump): corrupt frames that passed '
                                'the checksum, a noisy link', values)
        # An implausible temperature is the temperature status's ERROR; the others would show nowhere else.
        if any(count for reason, count in recent.items() if reason != IMPLAUSIBLE_TEMPERATURE):
            not_published = ', '.join(f'{count} {reason}' for reason, count in recent.items() if count)
            return self._status('link', DiagnosticStatus.ERROR, f'connected, {rate_hz:.1f} Hz; frames not '
                                f'published since the last report: {not_published}', values)
        if lost or flagged:
            return self._status('link', DiagnosticStatus.WARN,
                                f'connected, {rate_hz:.1f} Hz; since the last report {lost} frames lost (sequence '
                                f'gaps), {flagged} flagged invalid by the gyro', values)
        return self._status('link', DiagnosticStatus.OK, f'connected, {rate_hz:.1f} Hz', values)

    def _rate_error(self, stats: DriverStats, values: dict[str, Any]) -> str:
        """A unit whose rate is measured: its values added; why its set output rate is wrong (also said), or ''."""
        node = self._node
        if not node.description.reports_rate:
            return ''
        measured = stats.measured_rate_hz
        values['measured_rate_hz'] = 'not yet' if measured is None else f'{measured:.3f}'
        values['garbage_runs'] = stats.garbage_runs
        values['stamp_source'] = stats.stamp_source
        message = node.description.rate_error(measured)
        if message:
            node.get_logger().error(message, throttle_duration_sec=RATE_MISMATCH_CONSOLE_PERIOD_S)
        return message

    def _log_status(self) -> DiagnosticStatus:
        log = self._node.raw_log.state()
        values = {'file': log.file, 'rows_not_logged': log.rows_not_logged, 'last_error': log.last_error}
        if not log.logging:
            return self._status('raw log', DiagnosticStatus.ERROR,
                                f'not logging: {log.last_error}; retrying every {LOG_RETRY_S:g} s', values)
        return self._status('raw log', DiagnosticStatus.OK, f'logging to {log.file}', values)

    def _bias_status(self) -> DiagnosticStatus:
        node = self._node
        state, bias, refusal, bias_time, collected = node.bias_service.state()
        values: dict[str, Any] = {
            'state': state, 'static_bias_drift_dps': f'{bias.static_bias_drift_dps:.6f}',
            'calc_static_bias_drift_dps': f'{bias.calc_static_bias_drift_dps:.6f}',
            'samples': bias.samples, 'rate_std_dps': f'{bias.rate_std_dps:.6f}',
            'age_s': f'{time.monotonic() - bias_time:.0f}' if bias.samples else 'none',
            # The temperature-rate refinement: pending while the bias window is kept, then its change.
            'refinement': ('pending' if bias.window is not None and node.corrector.compensator.refinable
                           else f'{bias.refined_dps:+.6f} dps' if bias.refined_dps else 'none'),
            'last_refusal': refusal}
        if state == 'collecting':
            progress = f'{collected}/{node.settings.bias_samples}'
            waiting = node.bias_service.signal_problems()   # frames are taken only with every extra signal current
            return self._status('static bias', DiagnosticStatus.OK,
                                f'collecting ({progress})' + (f', waiting: {waiting}' if waiting else ''), values)
        if state == 'ok':
            return self._status('static bias', DiagnosticStatus.OK, bias.describe(), values)
        if state == 'refused':
            kept = 'previous bias kept' if bias.samples else 'no bias applied'
            return self._status('static bias', DiagnosticStatus.WARN, f'refused ({refusal}); {kept}',
                                values)
        return self._status('static bias', DiagnosticStatus.WARN,
                            'none: call imu/static_bias with the gyro still', values)

    def _parked_status(self, parked: ParkedState) -> DiagnosticStatus:
        """The parked bias: the last update, its age, the refusals by reason."""
        refused = sum(parked.refused.values())
        values: dict[str, Any] = {
            'parked': parked.parked, 'state': 'collecting' if parked.collecting else 'waiting',
            'updates': parked.updates, 'age_s': f'{parked.age_s:.0f}' if parked.updates else 'none',
            'refused': refused, **{f'refused_{reason}': n for reason, n in parked.refused.items()},
            'last_refusal': parked.last_refusal}
        last = f'last {parked.age_s:.0f} s ago' if parked.updates else 'none yet'
        return self._status('parked bias', DiagnosticStatus.OK,
                            f'{parked.updates} taken ({last}), {refused} refused'
                            + (', collecting' if parked.collecting else ''), values)

    def _extra_signal_status(self, extra: ExtraSignal, feed: SignalFeed, topic: str,
                             not_finite: SinceLastReport) -> DiagnosticStatus:
        """A signal from outside the gyro: ERROR while it has no current value, or one beyond its limits (flagged)."""
        latest = feed.latest
        values = {'topic': topic, 'type': extra.type, 'value': 'none' if latest is None else f'{latest[0]:g}',
                  'age_s': 'none' if latest is None else f'{feed.clock() - latest[1]:.1f}',
                  'max_age_s': extra.max_age_s, 'received': feed.received, 'not_finite': feed.not_finite}
        calibration = self._node.calibration
        if extra.signal in calibration.signal_ranges:
            low, high = calibration.signal_limits(extra.signal)
            values['limits'] = f'{low:g}..{high:g}'
            values['beyond_limits'] = self._node.corrector.compensator.beyond_limits[self._node.feeds.index(feed)]
        refused = not_finite.take(feed.not_finite)
        problem = feed.problem()
        name = f'extra signal {extra.signal}'
        beyond = '' if latest is None else calibration.signal_problem(extra.signal, latest[0])
        if beyond and not problem:
            return self._status(name, DiagnosticStatus.ERROR, f'{beyond} on {topic}: the rate is flagged uncorrected '
                                '(covariance), no static bias is taken', values)
        if problem:
            effect = ('its terms are left out and no static bias is taken until one arrives' if latest is None
                      else 'the last value is applied')
            hint = self._other_type(extra, topic) if latest is None else ''
            return self._status(name, DiagnosticStatus.ERROR,
                                f'{problem} on {topic}: {effect}; the rate is flagged uncorrected (covariance)' + hint
                                + (f'; {refused} values not finite since the last report' if refused else ''),
                                values)
        if refused:
            return self._status(name, DiagnosticStatus.WARN, f'{values["value"]} (the last finite value); {refused} '
                                'values not finite since the last report, ignored', values)
        return self._status(name, DiagnosticStatus.OK, str(values['value']), values)

    def _other_type(self, extra: ExtraSignal, topic: str) -> str:
        """What a topic that sends nothing the node can read carries instead, if it has publishers of another type."""
        node = self._node
        expected = ros_type_name(EXTRA_SIGNAL_MESSAGES[extra.type][0])
        types = {info.topic_type for info in node.get_publishers_info_by_topic(topic)} - {expected}
        if not types:
            return ''
        return (f'; {topic} is published as {", ".join(sorted(types))}: check extra_signals.{extra.signal}.type '
                f'(it is {extra.type}, {expected})')

    def _temperature_status(self) -> DiagnosticStatus:
        node = self._node
        temp = node.last_temp_c
        calibration = node.calibration
        low, high = calibration.expected_range_c or (-math.inf, math.inf)
        # A calibrated range is clamped to; the report's (temperature_warn_range_c) only warned about.
        clamped = calibration.temperature_range_c is not None
        effect = (calibration.beyond_range if clamped else
                  'temperature_warn_range_c, assumed: the polynomial applied as the report does, not clamped')
        outside = node.corrector.compensator.outside_range
        recent = self._outside_range.take(outside)
        implausible = node.corrector.dropped[IMPLAUSIBLE_TEMPERATURE]
        dropped = self._implausible.take(implausible)
        values = {'temperature_c': f'{temp:.2f}', 'calibrated_min_c': low, 'calibrated_max_c': high,
                  'range_clamped': clamped, 'frames_outside_range': outside,
                  'frames_implausible_temperature': implausible}
        if math.isnan(temp) and not dropped:
            return self._status('temperature', DiagnosticStatus.STALE, 'no frame yet', values)
        level, parts = DiagnosticStatus.OK, [f'{temp:.2f} degC' if not math.isnan(temp) else 'no valid frame yet']
        if not math.isnan(temp) and not low <= temp <= high:
            level = DiagnosticStatus.WARN
            parts = [f'{temp:.2f} degC is outside the calibrated range {low}..{high} degC ({effect})']
        elif recent:
            level = DiagnosticStatus.WARN
            parts.append(f'{recent} frames since the last report were outside the calibrated range {low}..{high} degC '
                         f'({effect})')
        if dropped:
            level = DiagnosticStatus.ERROR
            parts.append(f'{dropped} frames since the last report claimed a temperature outside '
                         f'{PLAUSIBLE_TEMPERATURE_C[0]:g}..{PLAUSIBLE_TEMPERATURE_C[1]:g} degC and were dropped: '
                         'corrupt frames, or ' + node.description.temperature_hint)
        return self._status('temperature', level, '; '.join(parts), values)
