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
The reply is deferred, not waited for: the callback returns at once and the executor thread is free.

Parameters are strict: an unknown name, a value of the wrong type or out of its range, or
a calibration that does not fit, ends the node at startup with a message naming it.
"""

from __future__ import annotations

import math
import os
import re
import signal
import sys
import threading
import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from datetime import datetime, timezone
from pathlib import Path
from typing import Any, NamedTuple

import rclpy
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor
from rclpy.callback_groups import MutuallyExclusiveCallbackGroup
from rclpy.executors import ExternalShutdownException, MultiThreadedExecutor
from rclpy.impl.implementation_singleton import rclpy_implementation as _rclpy
from rclpy.node import Node
from rclpy.qos import QoSProfile
from rclpy.qos_overriding_options import QoSOverridingOptions
from sensor_msgs.msg import Imu
from std_msgs.msg import Float64
from std_srvs.srv import Trigger

from art_gyro_calibration.calibration import (CALIBRATION_KEYS, Calibration, CalibrationError, closest,
                                              find_calibration_file, flatten, from_parameters, is_calibration_key,
                                              load_calibration, read_yaml, resolve_calibration_url)
from art_gyro_calibration.compensation import (IMPLAUSIBLE_TEMPERATURE, NOT_FINITE, PLAUSIBLE_TEMPERATURE_C,
                                               FrameCorrector, RunStart)
from art_gyro_calibration.driver import STANDARD_BAUDS, Frame, Rd2100Driver
from art_gyro_calibration.frame import AXIS_INVALID, KVH_FOG, PROTOCOLS, KvhFogConfig
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
# A raw log that failed (full disk, deleted) is reopened this often; frames meanwhile are not logged.
LOG_RETRY_S = 5.0
# An out-of-range temperature is said on the console at most this often.
TEMPERATURE_WARNING_PERIOD_S = 60.0
IMU_TOPIC = 'imu/data_raw'
# Calls to imu/static_bias that can wait for one collection at once (requests and replies are queued this deep).
SERVICE_QUEUE_DEPTH = 1000


class Range(NamedTuple):
    """Inclusive bounds of a numeric parameter."""

    low: float
    high: float


# name: (default, description[, constraint]), the node's parameters besides a calibration's own.
# The constraint is a Range for a number or a tuple of the allowed values; the type is the default's.
PARAMETERS: dict[str, tuple[Any, ...]] = {
    'port': ('/dev/ttyUSB0', 'Serial port of the gyro.'),
    'baud': (9600, 'Serial baud rate (check the unit\'s setting; a 1 kHz unit needs 115200 or more).',
             STANDARD_BAUDS),
    'protocol': ('binary', 'Frame format on the wire: binary (8-byte RD2100 frames) or ascii '
                           '("<raw_rate> <raw_temp>" lines).', PROTOCOLS),
    'serial_number': ('', 'KVH serial number of the gyro; loads the packaged config/<serial_number>.yaml '
                          'unless calibration_file is set or a calibration comes in by --params-file, which '
                          'must be for this serial.'),
    'calibration_file': ('', 'A calibration file instead of the packaged one: a path, file:///path or '
                             'package://<package>/<path> (as camera_info_url); its serial_number must match.'),
    'frame_id': ('imu_link', 'header.frame_id of the published messages.'),
    'bias_samples': (DEFAULT_SAMPLES, 'Frames per static bias collection (100 = 10 s at 10 Hz).',
                     Range(2, 1_000_000)),
    'static_bias_on_startup': (True, 'Collect a static bias at startup (the gyro must be still).'),
    'static_bias_max_mean_dps': (DEFAULT_MAX_MEAN_DPS, 'A static bias whose mean compensated rate exceeds '
                                                       'this (deg/s) is refused: the gyro was turning.',
                                 Range(1e-6, 10.0)),
    'static_bias_max_std_dps': (DEFAULT_MAX_STD_DPS, 'A static bias whose rate spread (standard deviation, '
                                                     'deg/s) exceeds this is refused: the gyro was moving.',
                                Range(1e-6, 10.0)),
    'yaw_rate_stddev': (0.001, 'Standard deviation of the compensated yaw rate (rad/s); its square is '
                               'angular_velocity_covariance[8].', Range(1e-7, 1.0)),
    'powered_on_at_start': (False, 'The gyro was switched on with the node (a cold start): a warm-up term of the '
                                   'calibration then decays from the node\'s first frame. Otherwise (the default, '
                                   'safe on a warm restart) a warm-up term counts as decayed.'),
    'log_path': ('', 'If set, every received frame is appended as t,raw_rate,raw_temp: a file to create '
                     '(must not exist) or a directory, where <serial>_<UTC time>.csv is created.'),
}

# --- protocol kvh_fog (KVH DSP-1750/1760, 1725/1750/1775) ------------------------------------------
# What the unit is set to send, which its messages do not say: name: (default, description). Declared
# and checked at startup whatever the protocol; read by the kvh_fog parser only. Defaults: the manuals'.
_KVH_FOG_DESCRIPTIONS = {
    'message_format': 'kvh_fog message format (=OUTPUTFMT): A (36 bytes, the default), B (40) or C (38).',
    'yaw_axis': 'kvh_fog axis that points up on the robot: x, y or z, or -x, -y, -z if it points down.',
    'rotation': 'kvh_fog rotation output (=ROTFMT): delta_angle (the default) or rate.',
    'angle_units': 'kvh_fog angle units (=ROTUNITS): rad (the default) or deg.',
    'output_rate_hz': 'kvh_fog messages per second (=DR); a delta angle times it is the rate.',
    'temperature_units': 'kvh_fog temperature units (=TEMPUNITS): C (the default), C_100, F or F_100.',
}
KVH_FOG_PARAMETERS: dict[str, tuple[Any, str]] = {
    f'kvh_fog.{name}': (getattr(KvhFogConfig(), name), description)
    for name, description in _KVH_FOG_DESCRIPTIONS.items()}


class ParameterError(ValueError):
    """A node parameter that cannot be used, named in the message."""


def check_kvh_fog_calibration(calibration: Calibration, source: str) -> None:
    """Refuse for protocol kvh_fog a calibration whose scale factors are not 1.0 (its samples are deg/s, degC)."""
    if calibration.rate_scale_factor != 1.0 or calibration.temp_scale_factor != 1.0:
        raise ParameterError(
            f'parameter protocol is {KVH_FOG}, whose samples are deg/s and degC, but the calibration of '
            f'{calibration.serial_number} from {source} has rate_scale_factor {calibration.rate_scale_factor} and '
            f'temp_scale_factor {calibration.temp_scale_factor}: both must be 1.0 '
            '(config/KVH_DSP1760_EXAMPLE.yaml is an example)')


@dataclass(frozen=True)
class Settings:
    """The node's parameters, checked."""

    port: str
    baud: int
    protocol: str
    serial_number: str
    calibration_file: str
    frame_id: str
    bias_samples: int
    static_bias_on_startup: bool
    static_bias_max_mean_dps: float
    static_bias_max_std_dps: float
    yaw_rate_stddev: float
    powered_on_at_start: bool
    log_path: str


