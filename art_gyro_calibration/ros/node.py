"""ROS 2 node ``gyro_node``: a serial gyro (an RD2100, or a KVH FOG) as a compensated yaw-rate source.

Per frame (on the driver's reader thread, so latency is one serial read) the core's
:class:`~art_gyro_calibration.compensation.FrameCorrector` scales, drops, compensates, feeds
a running static bias collection and corrects; the node publishes what it answers.

Topics (relative names, so they follow the node's namespace and remappings):

- ``imu/data_raw`` (sensor_msgs/Imu): ``angular_velocity.z`` is the compensated yaw rate in
  rad/s (REP 103: counter-clockwise seen from above is positive). Orientation and linear
  acceleration are not measured: element 0 of their covariances is -1 (REP 145). The gyro
  measures z only: x and y are reported as 0 with variance :data:`UNMEASURED_VARIANCE`, so a
  filter that fuses them gives them no weight; element 8 is ``yaw_rate_stddev`` squared while a
  static bias is in force, :data:`UNCORRECTED_YAW_VARIANCE` before (an uncorrected rate), and for a
  frame whose corrected rate is beyond the unit's range, published uncorrected.
  With ``protocol:=kvh_fog`` the message is the whole IMU: x and y rates and the three
  accelerations (m/s^2) too, in REP 103 axes from ``kvh_fog.yaw_axis`` and ``forward_axis``, with
  the variances of ``kvh_fog.rate_stddev`` and ``acceleration_stddev`` (an axis its status byte
  flags invalid, or not finite: 0 with :data:`UNMEASURED_VARIANCE`, or -1 for the accelerations).
- ``imu/is_calibrated`` (std_msgs/Bool, transient local): true once a static bias is in force.
- ``imu/temperature`` (std_msgs/Float64): the gyro temperature in degC.
- ``imu/uncalibrated`` (sensor_msgs/Imu), only with ``publish_uncalibrated``: the rate with only the
  scale factor applied (no polynomial, no static bias), rad/s, at the same stamps: what a
  recorded bag needs for ``calibrate fit`` and ``calibrate allan``.
- ``/diagnostics`` (diagnostic_msgs/DiagnosticArray, 1 Hz): link, static bias, temperature, raw log,
  each extra signal (:mod:`.diagnostics`).

Subscribed: for each signal a calibration term needs that the gyro does not measure (a supply
voltage, fitted with ``calibrate fit --node-signal``), ``extra_signals.<signal>.topic``
(std_msgs/Float64 ``data`` or sensor_msgs/BatteryState ``voltage``, best effort, so that it matches
any publisher). Each frame takes the latest finite value. Until one has arrived, the terms on these
signals are left out and no static bias is collected (the start-up one waits for it); while a value
is older than ``extra_signals.<signal>.max_age_s`` it is still applied, the last known; one beyond the
calibration's limits for it (:meth:`~art_gyro_calibration.calibration.Calibration.signal_limits`) is applied
at the limit. In each case the rate is flagged: covariance[8] is :data:`UNCORRECTED_YAW_VARIANCE` and the
signal's status an ERROR.

Subscribed with ``parked_bias.enabled``: ``parked_bias.topic`` (std_msgs/Bool or nav_msgs/Odometry, best effort),
which says when the robot is parked: a static bias is then taken (:mod:`art_gyro_calibration.parked`).

Service ``imu/static_bias`` (std_srvs/Trigger): collect a new static bias (:mod:`.bias_service`).
The raw log: :mod:`.raw_log`. Parameters are strict (:mod:`.parameters`): an unknown name, a value
of the wrong type or out of its range, or a calibration that does not fit, ends the node at
startup with a message naming it.
"""

from __future__ import annotations

import math
import os
import signal
import sys
import threading
import time
from collections.abc import Callable, MutableMapping, Sequence
from pathlib import Path
from typing import Any

import rclpy
from rclpy.executors import ExternalShutdownException, MultiThreadedExecutor
from rclpy.impl.implementation_singleton import rclpy_implementation as _rclpy
from rclpy.node import Node
from rclpy.qos_overriding_options import QoSOverridingOptions
from rclpy.qos import DurabilityPolicy, QoSPolicyKind, ReliabilityPolicy
from rclpy.utilities import ok, try_shutdown
from sensor_msgs.msg import Imu   # type: ignore[import-untyped]  # the message wheels ship no type hints
from std_msgs.msg import Bool, Float64   # type: ignore[import-untyped]  # the message wheels ship no type hints

