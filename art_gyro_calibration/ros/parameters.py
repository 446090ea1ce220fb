"""The node's parameters: declaration, ranges, descriptors, ``--help``, and their checks at startup.

Parameters are strict: an unknown name (with the closest valid one), a value of the wrong type
or out of its range, or a calibration that does not fit, is a :class:`ParameterError` naming it.
The node's own look into its params files says which file gave a value and refuses another
gyro's calibration.
"""

from __future__ import annotations

import math
import re
from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import dataclass
from typing import Any, NamedTuple

# The message wheels ship no type hints.
from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor   # type: ignore[import-untyped]
from rclpy.node import Node
from sensor_msgs.msg import BatteryState   # type: ignore[import-untyped]
from std_msgs.msg import Float64   # type: ignore[import-untyped]

from art_gyro_calibration.calibration import (CALIBRATION_KEYS, EXTRA_SIGNAL_TYPES, SIGNAL_PATTERN, Calibration,
                                              CalibrationError, check_fed, closest, extra_signal_parameter,
                                              find_calibration_file, flatten, from_parameters, is_calibration_key,
                                              load_calibration, read_yaml, resolve_calibration_url, shorten)
from art_gyro_calibration.driver import BAUDS
from art_gyro_calibration.parked import ParkedSettings
from art_gyro_calibration.protocols import KVH_FOG, PROTOCOLS
from art_gyro_calibration.protocols.kvh_fog import KVH_DEFAULT_BAUD, KvhFogConfig
from art_gyro_calibration.signals import SIGNALS
from art_gyro_calibration.static_bias import DEFAULT_MAX_MEAN_DPS, DEFAULT_MAX_STD_DPS, DEFAULT_SAMPLES

NODE_NAME = 'gyro_node'
# What says parked_bias.topic's robot is parked.
PARKED_TYPES = ('bool', 'odometry')
IMU_TOPIC = 'imu/data_raw'


class Range(NamedTuple):
    """Inclusive bounds of a numeric parameter."""

    low: float
    high: float


# name: (default, description[, constraint]), the node's parameters besides a calibration's own.
# The constraint is a Range for a number or a tuple of the allowed values; the type is the default's.
PARAMETERS: dict[str, tuple[Any, ...]] = {
    'port': ('/dev/ttyUSB0', 'Serial port of the gyro.'),
    'baud': (9600, 'Serial baud rate (check the unit\'s setting; a 1 kHz unit needs 115200 or more); '
                   f'{KVH_DEFAULT_BAUD} for protocol kvh_fog when not given.', BAUDS),
    'protocol': ('binary', 'Frame format on the wire: binary (8-byte RD2100 frames), ascii '
                           '("<raw_rate> <raw_temp>" lines) or kvh_fog (KVH DSP-1760, 1725/1750/1775 IMUs: '
                           'the kvh_fog.* parameters below).', PROTOCOLS),
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
    'guard_look_ahead': (False, 'binary and ascii: the frame guard also refuses a one-frame spike of a corruption\'s '
                                'size that the next frame returns from, at one frame of latency (each frame is '
                                'published when the next one comes).'),
    'publish_uncalibrated': (False, 'Also publish imu/uncalibrated (sensor_msgs/Imu): the rate with only the scale '
                                    'factor applied, rad/s, at the same stamps: with imu/temperature, a recorded bag '
                                    'then holds what calibrate fit and calibrate allan need.'),
    # A static bias whenever the robot is parked (art_gyro_calibration.parked).
    'parked_bias.enabled': (False, 'Take a static bias whenever the robot is parked for bias_samples frames (the '
                                   'service\'s checks, the mean relative to the bias in force); needs '
                                   'parked_bias.topic or parked_bias.gyro_stillness.'),
    'parked_bias.topic': ('', 'Topic that says the robot is parked (relative names follow the namespace and '
                              'remappings); empty: none (then parked_bias.gyro_stillness must be true).'),
    'parked_bias.type': ('bool', 'Its message: bool (std_msgs/Bool, true = parked) or odometry (nav_msgs/Odometry: '
                                 'parked while its twist is within parked_bias.max_linear_mps and max_angular_dps).',
                         PARKED_TYPES),
    'parked_bias.max_age_s': (1.0, 'A parked message older than this (s) is not "parked": a collection the topic '
                                   'falls silent in is aborted.', Range(0.01, 3600.0)),
    'parked_bias.max_linear_mps': (0.01, 'Odometry: parked while the linear speed (m/s) is at most this.',
                                   Range(0.0, 10.0)),
    'parked_bias.max_angular_dps': (0.02, 'Odometry: parked while the angular rate (deg/s) is at most this: the '
                                          'slowest turn the odometry can refuse.', Range(0.0, 10.0)),
    'parked_bias.gyro_stillness': (False, 'Also let the gyro\'s own stillness decide (without a topic: alone): '
                                          'refused unless the rate spread is within parked_bias.max_std_dps and the '
                                          'mean compensated rate within the Earth\'s rate plus 3 standard errors.'),
    'parked_bias.max_std_dps': (0.02, 'With gyro_stillness: a parked bias whose rate spread (deg/s) exceeds this '
                                      '(or static_bias_max_std_dps, if smaller) is refused.', Range(1e-6, 10.0)),
    'parked_bias.settle_s': (1.0, 'Seconds parked before a collection starts.', Range(0.0, 3600.0)),
    'parked_bias.min_interval_s': (600.0, 'After a bias, the next parked one waits until the robot moved and parked '
                                          'again, or this long (s).', Range(0.0, 604800.0)),
}