def _constraint(name: str) -> Any:
    entry = PARAMETERS[name]
    return entry[2] if len(entry) > 2 else None


def describe_constraint(name: str) -> str:
    """The allowed values of a parameter for people, or ''."""
    constraint = _constraint(name)
    if isinstance(constraint, Range):
        return f'{constraint.low:g}..{constraint.high:g}' if isinstance(constraint.low, float) else \
            f'{constraint.low}..{constraint.high}'
    if constraint:
        return 'one of ' + ', '.join(map(str, constraint))
    return ''


def check_settings(values: dict[str, Any]) -> Settings:
    """Check the node's parameter values (already of the declared types) against their constraints."""
    for name in ('port', 'frame_id'):
        if not values[name].strip():
            raise ParameterError(f'parameter {name} must not be empty')
    for name, value in values.items():
        constraint = _constraint(name)
        if isinstance(constraint, Range):
            if not (math.isfinite(value) and constraint.low <= value <= constraint.high):
                raise ParameterError(f'parameter {name} must be in {describe_constraint(name)}, got {value!r}')
        elif constraint and value not in constraint:
            raise ParameterError(f'parameter {name} must be {describe_constraint(name)}, got {value!r}')
    return Settings(**values)


def descriptor(name: str) -> ParameterDescriptor:
    """Read-only descriptor of a node parameter, with its range where it is a number."""
    default, description = PARAMETERS[name][:2]
    d = ParameterDescriptor(description=description, read_only=True)
    constraint = _constraint(name)
    if isinstance(constraint, Range) and isinstance(default, int):
        d.integer_range = [IntegerRange(from_value=int(constraint.low), to_value=int(constraint.high), step=1)]
    elif isinstance(constraint, Range):
        d.floating_point_range = [FloatingPointRange(from_value=float(constraint.low),
                                                     to_value=float(constraint.high), step=0.0)]
    elif constraint and isinstance(default, int):
        d.integer_range = [IntegerRange(from_value=min(constraint), to_value=max(constraint), step=0)]
        d.additional_constraints = describe_constraint(name)
    elif constraint:
        d.additional_constraints = describe_constraint(name)
    return d