from art_gyro_calibration.calibration import CalibrationError, extra_signal_parameter
from art_gyro_calibration.compensation import FrameCorrector, RunStart
from art_gyro_calibration.driver import SerialGyroDriver
from art_gyro_calibration.frame import STANDARD_GRAVITY, Frame, ImuReading, RawSample
from art_gyro_calibration.parked import ParkedBias, odometry_parked
from art_gyro_calibration.protocols import describe
from art_gyro_calibration.ros.bias_service import StaticBiasService
from art_gyro_calibration.ros.diagnostics import Diagnostics
from art_gyro_calibration.ros.parameters import (EXTRA_SIGNAL_MESSAGES, IMU_TOPIC, NODE_NAME, ExtraSignal,
                                                 NodeParameters, ParameterError, check_params_files, usage)
from art_gyro_calibration.ros.raw_log import RawLog
from art_gyro_calibration.ros.rclpy_typed import SerializedMessage, logger, qos_profile
from art_gyro_calibration.signals import SignalFeed

# Variance (rad/s)^2 given to the x and y rates, which a single-axis gyro does not measure:
# large enough that any filter fusing them ignores them, finite so that it stays usable.
UNMEASURED_VARIANCE = 1.0e6
# Variance (rad/s)^2 of the yaw rate before a static bias is in force (during the start-up bias, or for good
# if it is refused): (1 deg/s)^2. The rate is then uncorrected for the gyro's bias of the day, which a still
# gyro's static bias check lets through only under 0.1 deg/s (static_bias_max_mean_dps) and nothing bounds
# before one: large against the corrected yaw_rate_stddev (0.057 deg/s), so a filter leans on other sources.
UNCORRECTED_YAW_VARIANCE = math.radians(1.0) ** 2
# The policies of imu/data_raw a qos_overrides parameter may set (rclpy's default set lacks durability).
IMU_QOS_OVERRIDES = QoSOverridingOptions(policy_kinds=(QoSPolicyKind.RELIABILITY, QoSPolicyKind.HISTORY,
                                                       QoSPolicyKind.DEPTH, QoSPolicyKind.DURABILITY))
# imu/is_calibrated: the last value kept for subscribers that join later.
LATCHED_QOS = qos_profile(1, durability=DurabilityPolicy.TRANSIENT_LOCAL, reliability=ReliabilityPolicy.RELIABLE)
# An out-of-range temperature is said on the console at most this often.
TEMPERATURE_WARNING_PERIOD_S = 60.0
# An extra signal's topic: only the latest value matters; best effort matches reliable and best-effort publishers.
EXTRA_SIGNAL_QOS = qos_profile(1, reliability=ReliabilityPolicy.BEST_EFFORT)
# The Imu fields written per frame (the rest is fixed at start-up); a whole IMU (kvh_fog) writes IMU_AXES_FIELDS too.
IMU_FIELDS = ('header.stamp.sec', 'header.stamp.nanosec', 'angular_velocity.z', 'angular_velocity_covariance[8]')
IMU_AXES_FIELDS = ('angular_velocity.x', 'angular_velocity.y', 'angular_velocity_covariance[0]',
                   'angular_velocity_covariance[4]', 'linear_acceleration.x', 'linear_acceleration.y',
                   'linear_acceleration.z', 'linear_acceleration_covariance[0]', 'linear_acceleration_covariance[4]',
                   'linear_acceleration_covariance[8]')