# --- protocol kvh_fog (KVH DSP-1760, 1725/1750/1775 IMUs) ----------------------------------------
# What the unit is set to send, which its messages do not say: name: (default, description). Declared
# and checked at startup whatever the protocol; read by the kvh_fog parser only. Defaults: the manuals'.
_KVH_FOG_DESCRIPTIONS = {
    'message_format': 'kvh_fog message format (=OUTPUTFMT): A (36 bytes, the default), B (40) or C (38).',
    'yaw_axis': 'kvh_fog axis that points up on the robot: x, y or z, or -x, -y, -z if it points down.',
    'rotation': 'kvh_fog rotation output (=ROTFMT): delta_angle (the default) or rate.',
    'angle_units': 'kvh_fog angle units (=ROTUNITS): rad (the default) or deg.',
    'output_rate_hz': 'kvh_fog messages per second (=DR), 1 to 5000 and no more than the baud carries; checked '
                      'against the measured rate (an ERROR beyond 2 %); rates come from the measured interval.',
    'temperature_units': 'kvh_fog temperature units (=TEMPUNITS): C (the default), C_100, F or F_100.',
    'timestamp_source': 'kvh_fog stamps: arrival (the read, less the wire time) or unit_clock (Format B: the unit\'s '
                        'microsecond clock mapped to ROS time, drift and offset tracked; by arrival until mapped).',
    'forward_axis': 'kvh_fog axis that points forward on the robot (+x, -y, ...): with yaw_axis, the REP 103 axes of '
                    'the whole IMU message; empty: the axis after yaw_axis in x, y, z.',
}
KVH_FOG_PARAMETERS: dict[str, tuple[Any, str]] = {
    f'kvh_fog.{name}': (getattr(KvhFogConfig(), name), description)
    for name, description in _KVH_FOG_DESCRIPTIONS.items()}
# The IMU message's uncalibrated axes (kvh_fog): name: (default, description, range).
KVH_FOG_PARAMETERS.update({
    'kvh_fog.rate_stddev': (0.001, 'kvh_fog standard deviation (rad/s) of the x and y rates, which the calibration '
                                   'does not correct; its square is angular_velocity_covariance[0] and [4].'),
    'kvh_fog.acceleration_stddev': (0.05, 'kvh_fog standard deviation (m/s^2) of each acceleration; its square is '
                                          'the diagonal of linear_acceleration_covariance.'),
})
KVH_FOG_RANGES = {'kvh_fog.rate_stddev': Range(1e-7, 1.0), 'kvh_fog.acceleration_stddev': Range(1e-6, 100.0)}


