"""ROS 2 node ``gyro_node``: the RD2100 on a serial port as a compensated yaw-rate source.

Per frame (on the driver's reader thread, so latency is one serial read): scale the counts,
advance the causal signals and compute the modelled error, feed a running static bias
collection, correct with the current static bias and publish.

Topics (relative names, so they follow the node's namespace and remappings):

- ``imu/data_raw`` (sensor_msgs/Imu): ``angular_velocity.z`` is the compensated yaw rate in
  rad/s (REP 103: counter-clockwise seen from above is positive). Orientation and linear
  acceleration are not measured: element 0 of their covariances is -1 (REP 145). The gyro
  measures z only: x and y are reported as 0 with variance :data:`UNMEASURED_VARIANCE`, so a
  filter that fuses them gives them no weight; element 8 is ``yaw_rate_stddev`` squared.
- ``imu/temperature`` (std_msgs/Float64): the gyro temperature in degC.
- ``/diagnostics`` (diagnostic_msgs/DiagnosticArray, 1 Hz): link, static bias, temperature.

Service ``imu/static_bias`` (std_srvs/Trigger): collect a new static bias over
``bias_samples`` frames; the reply comes when it is done. A call while a collection runs
joins it and gets its result. Motion (mean compensated rate or spread of the rate beyond
the thresholds) refuses it and keeps the previous bias. Publishing goes on meanwhile with the previous bias.
"""

from __future__ import annotations

import math
import sys
import threading
import time
from collections.abc import Sequence
from dataclasses import dataclass
from datetime import datetime, timezone
from pathlib import Path
from typing import Any

import rclpy
import yaml
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from rcl_interfaces.msg import ParameterDescriptor
from rclpy.callback_groups import MutuallyExclusiveCallbackGroup, ReentrantCallbackGroup
from rclpy.executors import ExternalShutdownException, MultiThreadedExecutor
from rclpy.impl.implementation_singleton import rclpy_implementation as _rclpy
from rclpy.node import Node
from sensor_msgs.msg import Imu
from std_msgs.msg import Float64
from std_srvs.srv import Trigger

from art_gyro_calibration.calibration import (Calibration, CalibrationError, find_calibration_file,
                                              from_parameters, load_calibration)
from art_gyro_calibration.compensation import PLAUSIBLE_TEMPERATURE_C, Compensator, plausible
from art_gyro_calibration.driver import STANDARD_BAUDS, Frame, Rd2100Driver
from art_gyro_calibration.frame import PROTOCOLS
from art_gyro_calibration.log import RawLogWriter
from art_gyro_calibration.static_bias import (DEFAULT_MAX_MEAN_DPS, DEFAULT_MAX_STD_DPS, DEFAULT_SAMPLES,
                                              MotionError, StaticBias, StaticBiasCollector)

NODE_NAME = 'gyro_node'
# Variance (rad/s)^2 given to the x and y rates, which a single-axis gyro does not measure:
# large enough that any filter fusing them ignores them, finite so that it stays usable.
UNMEASURED_VARIANCE = 1.0e6
DIAGNOSTICS_PERIOD_S = 1.0
# A static bias collection with no frame for this long has lost its gyro: it is abandoned.
COLLECTION_STALL_S = 5.0
# Parameters whose presence means the calibration comes in as parameters (--params-file).
CALIBRATION_KEYS = ('rate_scale_factor', 'polynomial.rows', 'polynomial.columns', 'polynomial.coefficients')