class GyroNode(Node):
    """Owns the serial driver; corrects and publishes every frame; wires the service, raw log and diagnostics."""

    driver: SerialGyroDriver   # made last: it starts the frames

    def __init__(self, argv: Sequence[str] = ()) -> None:
        super().__init__(NODE_NAME)
        self._log = logger(self)
        parameters = NodeParameters(self, argv)
        self.settings, self.kvh_fog = parameters.settings, parameters.kvh_fog
        self.calibration, self.calibration_source = parameters.calibration, parameters.calibration_source
        self.extra_signals = parameters.extra_signals
        self.feeds = tuple(SignalFeed(e.signal, e.max_age_s) for e in self.extra_signals)   # aged on time.monotonic
        self.corrector = FrameCorrector(self.calibration, RunStart(self.settings.powered_on_at_start), self.feeds)
        self._closing = threading.Event()
        self.published = 0
        self.last_temp_c = math.nan   # of the last frame published
        # Outside it the console warns (at most every minute); no range known: never.
        self._temp_range = self.calibration.expected_range_c or (-math.inf, math.inf)
        self._outside_range_effect = (self.calibration.beyond_range
                                      if self.calibration.temperature_range_c is not None else
                                      'compensated by the polynomial as the report\'s program does (not clamped: '
                                      'temperature_warn_range_c is an assumed range)')
        self.raw_log = RawLog(self, self.settings.log_path, self.calibration.serial_number, self._closing)

        imu = Imu()
        imu.header.frame_id = self.settings.frame_id
        imu.orientation_covariance[0] = -1.0
        imu.linear_acceleration_covariance[0] = -1.0
        imu.angular_velocity_covariance[0] = UNMEASURED_VARIANCE
        imu.angular_velocity_covariance[4] = UNMEASURED_VARIANCE
        imu.angular_velocity_covariance[8] = UNCORRECTED_YAW_VARIANCE   # until a static bias is in force
        self.description = describe(self.settings.protocol, self.kvh_fog)
        # A whole IMU (kvh_fog): for the robot's x, y, z, the unit axis and its sign (REP 103 axes from the mounting).
        self._axes = self.description.imu_axes
        if self._axes:
            self._rate_variance = parameters.kvh_rate_stddev ** 2
            self._acceleration_variance = parameters.kvh_acceleration_stddev ** 2
        # The messages are published serialized, their per-frame fields written in place (doc/benchmark.md).
        self._imu = SerializedMessage(imu, IMU_FIELDS + (IMU_AXES_FIELDS if self._axes else ()))
        self._temperature = SerializedMessage(Float64(), ('data',))
        self._uncalibrated: SerializedMessage | None = None   # imu/uncalibrated's message, when publish_uncalibrated
        self._rate_scale = self.calibration.rate_scale_factor
        self._yaw_variance = self.settings.yaw_rate_stddev ** 2
        # Reliable, volatile, depth 10 unless overridden (qos_overrides.<topic>.publisher.* parameters, read-only).
        try:
            self._imu_pub = self.create_publisher(Imu, IMU_TOPIC, 10, qos_overriding_options=IMU_QOS_OVERRIDES)
        except Exception as e:   # rclpy raises several types for a bad override; all end here
            raise ParameterError(f'QoS override of {IMU_TOPIC}: {e}') from None
        parameters.check_known_names(self.has_parameter)
        self._temp_pub = self.create_publisher(Float64, 'imu/temperature', 10)
        self._calibrated_pub = self.create_publisher(Bool, 'imu/is_calibrated', LATCHED_QOS)
        self.is_calibrated = False   # a static bias in force: published on imu/is_calibrated
        self._calibrated_pub.publish(Bool(data=False))
        if self.settings.publish_uncalibrated:
            self._uncalibrated = SerializedMessage(imu, IMU_FIELDS[:3])   # the same frame and covariances
            self._uncalibrated_pub = self.create_publisher(Imu, 'imu/uncalibrated', 10)
        self.extra_topics = tuple(self._subscribe(extra, feed) for extra, feed in zip(self.extra_signals, self.feeds))
        for extra in parameters.unused_extra_signals:
            self._log.warning(f'parameters extra_signals.{extra.signal}.*: the calibration has no term on '
                              f'{extra.signal}; {extra.topic} is not subscribed')
        self.bias_service = StaticBiasService(self, self.settings, self.corrector, self._closing,
                                              lambda: self.driver.stats.last_error, self._on_bias,
                                              self.extra_signal_problems)
        if self.settings.parked_bias_enabled:
            self._subscribe_parked()
        self._diagnostics = Diagnostics(self)

        if self.settings.static_bias_on_startup:
            self.bias_service.start()
        self._log.info(
            f'calibration loaded: {self.calibration.serial_number} from {self.calibration_source}; '
            f'reading {self.settings.port} at {self.settings.baud} baud ({self.settings.protocol})')
        self.driver = SerialGyroDriver(self.settings.port, self.settings.baud, self.settings.protocol,
                                       self._on_frame, on_link=self._on_link, on_warning=self._on_driver_warning,
                                       clock_ns=lambda: self.get_clock().now().nanoseconds, kvh_fog=self.kvh_fog,
                                       rate_scale_dps=self.calibration.rate_scale_factor,
                                       guard_look_ahead=self.settings.guard_look_ahead)
        self.driver.start()

    # --- per frame (driver reader thread) ------------------------------------------------

    def _on_frame(self, frame: Frame) -> None:
        try:
            self._handle_frame(frame)
        except Exception as e:   # an exception here would end the driver's reader thread
            if not self._closing.is_set() and self.context.ok():
                self._log.error(f'frame not published: {type(e).__name__}: {e}',
                                throttle_duration_sec=5.0)

    def _handle_frame(self, frame: Frame) -> None:
        sample = frame.sample
        stamp_ns = frame.stamp_ns
        self._publish(sample.raw_rate, sample.raw_temp, stamp_ns, frame.steady_ns * 1e-9, sample)
        # After publishing: a log that fails (full disk) must not delay or stop the messages.
        # The log keeps what the wire said, at the steady time: a clock stepped back made the stamps' log unreadable.
        self.raw_log.write(frame.steady_ns * 1e-9, sample.raw_rate, sample.raw_temp)

    def _publish(self, raw_rate: float, raw_temp: float, stamp_ns: int, t: float,
                 sample: RawSample | None = None) -> None:
        corrector = self.corrector
        if corrector.step(raw_rate, raw_temp, t):
            return   # dropped, and counted by the corrector
        imu = self._imu
        put = imu.put
        sec, nanosec = divmod(stamp_ns, 1_000_000_000)
        put('header.stamp.sec', sec)
        put('header.stamp.nanosec', nanosec)
        put('angular_velocity.z', math.radians(corrector.rate_dps))
        if self._axes and sample is not None and sample.imu is not None:
            self._fill_imu(put, sample.imu)
        # Flagged as before a static bias: an extra signal missing, stale or beyond its limits, or a corrected rate
        # beyond the unit's range (published uncorrected).
        put('angular_velocity_covariance[8]', self._yaw_variance if self.is_calibrated and
            corrector.compensator.current else UNCORRECTED_YAW_VARIANCE)
        self._imu_pub.publish(imu.data())
        uncalibrated = self._uncalibrated
        if uncalibrated is not None:   # the rate as the compensator scales it, before any correction
            uncalibrated.put('header.stamp.sec', sec)
            uncalibrated.put('header.stamp.nanosec', nanosec)
            uncalibrated.put('angular_velocity.z', math.radians(raw_rate * self._rate_scale))
            self._uncalibrated_pub.publish(uncalibrated.data())
        temp_c = corrector.temp_c
        self._temperature.put('data', temp_c)
        self._temp_pub.publish(self._temperature.data())
        self.last_temp_c = temp_c
        low, high = self._temp_range
        if not low <= temp_c <= high:   # the Compensator counted it (and clamped it if the range is calibrated)
            self._log.warning(f'gyro temperature {temp_c:.2f} degC is outside the calibrated range '
                              f'{low:g}..{high:g} degC: {self._outside_range_effect}',
                              throttle_duration_sec=TEMPERATURE_WARNING_PERIOD_S)
        self.published += 1

    def _on_bias(self) -> None:
        """A static bias is in force (reader thread, before the frame that completed it is published)."""
        if not self.is_calibrated:   # a bias replaces a bias: the state changes once
            self.is_calibrated = True
            self._calibrated_pub.publish(Bool(data=True))

    # --- signals from outside the gyro ---------------------------------------------------------

    def _subscribe(self, extra: ExtraSignal, feed: SignalFeed) -> str:
        """Feed ``feed`` from its topic (on the executor); the topic's resolved name."""
        kind, field = EXTRA_SIGNAL_MESSAGES[extra.type]

        def received(message: Any) -> None:
            feed.put(getattr(message, field))
        try:
            subscription = self.create_subscription(kind, extra.topic, received, EXTRA_SIGNAL_QOS)
        except Exception as e:   # rclpy raises several types for a bad topic name
            raise ParameterError(f'parameter {extra_signal_parameter(extra.signal)}: {e}') from None
        self._log.info(f'{extra.signal} from {subscription.topic_name} ({extra.type}): the calibration\'s '
                       f'term on it is applied with the latest value, flagged when older than '
                       f'{extra.max_age_s:g} s')
        name: str = subscription.topic_name
        return name

    def _subscribe_parked(self) -> None:
        """Take a static bias whenever the robot is parked: per its topic, or the gyro's stillness alone."""
        settings = self.settings
        service = self.bias_service
        service.enable_parked(ParkedBias(settings.parked, time.monotonic()))
        topic = settings.parked_bias_topic
        stillness = ' and the gyro\'s stillness (its mean within the Earth\'s rate)' \
            if settings.parked_bias_gyro_stillness else ''
        if not topic.strip():
            self._log.info(f'parked bias: the gyro\'s stillness alone says when the robot is parked{stillness}')
            return
        max_linear, max_angular = settings.parked_bias_max_linear_mps, settings.parked_bias_max_angular_dps

        def received(message: Any) -> None:
            if kind is Bool:
                service.put_parked(bool(message.data))
                return
            linear, angular = message.twist.twist.linear, message.twist.twist.angular
            service.put_parked(odometry_parked((linear.x, linear.y, linear.z), (angular.x, angular.y, angular.z),
                                               max_linear, max_angular))
        kind: Any = Bool
        if settings.parked_bias_type == 'odometry':
            # Imported only here: a node without odometry does not load its message.
            from nav_msgs.msg import Odometry   # type: ignore[import-untyped]  # ROS messages: untyped
            kind = Odometry
        try:
            subscription = self.create_subscription(kind, topic, received, EXTRA_SIGNAL_QOS)
        except Exception as e:   # rclpy raises several types for a bad topic name
            raise ParameterError(f'parameter parked_bias.topic: {e}') from None
        self._log.info(f'parked bias: parked per {subscription.topic_name} ({settings.parked_bias_type}){stillness}; '
                       f'a message older than {settings.parked_bias_max_age_s:g} s is not parked')

    def extra_signal_problems(self) -> str:
        """Why the extra signals are not all current now ('' when they are), for a static bias that waits."""
        problems = []
        for feed, topic in zip(self.feeds, self.extra_topics):
            latest = feed.latest   # a value beyond the calibration's limits is not current either
            problem = feed.problem() or (self.calibration.signal_problem(feed.name, latest[0]) if latest else '')
            if problem:
                problems.append(f'{problem} on {topic}')
        return '; '.join(problems)

    def _fill_imu(self, put: Callable[[str, float], None], reading: ImuReading) -> None:
        """The x and y rates and the accelerations of a whole IMU in REP 103 axes (z is the calibrated yaw).

        ``put(field, value)`` writes an Imu field of :data:`IMU_AXES_FIELDS`.
        """
        (ix, sx), (iy, sy), _ = self._axes
        rates, rate_valid = reading.rates_dps, reading.rate_valid
        valid = rate_valid[ix] and math.isfinite(rates[ix])
        put('angular_velocity.x', math.radians(sx * rates[ix]) if valid else 0.0)
        put('angular_velocity_covariance[0]', self._rate_variance if valid else UNMEASURED_VARIANCE)
        valid = rate_valid[iy] and math.isfinite(rates[iy])
        put('angular_velocity.y', math.radians(sy * rates[iy]) if valid else 0.0)
        put('angular_velocity_covariance[4]', self._rate_variance if valid else UNMEASURED_VARIANCE)
        g = reading.acceleration_g
        # The three accelerometers valid (and a CRC-checked NaN is still no acceleration).
        if all(reading.acceleration_valid) and math.isfinite(g[0] + g[1] + g[2]):
            (ix, sx), (iy, sy), (iz, sz) = self._axes
            put('linear_acceleration.x', sx * g[ix] * STANDARD_GRAVITY)
            put('linear_acceleration.y', sy * g[iy] * STANDARD_GRAVITY)
            put('linear_acceleration.z', sz * g[iz] * STANDARD_GRAVITY)
            for field in IMU_AXES_FIELDS[-3:]:
                put(field, self._acceleration_variance)
        else:   # REP 145: not measured (a DSP-1760 has no accelerometers)
            for field in IMU_AXES_FIELDS[4:7]:
                put(field, 0.0)
            put('linear_acceleration_covariance[0]', -1.0)

    def _on_link(self, connected: bool, message: str) -> None:
        if connected:
            self._log.info(f'gyro link up: {message}')
        else:
            self._log.warning(f'gyro link down: {message}')

    def _on_driver_warning(self, message: str) -> None:
        self._log.warning(message)

    # --- shutdown ------------------------------------------------------------------------

    def close(self) -> None:
        """Stop the driver (no frame after this), end a static bias collection and close the raw log."""
        self._closing.set()
        self.driver.stop()
        self.bias_service.close()
        self.raw_log.close()