# --- signals from outside the gyro ---------------------------------------------------------------
# Per signal a calibration's terms need that the gyro does not measure (a log column such as supply_v, fitted with
# calibrate fit --node-signal): extra_signals.<signal>.<field>: (default, description[, range]).
EXTRA_SIGNAL_FIELDS: dict[str, tuple[Any, ...]] = {
    'topic': ('', 'Topic that carries the signal (relative names follow the namespace and remappings); required for '
                  'each signal a calibration term needs that the gyro does not measure (such as supply_v).'),
    'type': ('float64', 'Its message: ' + ', '.join(f'{k} ({v})' for k, v in EXTRA_SIGNAL_TYPES.items())
             + '. A value that is not finite (BatteryState\'s NaN, unknown) is not a value.',
             tuple(EXTRA_SIGNAL_TYPES)),
    'max_age_s': (5.0, 'A value older than this (s) at a frame is stale: still applied (the last known), but the '
                       'rate is flagged: covariance[8] as before a static bias, an ERROR in /diagnostics.',
                  Range(0.01, 86400.0)),
}


# How each extra_signals.<signal>.type is read: its message and the field that holds the value.
EXTRA_SIGNAL_MESSAGES: dict[str, tuple[type, str]] = {
    'float64': (Float64, 'data'), 'battery_state': (BatteryState, 'voltage')}


def ros_type_name(message: type) -> str:
    """A message class's type as the ROS graph names it (``sensor_msgs/msg/BatteryState``)."""
    return f'{message.__module__.split(".")[0]}/msg/{message.__name__}'


class ParameterError(ValueError):
    """A node parameter that cannot be used, named in the message."""


@dataclass(frozen=True)
class ExtraSignal:
    """Where the node gets one signal from outside the gyro: ``extra_signals.<signal>.*``, checked."""

    signal: str
    topic: str
    type: str
    max_age_s: float


def extra_signal_name(name: str) -> tuple[str, str] | None:
    """(signal, field) of an ``extra_signals.<signal>.<field>`` parameter name, else None."""
    parts = name.split('.')
    if len(parts) == 3 and parts[0] == 'extra_signals' and parts[2] in EXTRA_SIGNAL_FIELDS \
            and SIGNAL_PATTERN.match(parts[1]):
        return parts[1], parts[2]
    return None