def _coerce(name: str, value: Any, default: Any) -> Any:
    """``value`` as the type of ``default`` (an integer is a valid float), or a :class:`ParameterError`."""
    kind = type(default)
    if isinstance(value, kind) and (kind is bool or not isinstance(value, bool)):
        return value
    if kind is float and isinstance(value, int) and not isinstance(value, bool):
        return float(value)
    names = {bool: 'a boolean', int: 'an integer', float: 'a number', str: 'a string'}
    raise ParameterError(f'parameter {name} must be {names[kind]}, got {value!r}')


def usage() -> str:
    """``gyro_node --help``: how to run it and every parameter with its default, range and meaning."""
    lines = [f'usage: {NODE_NAME} [--help] --ros-args [-p NAME:=VALUE]... [--params-file FILE]... '
             '[-r __ns:=/NAMESPACE]', '', __doc__.splitlines()[0], '',
             'parameters (read-only; checked at startup, an unknown or bad one ends the node with exit 1):']
    for name, (default, description, *_) in PARAMETERS.items():
        allowed = describe_constraint(name)
        lines.append(f'  {name} ({type(default).__name__}, default {default!r}{", " + allowed if allowed else ""})')
        lines.append(f'      {description}')
    lines += ['', 'calibration parameters (from the calibration file, read-only): '
              + ', '.join(sorted(CALIBRATION_KEYS)) + ', extended.<signal>.*',
              f'QoS of {IMU_TOPIC} (default reliable, depth 10): qos_overrides./<namespace>/{IMU_TOPIC}.publisher.'
              '{reliability,history,depth,durability}',
              'topics: imu/data_raw (sensor_msgs/Imu), imu/temperature (std_msgs/Float64), /diagnostics; '
              'service: imu/static_bias (std_srvs/Trigger)']
    return '\n'.join(lines)


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


def _entry_pattern(key: str) -> re.Pattern[str]:
    """A params file's node entry (``/**``, ``gyro_node``, ``/robot/*``) as a pattern of fully qualified names."""
    key = key if key.startswith('/') else '/' + key
    parts = re.split(r'(\*\*|\*)', key)
    return re.compile(''.join('.*' if p == '**' else '[^/]*' if p == '*' else re.escape(p) for p in parts) + '$')


def params_file_values(paths: Sequence[str], node_name: str) -> dict[str, dict[str, Any]]:
    """Per params file, the flat parameters it gives the node ``node_name`` (fully qualified).

    Read safely (size-bounded, no aliases); a file rcl parsed but that is refused here is an error.
    """
    values: dict[str, dict[str, Any]] = {}
    for path in paths:
        doc = read_yaml(path, 'params file')
        flat: dict[str, Any] = {}
        for key, body in (doc.items() if isinstance(doc, Mapping) else ()):
            params = body.get('ros__parameters') if isinstance(body, Mapping) else None
            if isinstance(params, Mapping) and _entry_pattern(str(key)).match(node_name):
                flat.update(flatten(params))
        values[path] = flat
    return values


class _Collection(StaticBiasCollector):
    """One static bias collection, which the reader thread feeds and callers wait for."""

    __slots__ = ('bias', 'error', 'last_sample', 'waiting')

    def __init__(self, samples: int, max_mean_dps: float, max_std_dps: float, keep_window: bool) -> None:
        super().__init__(samples, max_mean_dps, max_std_dps, keep_window)
        self.bias: StaticBias | None = None
        self.error = ''
        self.last_sample = time.monotonic()
        self.waiting: list[Any] = []   # request headers of the calls to answer when it ends

    def add(self, rate_dps: float, error_dps: float, t: float = 0.0, temp_c: float = 0.0,
            causal_dps: float = 0.0) -> bool:
        """Add a sample, noting when (a collection that gets none for long is abandoned)."""
        self.last_sample = time.monotonic()
        return super().add(rate_dps, error_dps, t, temp_c, causal_dps)