# Imported by rosidl_generator_py only to generate code (see main).
_ROSIDL_GENERATOR = 'rosidl_generator_py.generate_py_impl'
# The node's Fast DDS participant profile: fewer send buffers preallocated, nothing else (the file says why).
FASTDDS_PROFILE = Path(__file__).with_name('fastdds_profile.xml')
# Where a user's own Fast DDS profiles come from: Jazzy's Fast DDS 2.14 reads the first variable and the first
# file (in the working directory), Fast DDS 3 the second of each.
FASTDDS_PROFILE_VARIABLES = ('FASTRTPS_DEFAULT_PROFILES_FILE', 'FASTDDS_DEFAULT_PROFILES_FILE')
FASTDDS_PROFILE_FILES = ('DEFAULT_FASTRTPS_PROFILES.xml', 'DEFAULT_FASTDDS_PROFILES.xml')
# Set by Python's part of SIGINT: one that came before rclpy.init installed rclpy's handler stops the node too.
_INTERRUPTED = threading.Event()


def _stop_through_rclpy(signum: int, frame: object) -> None:
    """Python's part of SIGINT: only noted (rclpy's handler, chained before it, stops the node)."""
    _INTERRUPTED.set()


def use_own_fastdds_profile(environ: MutableMapping[str, str] | None = None) -> bool:
    """Point Fast DDS at :data:`FASTDDS_PROFILE` unless the user has a profile of their own; True if it did.

    Called before the participant exists (``rclpy.init``). A profile of the user's (either variable set, or a
    default profiles file in the working directory, which Fast DDS loads as well) is left alone and nothing is
    added to it. Only Fast DDS 2's variable is set: Fast DDS 3 (after Jazzy) reads another and keeps its defaults.
    """
    env = os.environ if environ is None else environ
    users = (any(env.get(name) for name in FASTDDS_PROFILE_VARIABLES)
             or any(Path(name).is_file() for name in FASTDDS_PROFILE_FILES))
    if users or not FASTDDS_PROFILE.is_file():
        return False
    env[FASTDDS_PROFILE_VARIABLES[0]] = str(FASTDDS_PROFILE)
    return True