def extra_signal_settings(values: Mapping[str, Any], calibration: Calibration,
                          source: str) -> tuple[tuple[ExtraSignal, ...], tuple[ExtraSignal, ...]]:
    """The ``extra_signals.*`` parameters given (``values``, by name) checked against the calibration from ``source``.

    Returns (the signals its terms need, in their order; those given that no term needs). A term on a
    signal without a topic is refused naming the parameter to set, as is a derived signal or a bad value.
    """
    given: dict[str, dict[str, Any]] = {}
    for name, value in values.items():
        parsed = extra_signal_name(name)
        if parsed is None:
            continue
        signal, field = parsed
        if signal in SIGNALS:
            raise ParameterError(f'parameter {name}: {signal} is derived from the gyro\'s frames, not fed by a topic')
        given.setdefault(signal, {})[field] = _coerce(name, value, EXTRA_SIGNAL_FIELDS[field][0])
    try:
        check_fed(calibration, [s for s, fields in given.items() if fields.get('topic', '').strip()],
                  f'the calibration of {calibration.serial_number} from {source}')
    except CalibrationError as e:
        raise ParameterError(str(e)) from None
    signals = []
    for signal, fields in given.items():
        topic = fields.get('topic', '')
        if not topic.strip():
            raise ParameterError(f'parameter {extra_signal_parameter(signal)} must name the topic of {signal} '
                                 f'(other extra_signals.{signal}.* parameters are given)')
        kind = fields.get('type', EXTRA_SIGNAL_FIELDS['type'][0])
        if kind not in EXTRA_SIGNAL_TYPES:
            name = extra_signal_parameter(signal, 'type')
            raise ParameterError(f'parameter {name} must be {describe_constraint(name)}, got {kind!r}')
        max_age_s = fields.get('max_age_s', EXTRA_SIGNAL_FIELDS['max_age_s'][0])
        name = extra_signal_parameter(signal, 'max_age_s')
        low, high = _constraint(name)
        if not (math.isfinite(max_age_s) and low <= max_age_s <= high):
            raise ParameterError(f'parameter {name} must be in {describe_constraint(name)}, got {max_age_s!r}')
        signals.append(ExtraSignal(signal, topic, kind, max_age_s))
    needed = [t.signal for t in calibration.terms]
    return (tuple(sorted((e for e in signals if e.signal in needed), key=lambda e: needed.index(e.signal))),
            tuple(e for e in signals if e.signal not in needed))


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
    publish_uncalibrated: bool = False
    guard_look_ahead: bool = False
    parked_bias_enabled: bool = False
    parked_bias_topic: str = ''
    parked_bias_type: str = 'bool'
    parked_bias_max_age_s: float = 1.0
    parked_bias_max_linear_mps: float = 0.01
    parked_bias_max_angular_dps: float = 0.02
    parked_bias_gyro_stillness: bool = False
    parked_bias_max_std_dps: float = 0.02
    parked_bias_settle_s: float = 1.0
    parked_bias_min_interval_s: float = 600.0

    def value(self, name: str) -> Any:
        """A parameter's value by its name (``parked_bias.topic`` is field ``parked_bias_topic``)."""
        return getattr(self, name.replace('.', '_'))

    @property
    def parked(self) -> ParkedSettings:
        """What the parked bias logic needs."""
        return ParkedSettings(bool(self.parked_bias_topic.strip()), self.parked_bias_gyro_stillness,
                              self.parked_bias_max_age_s, self.parked_bias_settle_s, self.parked_bias_min_interval_s)


def _entry(name: str) -> tuple[Any, ...]:
    """(default, description[, constraint]) of a node parameter or of an ``extra_signals.<signal>.<field>``."""
    parsed = extra_signal_name(name)
    return EXTRA_SIGNAL_FIELDS[parsed[1]] if parsed is not None else PARAMETERS[name]


def _constraint(name: str) -> Any:
    entry = _entry(name)
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
    source = values.get('parked_bias.topic', '').strip() or values.get('parked_bias.gyro_stillness')
    if values.get('parked_bias.enabled') and not source:
        raise ParameterError('parameter parked_bias.topic must name the topic that says the robot is parked '
                             '(or parked_bias.gyro_stillness be true) when parked_bias.enabled is true')
    return Settings(**{name.replace('.', '_'): value for name, value in values.items()})


def descriptor(name: str) -> ParameterDescriptor:
    """Read-only descriptor of a node parameter, with its range where it is a number."""
    default, description = _entry(name)[:2]
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