class GyroNode(Node):
    """Owns the serial driver; compensates and publishes every frame."""

    def __init__(self, argv: Sequence[str] = ()) -> None:
        super().__init__(NODE_NAME)
        self._files = params_file_values(params_files(argv), self.get_fully_qualified_name())
        # Known now: the node's own, a calibration's, rclpy's (use_sim_time); QoS overrides once the publisher is made.
        self._check_known_names(lambda name: name in PARAMETERS or name in KVH_FOG_PARAMETERS
                                or is_calibration_key(name) or self.has_parameter(name)
                                or name.startswith('qos_overrides.'))
        self.settings = check_settings({name: self._override(name, entry[0]) for name, entry in PARAMETERS.items()})
        for name in PARAMETERS:
            # Read-only: the node reads them once at startup, so a later change is refused, not ignored.
            self.declare_parameter(name, getattr(self.settings, name), descriptor(name), ignore_override=True)
        self.kvh_fog = self._kvh_fog_config()
        self.calibration, self.calibration_source = self._load_calibration()
        if self.settings.protocol == KVH_FOG:
            check_kvh_fog_calibration(self.calibration, self.calibration_source)
        self._corrector = FrameCorrector(self.calibration, RunStart(self.settings.powered_on_at_start),
                                         self._finish_collection)
        self._lock = threading.Lock()
        self._closing = threading.Event()
        self._collection: _Collection | None = None
        self._finished: list[_Collection] = []   # ended, their replies not sent yet
        # How the last collection ended: none yet, ok or refused; while one runs, the state is 'collecting'.
        self._bias_outcome = 'none'
        self._bias_refusal = ''
        self._bias_time = 0.0
        self._published = 0
        self._last_temp_c = math.nan
        self._temp_range = self.calibration.temperature_range_c
        # Frames outside the calibrated range: the latest temperature alone would hide a glitch.
        self._outside_range_reported = 0   # frames clamped (Compensator.clamped) as of the last diagnostics
        self._dropped_reported = dict(self._corrector.dropped)
        self._implausible_reported = 0
        self._rate_window = (time.monotonic(), 0)
        self._lost_reported = self._invalid_reported = 0   # kvh_fog: as of the last diagnostics
        self._log_lock = threading.Lock()
        self._log: RawLogWriter | None = None
        self._log_stream: Any = None
        self._log_file = ''
        self._log_error = ''
        self._log_failed_at = 0.0
        self._log_rows_lost = 0
        if self.settings.log_path:
            self._open_log(self.settings.log_path, at_startup=True)

        self._imu = Imu()
        self._imu.header.frame_id = self.settings.frame_id
        self._imu.orientation_covariance[0] = -1.0
        self._imu.linear_acceleration_covariance[0] = -1.0
        self._imu.angular_velocity_covariance[0] = UNMEASURED_VARIANCE
        self._imu.angular_velocity_covariance[4] = UNMEASURED_VARIANCE
        self._imu.angular_velocity_covariance[8] = self.settings.yaw_rate_stddev ** 2
        self._temperature = Float64()
        # Reliable, depth 10 unless overridden (qos_overrides.<topic>.publisher.* parameters, read-only).
        try:
            self._imu_pub = self.create_publisher(Imu, IMU_TOPIC, 10,
                                                  qos_overriding_options=QoSOverridingOptions.with_default_policies())
        except Exception as e:   # rclpy raises several types for a bad override; all end here
            raise ParameterError(f'QoS override of {IMU_TOPIC}: {e}') from None
        self._check_known_names(self.has_parameter)
        self._temp_pub = self.create_publisher(Float64, 'imu/temperature', 10)
        self._diag_pub = self.create_publisher(DiagnosticArray, '/diagnostics', 10)
        # The reply is deferred: the callback returns at once and the executor sends the reply
        # through send_response, which this node takes over to hold it until the collection ends.
        # (rclpy 7 re-runs a waiting coroutine callback in a busy loop, so an async callback is not used.)
        # Deep queues: the replies to every joined call go out at once, and a reliable writer keeping
        # the default last 10 would drop all but 10 of them.
        self._service = self.create_service(Trigger, 'imu/static_bias', lambda request, response: response,
                                            qos_profile=QoSProfile(depth=SERVICE_QUEUE_DEPTH))
        self._send_reply = self._service.send_response
        self._service.send_response = self._defer_reply
        self._replies = self.create_guard_condition(self._send_replies)
        self.create_timer(DIAGNOSTICS_PERIOD_S, self._publish_diagnostics,
                          callback_group=MutuallyExclusiveCallbackGroup())
        self.create_timer(0.5, self._watch_collection)
        self.create_timer(LOG_RETRY_S, self._retry_log)

        if self.settings.static_bias_on_startup:
            self._start_collection()
        self.get_logger().info(
            f'calibration loaded: {self.calibration.serial_number} from {self.calibration_source}; '
            f'reading {self.settings.port} at {self.settings.baud} baud ({self.settings.protocol})')
        self._driver = Rd2100Driver(self.settings.port, self.settings.baud, self.settings.protocol,
                                    self._on_frame, on_link=self._on_link, on_warning=self._on_driver_warning,
                                    clock_ns=lambda: self.get_clock().now().nanoseconds, kvh_fog=self.kvh_fog)
        self._driver.start()

    # --- startup -------------------------------------------------------------------------

    def _where(self, name: str) -> str:
        """Which params file gave a parameter (the last one, as rcl applies them), else the command line."""
        files = [path for path, values in self._files.items() if name in values]
        return files[-1] if files else 'the command line'

    def _check_known_names(self, known: Any) -> None:
        """Refuse a parameter given to the node that nothing reads, naming the closest valid name."""
        names = set(PARAMETERS) | set(KVH_FOG_PARAMETERS) | set(CALIBRATION_KEYS) | set(self._parameters)
        for name in self._parameter_overrides:
            if not known(name):
                raise ParameterError(f'unknown parameter {name!r} (from {self._where(name)}){closest(name, names)}')

    def _override(self, name: str, default: Any) -> Any:
        if name not in self._parameter_overrides:
            return default
        return _coerce(name, self._parameter_overrides[name].value, default)

    def _kvh_fog_config(self) -> KvhFogConfig:
        values = {}
        for name, (default, description) in KVH_FOG_PARAMETERS.items():
            value = self._override(name, default)
            self.declare_parameter(name, value, ParameterDescriptor(description=description, read_only=True),
                                   ignore_override=True)
            values[name.removeprefix('kvh_fog.')] = value
        try:
            return KvhFogConfig(**values)
        except ValueError as e:
            raise ParameterError(f'parameter {e}') from None

    def _load_calibration(self) -> tuple[Calibration, str]:
        serial = self.settings.serial_number
        given = {name: p.value for name, p in self._parameter_overrides.items()
                 if is_calibration_key(name) and name != 'serial_number'}
        # Every params file that names a serial must agree with the node's (a node params file and
        # another gyro's calibration file would otherwise load that gyro's calibration silently).
        for path, values in self._files.items():
            file_serial = values.get('serial_number')
            if file_serial is not None and serial and str(file_serial) != serial:
                what = (f'the calibration in {path} is' if 'polynomial.coefficients' in values
                        else f'the parameters in {path} are')
                raise ParameterError(f'parameter serial_number is {serial!r} but {what} for '
                                     f'{str(file_serial)!r}: refusing a calibration of another gyro')
        if given:
            if self.settings.calibration_file:
                raise ParameterError(f'parameter calibration_file is set and a calibration came in as parameters '
                                     f'(from {self._where("polynomial.coefficients")}): give one or the other')
            files = sorted({self._where(name) for name in given})
            where = 'parameters (' + ', '.join(files) + ')'
            calibration = from_parameters({**given, 'serial_number': serial}, where)
        elif self.settings.calibration_file:
            path = resolve_calibration_url(self.settings.calibration_file)
            calibration, where = load_calibration(path, expected_serial=serial or None), str(path)
        elif not serial:
            raise ParameterError('parameter serial_number is required: the KVH serial number (such as '
                                 'NAVC3545) of the packaged calibration to load, unless calibration_file is '
                                 'set or a calibration file comes in by --params-file')
        else:
            try:
                path = find_calibration_file(serial)
            except CalibrationError as e:
                raise ParameterError(f'parameter serial_number: {e}') from None
            calibration, where = load_calibration(path, expected_serial=serial), str(path)
        for name, value in calibration.to_parameters().items():
            if name != 'serial_number':
                self.declare_parameter(name, value, ParameterDescriptor(
                    description=f'calibration of {calibration.serial_number} (from {where})', read_only=True),
                    ignore_override=True)
        return calibration, where

    # --- raw log -------------------------------------------------------------------------

    def _log_target(self, log_path: str) -> Path:
        path = Path(log_path)
        if path.is_dir():
            stamp = datetime.now(timezone.utc).strftime('%Y%m%dT%H%M%SZ')
            path = path / f'{self.calibration.serial_number}_{stamp}.csv'
        return path

    def _open_log(self, log_path: str, at_startup: bool = False) -> None:
        path = self._log_target(log_path)
        try:
            stream = open(path, 'x', encoding='utf-8')
            writer = RawLogWriter(stream)
        except OSError as e:
            if at_startup:
                raise ParameterError(f'parameter log_path: cannot create {path}: {e.strerror}') from None
            self._log_error = f'cannot create {path}: {e.strerror or e}'
            self._log_failed_at = time.monotonic()
            return
        with self._log_lock:
            self._log, self._log_stream, self._log_file = writer, stream, str(path)
            self._log_error = ''
        self.get_logger().info(f'logging raw frames to {path}')

    def _write_log(self, t: float, raw_rate: int, raw_temp: int) -> None:
        with self._log_lock:
            log = self._log
            if log is None:
                if self.settings.log_path:
                    self._log_rows_lost += 1
                return
            try:
                log.write(t, raw_rate, raw_temp)
            except (OSError, ValueError) as e:
                self._log_rows_lost += 1
                self._stop_log(f'writing {self._log_file} failed: {e}')

    def _stop_log(self, error: str) -> None:
        """Stop logging after a failure (lock held): one console error, an ERROR status, a retry on a timer."""
        log, self._log = self._log, None
        self._log_error = error
        self._log_failed_at = time.monotonic()
        try:
            log.close()
        except (OSError, ValueError):
            pass   # the rows not flushed are lost with the file system that refused them
        self.get_logger().error(f'raw log stopped, publishing goes on: {error}; retrying every {LOG_RETRY_S:g} s')

    def _check_log_file(self) -> None:
        """A log file deleted (or replaced) while open would swallow every row without an error."""
        with self._log_lock:
            if self._log is None:
                return
            try:
                same = os.path.samestat(os.stat(self._log_file), os.fstat(self._log_stream.fileno()))
            except OSError:
                same = False
            if not same:
                self._stop_log(f'{self._log_file} was deleted or replaced while logging')

    def _retry_log(self) -> None:
        if self.settings.log_path and self._log is None and self._log_error and not self._closing.is_set():
            self._open_log(self.settings.log_path)

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
        stamp_ns = frame.stamp_ns
        self._publish(sample.raw_rate, sample.raw_temp, stamp_ns, frame.steady_ns * 1e-9)
        # After publishing: a log that fails (full disk) must not delay or stop the messages.
        self._write_log(stamp_ns * 1e-9, sample.raw_rate, sample.raw_temp)   # the log keeps what the wire said

    def _publish(self, raw_rate: int, raw_temp: int, stamp_ns: int, t: float) -> None:
        corrector = self._corrector
        if corrector.step(raw_rate, raw_temp, t):
            return   # dropped, and counted by the corrector
        imu = self._imu
        imu.header.stamp.sec, imu.header.stamp.nanosec = divmod(stamp_ns, 1_000_000_000)
        imu.angular_velocity.z = math.radians(corrector.rate_dps)
        self._imu_pub.publish(imu)
        temp_c = corrector.temp_c
        self._temperature.data = temp_c
        self._temp_pub.publish(self._temperature)
        self._last_temp_c = temp_c
        low, high = self._temp_range
        if not low <= temp_c <= high:   # the Compensator clamped it and counted it
            self.get_logger().warning(f'gyro temperature {temp_c:.2f} degC is outside the calibrated range '
                                      f'{low:g}..{high:g} degC: compensated as at the nearest end of it',
                                      throttle_duration_sec=TEMPERATURE_WARNING_PERIOD_S)
        self._published += 1

    def _on_link(self, connected: bool, message: str) -> None:
        if connected:
            self.get_logger().info(f'gyro link up: {message}')
        else:
            self.get_logger().warning(f'gyro link down: {message}')

    def _on_driver_warning(self, message: str) -> None:
        self.get_logger().warning(message)

    # --- static bias ---------------------------------------------------------------------

    def _start_collection(self) -> _Collection:
        with self._lock:
            if self._collection is None:
                self._collection = self._corrector.collector = _Collection(
                    self.settings.bias_samples, self.settings.static_bias_max_mean_dps,
                    self.settings.static_bias_max_std_dps, self._corrector.compensator.refinable)
                self.get_logger().info(f'static bias: collecting {self.settings.bias_samples} samples; '
                                       'keep the gyro still')
            return self._collection

    def _finish_collection(self, collection: StaticBiasCollector) -> None:
        assert isinstance(collection, _Collection)
        try:
            bias = collection.result()
        except (MotionError, ValueError) as e:
            self._end_collection(collection, None, str(e))
        else:
            self._end_collection(collection, bias, '')

    def _end_collection(self, collection: _Collection, bias: StaticBias | None, error: str) -> None:
        with self._lock:
            if self._collection is not collection:
                return   # abandoned meanwhile
            self._collection = self._corrector.collector = None
            if bias is not None:
                self._corrector.compensator.bias = bias
                self._bias_outcome = 'ok'
                self._bias_time = time.monotonic()
                self.get_logger().info(f'static bias: {bias.describe()}')
            else:
                self._bias_outcome = 'refused'
                self._bias_refusal = error
                self.get_logger().warning(f'static bias refused, previous bias kept: {error}')
            collection.bias = bias
            collection.error = error
            self._finished.append(collection)
        self._replies.trigger()   # the replies go out on the executor

    def _defer_reply(self, response: Trigger.Response, header: Any) -> None:
        """Take the place of the service's send_response: join (or start) the collection; reply when it ends."""
        if self._closing.is_set():
            response.success, response.message = False, 'refused: the node is shutting down'
            self._send_reply(response, header)
            return
        collection = self._start_collection()
        with self._lock:
            if self._collection is collection:
                collection.waiting.append(header)
                return
        self._send_reply(self._reply(collection), header)   # it ended meanwhile

    @staticmethod
    def _reply(collection: _Collection) -> Trigger.Response:
        if collection.bias is not None:
            return Trigger.Response(success=True, message=collection.bias.describe())
        return Trigger.Response(success=False, message=f'refused, previous bias kept: {collection.error}')

    def _send_replies(self) -> None:
        with self._lock:
            finished, self._finished = self._finished, []
        for collection in finished:
            response = self._reply(collection)
            for header in collection.waiting:
                self._send_reply(response, header)

    def _watch_collection(self) -> None:
        """Give up a collection that gets no frames (the replies say why), or one the shutdown cuts short."""
        collection = self._collection
        if collection is None:
            return
        if self._closing.is_set():
            self._end_collection(collection, None, 'the node is shutting down')
        elif collection.waiting and time.monotonic() - collection.last_sample > COLLECTION_STALL_S:
            self._end_collection(collection, None, f'no frame from the gyro for {COLLECTION_STALL_S:.0f} s '
                                                   f'(link: {self._driver.stats.last_error or "no data"})')

    # --- diagnostics ---------------------------------------------------------------------

    def _publish_diagnostics(self) -> None:
        msg = DiagnosticArray()
        msg.header.stamp = self.get_clock().now().to_msg()
        msg.status = [self._link_status(), self._bias_status(), self._temperature_status()]
        if self.settings.log_path:
            self._check_log_file()
            msg.status.append(self._log_status())
        self._diag_pub.publish(msg)

    def _status(self, name: str, level: bytes, message: str, values: dict[str, Any]) -> DiagnosticStatus:
        # The fully qualified name: two gyros in two namespaces report apart.
        return DiagnosticStatus(level=level, name=f'{self.get_fully_qualified_name()}: {name}', message=message,
                                hardware_id=f'KVH {"FOG" if self.settings.protocol == KVH_FOG else "RD2100"} '
                                            f'{self.calibration.serial_number}',
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
            'rejected': stats.rejected, 'bytes_skipped': stats.bytes_skipped, 'published': self._published,
            'lost_frames': stats.lost_frames}
        for reason, count in stats.rejected_by_reason.items():
            values[f'rejected_{reason}'] = count
        # Frames read but not published, per reason: since the last report, and in all.
        dropped = dict(self._corrector.dropped)
        recent = {reason: count - self._dropped_reported[reason] for reason, count in dropped.items()}
        self._dropped_reported = dropped
        values['dropped'] = sum(dropped.values())
        for reason, count in dropped.items():
            values[f'dropped_{reason}'] = count
        if dropped[NOT_FINITE]:
            values['last_not_finite_error'] = self._corrector.last_drop_error or 'a non-finite compensated rate'
        # kvh_fog: frames the gyro numbered but that never came, and frames it flagged invalid, since the last report.
        invalid = stats.rejected_by_reason.get(AXIS_INVALID, 0)
        lost, self._lost_reported = stats.lost_frames - self._lost_reported, stats.lost_frames
        flagged, self._invalid_reported = invalid - self._invalid_reported, invalid
        if not stats.connected:
            return self._status('link', DiagnosticStatus.ERROR, f'disconnected: {stats.last_error}', values)
        if rate_hz == 0.0:
            return self._status('link', DiagnosticStatus.WARN, 'connected, no frames', values)
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

    def _log_status(self) -> DiagnosticStatus:
        with self._log_lock:
            values = {'file': self._log_file, 'rows_not_logged': self._log_rows_lost, 'last_error': self._log_error}
            if self._log is None:
                return self._status('raw log', DiagnosticStatus.ERROR,
                                    f'not logging: {self._log_error}; retrying every {LOG_RETRY_S:g} s', values)
        return self._status('raw log', DiagnosticStatus.OK, f'logging to {values["file"]}', values)

    def _bias_status(self) -> DiagnosticStatus:
        with self._lock:   # one consistent snapshot: the reader thread may end a collection meanwhile
            collection = self._collection
            state = 'collecting' if collection is not None else self._bias_outcome
            bias, refusal, bias_time = self._corrector.compensator.bias, self._bias_refusal, self._bias_time
        values: dict[str, Any] = {
            'state': state, 'static_bias_drift_dps': f'{bias.static_bias_drift_dps:.6f}',
            'calc_static_bias_drift_dps': f'{bias.calc_static_bias_drift_dps:.6f}',
            'samples': bias.samples, 'rate_std_dps': f'{bias.rate_std_dps:.6f}',
            'age_s': f'{time.monotonic() - bias_time:.0f}' if bias.samples else 'none',
            # The temperature-rate refinement: pending while the bias window is kept, then its change.
            'refinement': ('pending' if bias.window is not None and self._corrector.compensator.refinable
                           else f'{bias.refined_dps:+.6f} dps' if bias.refined_dps else 'none'),
            'last_refusal': refusal}
        if collection is not None:
            progress = f'{collection.count}/{self.settings.bias_samples}'
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
        outside = self._corrector.compensator.clamped
        recent, self._outside_range_reported = outside - self._outside_range_reported, outside
        implausible = self._corrector.dropped[IMPLAUSIBLE_TEMPERATURE]
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
            parts.append(f'{recent} frames since the last report were outside the calibrated range {low}..{high} degC '
                         '(compensated at its edge)')
        if dropped:
            level = DiagnosticStatus.ERROR
            parts.append(f'{dropped} frames since the last report claimed a temperature outside '
                         f'{PLAUSIBLE_TEMPERATURE_C[0]:g}..{PLAUSIBLE_TEMPERATURE_C[1]:g} degC and were dropped: '
                         'corrupt frames, or ' + ('kvh_fog.temperature_units is not what the unit sends'
                                                  if self.settings.protocol == KVH_FOG
                                                  else 'the temperature field is not m[3]:m[4] on this unit'))
        return self._status('temperature', level, '; '.join(parts), values)

    # --- shutdown ------------------------------------------------------------------------

    def close(self) -> None:
        """Stop the driver (no frame after this) and close the raw log."""
        self._closing.set()
        self._driver.stop()
        collection = self._collection
        if collection is not None:   # the calls waiting for it hear why, rather than time out
            self._end_collection(collection, None, 'the node is shutting down')
            try:
                self._send_replies()
            except Exception as e:   # the context may be shut down already (SIGINT): nothing more to say
                self.get_logger().warning(f'static bias replies not sent at shutdown: {type(e).__name__}: {e}')
        with self._log_lock:
            log, self._log = self._log, None
        if log is not None:
            try:
                log.close()
            except (OSError, ValueError) as e:
                self.get_logger().error(f'closing the raw log {self._log_file}: {e}')