def main(args: list[str] | None = None) -> int:
    """Entry point of ``gyro_node``; returns the exit code."""
    argv = sys.argv if args is None else args
    if any(arg in ('-h', '--help') for arg in argv[1:argv.index('--ros-args') if '--ros-args' in argv else None]):
        print(usage(__doc__.splitlines()[0]))
        return 0
    node: GyroNode | None = None
    # rosidl_generator_py's __init__ imports its code generator (lark, empy, hashlib with OpenSSL: megabytes resident)
    # to offer generate_py, which only a package build uses, and takes an ImportError there as
    # "not available". The node builds nothing: the message type supports it imports need only import_type_support.
    # None in sys.modules makes an import raise ImportError (importlib's documented rule; typeshed allows modules only).
    sys.modules.setdefault(_ROSIDL_GENERATOR, None)   # type: ignore[arg-type]
    use_own_fastdds_profile()
    # SIGINT stops the node through rclpy's handler, which shuts the context down and the executor with it.
    # Python's own handler would also raise KeyboardInterrupt wherever the main thread is: inside the thread
    # pool's `with lock:` it leaves the lock held, the pool's workers wait on it, and the exit waits on them
    # for ever (seen under repeated SIGINTs; faulthandler showed the three workers in Semaphore.release).
    _INTERRUPTED.clear()
    signal.signal(signal.SIGINT, _stop_through_rclpy)
    try:
        check_params_files(argv)   # before rcl's parser, which hangs on a huge file or a FIFO
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
        if not ok() and (_INTERRUPTED.is_set() or node is not None and isinstance(e, _rclpy.RCLError)):
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
                node.destroy_node()   # type: ignore[no-untyped-call]  # rclpy: destroy_node unannotated
        try_shutdown()
    return 0


if __name__ == '__main__':
    sys.exit(main())