def usage(summary: str) -> str:
    """``gyro_node --help``: how to run it, ``summary`` (what it does), every parameter with its default and range."""
    lines = [f'usage: {NODE_NAME} [--help] --ros-args [-p NAME:=VALUE]... [--params-file FILE]... '
             '[-r __ns:=/NAMESPACE]', '', summary.replace('``', ''), '',
             'parameters (read-only; checked at startup, an unknown or bad one ends the node with exit 1):']
    for name, (default, description, *_) in PARAMETERS.items():
        allowed = describe_constraint(name)
        lines.append(f'  {name} ({type(default).__name__}, default {default!r}{", " + allowed if allowed else ""})')
        lines.append(f'      {description}')
    lines += ['', 'protocol kvh_fog (KVH DSP-1760, 1725/1750/1775 IMUs): what the unit is set to send, and the IMU '
              'message:']
    for name, (default, description) in KVH_FOG_PARAMETERS.items():
        bounds = KVH_FOG_RANGES.get(name)
        allowed = f', {bounds.low:g}..{bounds.high:g}' if bounds else ''
        lines.append(f'  {name} ({type(default).__name__}, default {default!r}{allowed})')
        lines.append(f'      {description}')
    lines += ['', 'signals from outside the gyro: for each <signal> a calibration term needs that the gyro does not '
              'measure (a supply voltage; calibrate fit --node-signal), where it comes from:']
    for field, (default, description, *_) in EXTRA_SIGNAL_FIELDS.items():
        name = extra_signal_parameter('<signal>', field)
        allowed = describe_constraint(extra_signal_parameter('signal', field))
        lines.append(f'  {name} ({type(default).__name__}, default {default!r}{", " + allowed if allowed else ""})')
        lines.append(f'      {description}')
    lines += ['', 'calibration parameters (from the calibration file, read-only): '
              + ', '.join(sorted(CALIBRATION_KEYS)) + ', extended.<signal>.*',
              f'QoS of {IMU_TOPIC} (default reliable, depth 10): qos_overrides./<namespace>/{IMU_TOPIC}.publisher.'
              '{reliability,history,depth,durability}',
              'topics out: imu/data_raw (sensor_msgs/Imu), imu/temperature (std_msgs/Float64), imu/is_calibrated '
              '(std_msgs/Bool, latched: true once a static bias is in force), imu/uncalibrated (sensor_msgs/Imu, '
              'with publish_uncalibrated), /diagnostics (diagnostic_msgs/DiagnosticArray); topics in: each '
              'extra_signals.<signal>.topic, parked_bias.topic; service: imu/static_bias (std_srvs/Trigger)']
    return '\n'.join(lines)


# The rcl options that give parameters, each followed by its argument: a rule ``[node:]name:=value``, or a file.
PARAMETER_RULE_OPTIONS = ('-p', '--param')
PARAMS_FILE_OPTION = '--params-file'


def ros_parameter_options(argv: Sequence[str]) -> Iterator[tuple[str, str]]:
    """(option, argument) of each ``-p``/``--param`` and ``--params-file`` among a command line's ROS arguments."""
    in_ros_args = False
    args = iter(argv)
    for arg in args:
        if arg == '--ros-args':
            in_ros_args = True
        elif arg == '--':
            in_ros_args = False
        elif in_ros_args and arg in (*PARAMETER_RULE_OPTIONS, PARAMS_FILE_OPTION):
            value = next(args, None)
            if value is not None:
                yield arg, value


def params_files(argv: Sequence[str]) -> list[str]:
    """The ``--params-file`` paths among the ROS arguments of a command line."""
    return [value for option, value in ros_parameter_options(argv) if option == PARAMS_FILE_OPTION]


@dataclass(frozen=True)
class GivenValue:
    """One value the user gave a parameter (as text), and where, for people."""

    value: str
    source: str


def given_values(argv: Sequence[str], name: str, node_name: str,
                 files: Mapping[str, Mapping[str, Any]]) -> list[GivenValue]:
    """Every value of parameter ``name`` given to node ``node_name`` (fully qualified), in command-line order.

    From each ``-p [node:]name:=value`` whose node prefix (a name, ``*`` or ``**``, as rcl accepts) matches, and
    each params file in ``files`` (:func:`params_file_values`) that sets it. rcl merges them by node entry, not
    by their order, so a value that differs from another is the user's mistake whichever rcl keeps.
    """
    given = []
    for option, argument in ros_parameter_options(argv):
        if option == PARAMS_FILE_OPTION:
            values = files.get(argument, {})
            if name in values:
                what = 'calibration' if 'polynomial.coefficients' in values else 'parameters'
                given.append(GivenValue(str(values[name]), f'the {what} in {argument}'))
            continue
        rule, separator, text = argument.partition(':=')
        prefix, colon, rule_name = rule.rpartition(':')
        if separator and rule_name == name and (not colon or _entry_pattern(prefix).match(node_name)):
            value = text.strip()
            if len(value) > 1 and value[0] == value[-1] and value[0] in '\'"':
                value = value[1:-1]   # a quoted string, as rcl reads it (anything else that is no string: rcl's)
            given.append(GivenValue(value, f'{option} {shorten(argument, 80)} on the command line'))
    return given