# name: (default, description); the node's parameters besides a calibration's own.
PARAMETERS: dict[str, tuple[Any, str]] = {
    'port': ('/dev/ttyUSB0', 'Serial port of the gyro.'),
    'baud': (9600, 'Serial baud rate (a standard rate; check the unit\'s setting).'),
    'protocol': ('binary', 'Frame format on the wire: binary (8-byte RD2100 frames) or ascii '
                           '("<raw_rate> <raw_temp>" lines).'),
    'serial_number': ('', 'KVH serial number of the gyro; loads the packaged config/<serial_number>.yaml '
                          'unless a calibration comes in by --params-file, which must be for this serial.'),
    'frame_id': ('imu_link', 'header.frame_id of the published messages.'),
    'bias_samples': (DEFAULT_SAMPLES, 'Frames per static bias collection (100 = 10 s at 10 Hz).'),
    'static_bias_on_startup': (True, 'Collect a static bias at startup (the gyro must be still).'),
    'static_bias_max_mean_dps': (DEFAULT_MAX_MEAN_DPS, 'A static bias whose mean compensated rate exceeds '
                                                       'this (deg/s) is refused: the gyro was turning.'),
    'static_bias_max_std_dps': (DEFAULT_MAX_STD_DPS, 'A static bias whose rate spread (standard deviation, '
                                                     'deg/s) exceeds this is refused: the gyro was moving.'),
    'yaw_rate_stddev': (0.001, 'Standard deviation of the compensated yaw rate (rad/s); its square is '
                               'angular_velocity_covariance[8].'),
    'log_path': ('', 'If set, every received frame is appended as t,raw_rate,raw_temp: a file to create '
                     '(must not exist) or a directory, where <serial>_<UTC time>.csv is created.'),
}


class ParameterError(ValueError):
    """A node parameter that cannot be used, named in the message."""


@dataclass(frozen=True)
class Settings:
    """The node's parameters, checked."""

    port: str
    baud: int
    protocol: str
    serial_number: str
    frame_id: str
    bias_samples: int
    static_bias_on_startup: bool
    static_bias_max_mean_dps: float
    static_bias_max_std_dps: float
    yaw_rate_stddev: float
    log_path: str


def _positive(name: str, value: float) -> float:
    if not (math.isfinite(value) and value > 0.0):
        raise ParameterError(f'parameter {name} must be a positive number, got {value!r}')
    return value


def check_settings(values: dict[str, Any]) -> Settings:
    """Check the node's parameter values (already of the declared types)."""
    for name in ('port', 'frame_id'):
        if not values[name].strip():
            raise ParameterError(f'parameter {name} must not be empty')
    if values['baud'] not in STANDARD_BAUDS:
        raise ParameterError(f'parameter baud must be a standard rate ({", ".join(map(str, STANDARD_BAUDS))}), '
                             f'got {values["baud"]}')
    if values['protocol'] not in PROTOCOLS:
        raise ParameterError(f'parameter protocol must be one of {", ".join(PROTOCOLS)}, '
                             f'got {values["protocol"]!r}')
    if values['bias_samples'] < 2:
        raise ParameterError(f'parameter bias_samples must be at least 2, got {values["bias_samples"]}')
    for name in ('static_bias_max_mean_dps', 'static_bias_max_std_dps', 'yaw_rate_stddev'):
        _positive(name, values[name])
    return Settings(**values)


def _coerce(name: str, value: Any, default: Any) -> Any:
    """``value`` as the type of ``default`` (an integer is a valid float), or a :class:`ParameterError`."""
    kind = type(default)
    if isinstance(value, kind) and (kind is bool or not isinstance(value, bool)):
        return value
    if kind is float and isinstance(value, int) and not isinstance(value, bool):
        return float(value)
    names = {bool: 'a boolean', int: 'an integer', float: 'a number', str: 'a string'}
    raise ParameterError(f'parameter {name} must be {names[kind]}, got {value!r}')


def params_files(argv: Sequence[str]) -> list[str]:
    """The ``--params-file`` paths among the ROS arguments of a command line."""
    files = []
    in_ros_args = False
    for i, arg in enumerate(argv):
        if arg == '--ros-args':
            in_ros_args = True
        elif arg == '--':
            in_ros_args = False
        elif in_ros_args and arg == '--params-file' and i + 1 < len(argv):
            files.append(argv[i + 1])
    return files