# Set by Python's part of SIGINT: one that came before rclpy.init installed rclpy's handler stops the node too.
_INTERRUPTED = threading.Event()


def _stop_through_rclpy(signum: int, frame: object) -> None:
    """Python's part of SIGINT: only noted (rclpy's handler, chained before it, stops the node)."""
    _INTERRUPTED.set()


def main(args: list[str] | None = None) -> int:
    """Entry point of ``gyro_node``; returns the exit code."""
    argv = sys.argv if args is None else args
    if any(arg in ('-h', '--help') for arg in argv[1:argv.index('--ros-args') if '--ros-args' in argv else None]):
        print(usage())
        return 0
    node: GyroNode | None = None
    # SIGINT stops the node through rclpy's handler, which shuts the context down and the executor with it.
    # Python's own handler would also raise KeyboardInterrupt wherever the main thread is: inside the thread
    # pool's `with lock:` it leaves the lock held, the pool's workers wait on it, and the exit waits on them
    # for ever (seen about once in 25 SIGINTs; faulthandler showed the three workers in Semaphore.release).
    _INTERRUPTED.clear()
    signal.signal(signal.SIGINT, _stop_through_rclpy)
    try:
        rclpy.init(args=argv)
        if _INTERRUPTED.is_set():   # before rclpy's handler was there to shut the context down
            return 0
        node = GyroNode(argv)
        executor = MultiThreadedExecutor(num_threads=3)
        executor.add_node(node)
        executor.spin()
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    except Exception as e:
        if not rclpy.ok() and (_INTERRUPTED.is_set() or node is not None and isinstance(e, _rclpy.RCLError)):
            # A signal shut the context down under a call to it: between two waits of the executor ("failed to
            # initialize wait set: the given context is not valid") or while the node was being built ("rclpy.init()
            # has not been called"). A stop as asked, not a failure.
            return 0
        if not isinstance(e, (ParameterError, CalibrationError, _rclpy.RCLError)):
            raise
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