def check_agree(given: Sequence[GivenValue], name: str, why: str) -> GivenValue | None:
    """The first of values given a parameter (empty ones left out) if all agree, else a :class:`ParameterError`."""
    given = [g for g in given if g.value]
    for other in given[1:]:
        if other.value != given[0].value:
            raise ParameterError(f'parameter {name} is {shorten(repr(given[0].value), 80)} from {given[0].source} '
                                 f'but {shorten(repr(other.value), 80)} from {other.source}: {why}')
    return given[0] if given else None


def check_params_files(argv: Sequence[str]) -> None:
    """Read every ``--params-file`` as :func:`params_file_values` will, before rcl parses them.

    rcl's parser hangs on a multi-MB file (and blocks on a FIFO) ignoring SIGINT: a file that is
    not a regular one, too large, or not the YAML the node accepts is refused here first.
    """
    for path in params_files(argv):
        read_yaml(path, 'params file')


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


class NodeParameters:
    """A node's parameters read, checked and declared (read-only) at startup: its own, kvh_fog's, the calibration's.

    It looks at the node's overrides (rclpy's ``_parameter_overrides``) before declaring anything,
    so that a name nothing reads is refused, not ignored, and every value is checked first.
    """

    def __init__(self, node: Node, argv: Sequence[str]) -> None:
        self._node = node
        self._argv = argv
        self._files = params_file_values(params_files(argv), node.get_fully_qualified_name())
        # Known now: the node's own, a calibration's, rclpy's (use_sim_time); QoS overrides once the publisher is made.
        self.check_known_names(lambda name: name in PARAMETERS or name in KVH_FOG_PARAMETERS
                               or is_calibration_key(name) or node.has_parameter(name)
                               or name.startswith('qos_overrides.') or extra_signal_name(name) is not None)
        values = {name: self._override(name, entry[0]) for name, entry in PARAMETERS.items()}
        if values['protocol'] == KVH_FOG and 'baud' not in node._parameter_overrides:
            values['baud'] = KVH_DEFAULT_BAUD   # the unit's factory rate, not an RD2100's
        self.settings = check_settings(values)
        for name in PARAMETERS:
            # Read-only: the node reads them once at startup, so a later change is refused, not ignored.
            node.declare_parameter(name, self.settings.value(name), descriptor(name), ignore_override=True)
        self.kvh_fog, self.kvh_rate_stddev, self.kvh_acceleration_stddev = self._kvh_fog_config()
        if self.settings.protocol == KVH_FOG:
            carried = self.kvh_fog.max_rate_hz(self.settings.baud)
            if self.kvh_fog.output_rate_hz > carried:
                raise ParameterError(
                    f'parameter kvh_fog.output_rate_hz is {self.kvh_fog.output_rate_hz:g} but baud '
                    f'{self.settings.baud} carries at most {carried:.0f} Format {self.kvh_fog.message_format} '
                    f'messages ({self.kvh_fog.format.length} bytes) per second: raise baud or lower the rate')
        self.calibration, self.calibration_source = self._load_calibration()
        if self.settings.protocol == KVH_FOG:
            check_kvh_fog_calibration(self.calibration, self.calibration_source)
        self.extra_signals, self.unused_extra_signals = extra_signal_settings(
            {name: p.value for name, p in node._parameter_overrides.items() if extra_signal_name(name)},
            self.calibration, self.calibration_source)
        for extra in self.extra_signals + self.unused_extra_signals:
            for field in EXTRA_SIGNAL_FIELDS:
                name = extra_signal_parameter(extra.signal, field)
                node.declare_parameter(name, getattr(extra, field), descriptor(name), ignore_override=True)

    def _where(self, name: str) -> str:
        """Which params file gave a parameter (the last one, as rcl applies them), else the command line."""
        files = [path for path, values in self._files.items() if name in values]
        return files[-1] if files else 'the command line'

    def check_known_names(self, known: Callable[[str], bool]) -> None:
        """Refuse a parameter given to the node that nothing reads, naming the closest valid name."""
        names = set(PARAMETERS) | set(KVH_FOG_PARAMETERS) | set(CALIBRATION_KEYS) | set(self._node._parameters)
        # A misspelt field of an extra signal: the valid fields of the signals named.
        names |= {extra_signal_parameter(name.split('.')[1], field) for name in self._node._parameter_overrides
                  if name.startswith('extra_signals.') and name.count('.') == 2 for field in EXTRA_SIGNAL_FIELDS}
        for name in self._node._parameter_overrides:
            if not known(name):
                raise ParameterError(f'unknown parameter {name!r} (from {self._where(name)}){closest(name, names)}')

    def _override(self, name: str, default: Any) -> Any:
        if name not in self._node._parameter_overrides:
            return default
        return _coerce(name, self._node._parameter_overrides[name].value, default)

    def _kvh_fog_config(self) -> tuple[KvhFogConfig, float, float]:
        values: dict[str, Any] = {}
        for name, (default, description) in KVH_FOG_PARAMETERS.items():
            given = self._node._parameter_overrides.get(name)
            if name.endswith('_axis') and given is not None and isinstance(given.value, bool):
                value = given.value   # YAML's bare y: KvhFogConfig refuses it with the hint to quote it
            else:
                value = self._override(name, default)
            bounds = KVH_FOG_RANGES.get(name)
            if bounds is not None and not (math.isfinite(value) and bounds.low <= value <= bounds.high):
                raise ParameterError(f'parameter {name} must be in {bounds.low:g}..{bounds.high:g}, got {value!r}')
            if not isinstance(value, bool):   # declared once KvhFogConfig has refused a boolean axis
                self._node.declare_parameter(
                    name, value, ParameterDescriptor(description=description, read_only=True), ignore_override=True)
            values[name.removeprefix('kvh_fog.')] = value
        rate_stddev = values.pop('rate_stddev')
        acceleration_stddev = values.pop('acceleration_stddev')
        try:
            return KvhFogConfig(**values), rate_stddev, acceleration_stddev
        except ValueError as e:
            raise ParameterError(f'parameter {e}') from None

    def _load_calibration(self) -> tuple[Calibration, str]:
        serial = self.settings.serial_number
        given = {name: p.value for name, p in self._node._parameter_overrides.items()
                 if is_calibration_key(name) and name != 'serial_number'}
        # Every serial and calibration file the user gave must agree: rcl keeps one of them, not by their order.
        name = self._node.get_fully_qualified_name()
        given_serial = check_agree(given_values(self._argv, 'serial_number', name, self._files), 'serial_number',
                                   'refusing a calibration of another gyro')
        check_agree(given_values(self._argv, 'calibration_file', name, self._files), 'calibration_file',
                    'give one calibration file')
        if given:
            if self.settings.calibration_file:
                raise ParameterError(f'parameter calibration_file is set and a calibration came in as parameters '
                                     f'(from {self._where("polynomial.coefficients")}): give one or the other')
            files = sorted({self._where(name) for name in given})
            where = 'parameters (' + ', '.join(files) + ')'
            calibration = from_parameters({**given, 'serial_number': serial}, where)
        elif self.settings.calibration_file:
            path = resolve_calibration_url(self.settings.calibration_file)
            calibration, where = load_calibration(path), str(path)
            if given_serial is not None and calibration.serial_number != given_serial.value:
                raise ParameterError(f'{path}: serial_number is {calibration.serial_number!r}, '
                                     f'expected {given_serial.value!r} '
                                     f'(from {given_serial.source}): refusing a calibration of another gyro')
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
                self._node.declare_parameter(name, value, ParameterDescriptor(
                    description=f'calibration of {calibration.serial_number} (from {where})', read_only=True),
                    ignore_override=True)
        return calibration, where