def params_file_serials(paths: Sequence[str]) -> dict[str, str]:
    """Serial number of each params file that holds a calibration (has ``polynomial``)."""
    serials = {}
    for path in paths:
        try:
            doc = yaml.safe_load(Path(path).read_text(encoding='utf-8'))
        except (OSError, yaml.YAMLError):
            continue   # rcl has read it already and reports its own errors
        for body in (doc.values() if isinstance(doc, dict) else ()):
            params = body.get('ros__parameters') if isinstance(body, dict) else None
            if isinstance(params, dict) and 'polynomial' in params and 'serial_number' in params:
                serials[path] = str(params['serial_number'])
    return serials


class _Collection:
    """One static bias collection, which the reader thread feeds and callers wait for."""

    __slots__ = ('collector', 'done', 'result', 'error', 'last_sample')

    def __init__(self, collector: StaticBiasCollector) -> None:
        self.collector = collector
        self.done = threading.Event()
        self.result: StaticBias | None = None
        self.error = ''
        self.last_sample = time.monotonic()


class GyroNode(Node):
    """Owns the serial driver; compensates and publishes every frame."""

    def __init__(self, argv: Sequence[str] = ()) -> None:
        super().__init__(NODE_NAME, automatically_declare_parameters_from_overrides=True)
        self.settings = check_settings({name: self._declare(name, default, description)
                                        for name, (default, description) in PARAMETERS.items()})
        self.calibration, self.calibration_source = self._load_calibration(params_files(argv))
        self._compensator = Compensator(self.calibration)
        self._lock = threading.Lock()
        self._closing = threading.Event()
        self._collection: _Collection | None = None
        # How the last collection ended: none yet, ok or refused; while one runs, the state is 'collecting'.
        self._bias_outcome = 'none'
        self._bias_refusal = ''
        self._bias_time = 0.0
        self._published = 0
        self._last_temp_c = math.nan
        self._temp_range = self.calibration.temperature_range_c
        # Frames outside the calibrated range: the latest temperature alone would hide a glitch.
        self._outside_range = 0
        self._outside_range_reported = 0   # as of the last diagnostics
        self._implausible = 0
        self._implausible_reported = 0
        self._rate_window = (time.monotonic(), 0)
        self._log: RawLogWriter | None = None
        if self.settings.log_path:
            self._open_log(self.settings.log_path)

        self._imu = Imu()
        self._imu.header.frame_id = self.settings.frame_id
        self._imu.orientation_covariance[0] = -1.0
        self._imu.linear_acceleration_covariance[0] = -1.0
        self._imu.angular_velocity_covariance[0] = UNMEASURED_VARIANCE
        self._imu.angular_velocity_covariance[4] = UNMEASURED_VARIANCE
        self._imu.angular_velocity_covariance[8] = self.settings.yaw_rate_stddev ** 2
        self._temperature = Float64()
        self._imu_pub = self.create_publisher(Imu, 'imu/data_raw', 10)
        self._temp_pub = self.create_publisher(Float64, 'imu/temperature', 10)
        self._diag_pub = self.create_publisher(DiagnosticArray, '/diagnostics', 10)
        # The service waits for its collection: in its own reentrant group it blocks neither
        # the diagnostics timer nor another call.
        self.create_service(Trigger, 'imu/static_bias', self._on_static_bias,
                            callback_group=ReentrantCallbackGroup())
        self.create_timer(DIAGNOSTICS_PERIOD_S, self._publish_diagnostics,
                          callback_group=MutuallyExclusiveCallbackGroup())

        if self.settings.static_bias_on_startup:
            self._start_collection()
        self.get_logger().info(
            f'calibration loaded: {self.calibration.serial_number} from {self.calibration_source}; '
            f'reading {self.settings.port} at {self.settings.baud} baud ({self.settings.protocol})')
        self._driver = Rd2100Driver(self.settings.port, self.settings.baud, self.settings.protocol,
                                    self._on_frame, on_link=self._on_link)
        self._driver.start()

    # --- startup -------------------------------------------------------------------------

    def _declare(self, name: str, default: Any, description: str) -> Any:
        # Declared from the overrides already (automatically_declare_parameters_from_overrides):
        # check the given value's type, then declare again with the description.
        value = default
        if self.has_parameter(name):
            value = self.get_parameter(name).value
            self.undeclare_parameter(name)
            value = _coerce(name, value, default)
        # Read-only: the node reads them once at startup, so a later change is refused, not ignored.
        return self.declare_parameter(name, value, ParameterDescriptor(description=description, read_only=True),
                                      ignore_override=True).value

    def _load_calibration(self, files: Sequence[str]) -> tuple[Calibration, str]:
        serial = self.settings.serial_number
        if not any(self.has_parameter(key) for key in CALIBRATION_KEYS):
            if not serial:
                raise ParameterError('parameter serial_number is required: the KVH serial number (such as '
                                     'NAVC3545) of the packaged calibration to load, unless a calibration '
                                     'file comes in by --params-file')
            try:
                path = find_calibration_file(serial)
                return load_calibration(path, expected_serial=serial), str(path)
            except CalibrationError as e:
                raise ParameterError(f'parameter serial_number: {e}') from None
        where = 'parameters (' + (', '.join(files) or 'command line') + ')'
        for path, file_serial in params_file_serials(files).items():
            if file_serial != serial:
                raise ParameterError(f'parameter serial_number is {serial!r} but the calibration in {path} '
                                     f'is for {file_serial!r}: refusing a calibration of another gyro')
        values = {name: param.value for name, param in self.get_parameters_by_prefix('').items()}
        return from_parameters(values, where), where

    def _open_log(self, log_path: str) -> None:
        path = Path(log_path)
        if path.is_dir():
            stamp = datetime.now(timezone.utc).strftime('%Y%m%dT%H%M%SZ')
            path = path / f'{self.calibration.serial_number}_{stamp}.csv'
        try:
            stream = open(path, 'x', encoding='utf-8')
        except OSError as e:
            raise ParameterError(f'parameter log_path: cannot create {path}: {e.strerror}') from None
        self._log = RawLogWriter(stream)
        self.get_logger().info(f'logging raw frames to {path}')

    # --- per frame (driver reader thread) ------------------------------------------------

    def _on_frame(self, frame: Frame) -> None:
        try:
            self._handle_frame(frame)
        except Exception as e:   # an exception here would end the driver's reader thread
            if not self._closing.is_set() and self.context.ok():
                self.get_logger().error(f'frame not published: {type(e).__name__}: {e}',
                                        throttle_duration_sec=5.0)

    def _handle_frame(self, frame: Frame) -> None:
        sample = frame.sample
        compensator = self._compensator
        rate_dps, temp_c = compensator.scale(sample.raw_rate, sample.raw_temp)
        stamp_ns = frame.stamp_ns
        t = stamp_ns * 1e-9
        if self._log is not None:
            self._log.write(t, sample.raw_rate, sample.raw_temp)   # the log keeps what the wire said
        if not plausible(temp_c):
            self._implausible += 1
            return
        error_dps = compensator.error(t, rate_dps, temp_c)   # every sample: it advances the signals
        collection = self._collection
        if collection is not None:
            collection.last_sample = time.monotonic()
            if collection.collector.add(rate_dps, error_dps):
                self._finish_collection(collection)
        imu = self._imu
        imu.header.stamp.sec, imu.header.stamp.nanosec = divmod(stamp_ns, 1_000_000_000)
        imu.angular_velocity.z = math.radians(compensator.correct(rate_dps, error_dps))
        self._imu_pub.publish(imu)
        self._temperature.data = temp_c
        self._temp_pub.publish(self._temperature)
        self._last_temp_c = temp_c
        low, high = self._temp_range
        if not low <= temp_c <= high:
            self._outside_range += 1
        self._published += 1

    def _on_link(self, connected: bool, message: str) -> None:
        if connected:
            self.get_logger().info(f'gyro link up: {message}')
        else:
            self.get_logger().warning(f'gyro link down: {message}')

    # --- static bias ---------------------------------------------------------------------

    def _start_collection(self) -> _Collection:
        with self._lock:
            if self._collection is None:
                self._collection = _Collection(StaticBiasCollector(
                    self.settings.bias_samples, self.settings.static_bias_max_mean_dps,
                    self.settings.static_bias_max_std_dps))
                self.get_logger().info(f'static bias: collecting {self.settings.bias_samples} samples; '
                                       'keep the gyro still')
            return self._collection

    def _finish_collection(self, collection: _Collection) -> None:
        try:
            bias = collection.collector.result()
        except (MotionError, ValueError) as e:
            self._end_collection(collection, None, str(e))
        else:
            self._end_collection(collection, bias, '')

    def _end_collection(self, collection: _Collection, bias: StaticBias | None, error: str) -> None:
        with self._lock:
            if self._collection is not collection:
                return   # abandoned meanwhile
            self._collection = None
            if bias is not None:
                self._compensator.bias = bias
                self._bias_outcome = 'ok'
                self._bias_time = time.monotonic()
                self.get_logger().info(f'static bias: {bias.describe()}')
            else:
                self._bias_outcome = 'refused'
                self._bias_refusal = error
                self.get_logger().warning(f'static bias refused, previous bias kept: {error}')
            collection.result = bias
            collection.error = error
            collection.done.set()

    def _on_static_bias(self, request: Trigger.Request, response: Trigger.Response) -> Trigger.Response:
        collection = self._start_collection()
        while not collection.done.wait(0.2):
            if self._closing.is_set():
                self._end_collection(collection, None, 'the node is shutting down')
            elif time.monotonic() - collection.last_sample > COLLECTION_STALL_S:
                self._end_collection(collection, None, f'no frame from the gyro for {COLLECTION_STALL_S:.0f} s '
                                                       f'(link: {self._driver.stats.last_error or "no data"})')
        response.success = collection.result is not None
        if collection.result is not None:
            response.message = collection.result.describe()
        else:
            response.message = f'refused, previous bias kept: {collection.error}'
        return response

    # --- diagnostics ---------------------------------------------------------------------

    def _publish_diagnostics(self) -> None:
        msg = DiagnosticArray()
        msg.header.stamp = self.get_clock().now().to_msg()
        msg.status = [self._link_status(), self._bias_status(), self._temperature_status()]
        self._diag_pub.publish(msg)

    def _status(self, name: str, level: bytes, message: str, values: dict[str, Any]) -> DiagnosticStatus:
        return DiagnosticStatus(level=level, name=f'{self.get_name()}: {name}', message=message,
                                hardware_id=f'KVH RD2100 {self.calibration.serial_number}',
                                values=[KeyValue(key=k, value=str(v)) for k, v in values.items()])

    def _link_status(self) -> DiagnosticStatus:
        stats = self._driver.stats
        now = time.monotonic()
        then, frames_then = self._rate_window
        self._rate_window = (now, stats.frames)
        rate_hz = (stats.frames - frames_then) / (now - then) if now > then else 0.0
        values: dict[str, Any] = {
            'port': stats.port, 'connected': stats.connected, 'reopens': stats.reopens,
            'last_error': stats.last_error, 'frame_rate_hz': f'{rate_hz:.2f}', 'frames': stats.frames,
            'rejected': stats.rejected, 'bytes_skipped': stats.bytes_skipped, 'published': self._published}
        for reason, count in stats.rejected_by_reason.items():
            values[f'rejected_{reason}'] = count
        if not stats.connected:
            return self._status('link', DiagnosticStatus.ERROR, f'disconnected: {stats.last_error}', values)
        if rate_hz == 0.0:
            return self._status('link', DiagnosticStatus.WARN, 'connected, no frames', values)
        return self._status('link', DiagnosticStatus.OK, f'connected, {rate_hz:.1f} Hz', values)

    def _bias_status(self) -> DiagnosticStatus:
        with self._lock:   # one consistent snapshot: the reader thread may end a collection meanwhile
            collection = self._collection
            state = 'collecting' if collection is not None else self._bias_outcome
            bias, refusal, bias_time = self._compensator.bias, self._bias_refusal, self._bias_time
        values: dict[str, Any] = {
            'state': state, 'static_bias_drift_dps': f'{bias.static_bias_drift_dps:.6f}',
            'calc_static_bias_drift_dps': f'{bias.calc_static_bias_drift_dps:.6f}',
            'samples': bias.samples, 'rate_std_dps': f'{bias.rate_std_dps:.6f}',
            'age_s': f'{time.monotonic() - bias_time:.0f}' if bias.samples else 'none',
            'last_refusal': refusal}
        if collection is not None:
            progress = f'{collection.collector.count}/{self.settings.bias_samples}'
            return self._status('static bias', DiagnosticStatus.OK, f'collecting ({progress})', values)
        if state == 'ok':
            return self._status('static bias', DiagnosticStatus.OK, bias.describe(), values)
        if state == 'refused':
            kept = 'previous bias kept' if bias.samples else 'no bias applied'
            return self._status('static bias', DiagnosticStatus.WARN, f'refused ({refusal}); {kept}',
                                values)
        return self._status('static bias', DiagnosticStatus.WARN,
                            'none: call imu/static_bias with the gyro still', values)

    def _temperature_status(self) -> DiagnosticStatus:
        temp = self._last_temp_c
        low, high = self._temp_range
        outside = self._outside_range
        recent, self._outside_range_reported = outside - self._outside_range_reported, outside
        implausible = self._implausible
        dropped, self._implausible_reported = implausible - self._implausible_reported, implausible
        values = {'temperature_c': f'{temp:.2f}', 'calibrated_min_c': low, 'calibrated_max_c': high,
                  'frames_outside_range': outside, 'frames_implausible_temperature': implausible}
        if math.isnan(temp) and not dropped:
            return self._status('temperature', DiagnosticStatus.STALE, 'no frame yet', values)
        level, parts = DiagnosticStatus.OK, [f'{temp:.2f} degC' if not math.isnan(temp) else 'no valid frame yet']
        if not math.isnan(temp) and not low <= temp <= high:
            level = DiagnosticStatus.WARN
            parts = [f'{temp:.2f} degC is outside the calibrated range {low}..{high} degC']
        elif recent:
            level = DiagnosticStatus.WARN
            parts.append(f'{recent} frames since the last report were outside the calibrated range {low}..{high} degC')
        if dropped:
            level = DiagnosticStatus.ERROR
            parts.append(f'{dropped} frames since the last report claimed a temperature outside '
                         f'{PLAUSIBLE_TEMPERATURE_C[0]:g}..{PLAUSIBLE_TEMPERATURE_C[1]:g} degC and were dropped: '
                         'corrupt frames, or the temperature field is not m[3]:m[4] on this unit')
        return self._status('temperature', level, '; '.join(parts), values)

    # --- shutdown ------------------------------------------------------------------------

    def close(self) -> None:
        """Stop the driver (no frame after this) and close the raw log."""
        self._closing.set()
        self._driver.stop()
        if self._log is not None:
            self._log.close()
            self._log = None


def main(args: list[str] | None = None) -> int:
    """Entry point of ``gyro_node``; returns the exit code."""
    argv = sys.argv if args is None else args
    node: GyroNode | None = None
    try:
        rclpy.init(args=argv)
        node = GyroNode(argv)
        executor = MultiThreadedExecutor(num_threads=3)
        executor.add_node(node)
        executor.spin()
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    except (ParameterError, CalibrationError, _rclpy.RCLError) as e:
        # RCLError: rcl refused the command line, such as a params file it cannot parse.
        print(f'{NODE_NAME}: error: {e}', file=sys.stderr)
        return 1
    finally:
        if node is not None:
            try:
                node.close()
            finally:
                node.destroy_node()
        rclpy.try_shutdown()
    return 0


if __name__ == '__main__':
    sys.exit(main())
