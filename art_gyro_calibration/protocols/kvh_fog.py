"""KVH's ``kvh_fog`` message: the unit's settings, CRC, encoder and incremental parser (pure: no I/O, no ROS).

The binary message of KVH's DSP-1760 gyros and 1725/1750/1775 IMUs, whose manuals are
public (1775 IMU technical manual, section 5): a 4-byte header (``FE 81 FF 55`` Format A, 36
bytes; ``56`` Format B, 40 bytes, with a microsecond timestamp; ``57`` Format C, 38 bytes, whose
temperature float is multiplexed with the magnetometer by the sequence number modulo 4), six
big-endian IEEE-754 floats (X, Y, Z rotation, then X, Y, Z acceleration, reserved on the
DSP-1760), a status byte (bits 0-2: gyro X, Y, Z valid; 4-6: the accelerometers; 3 and 7 always
0), a sequence number 0..127 that wraps, the temperature (signed 16-bit integer in A and B) and
a CRC-32/MPEG-2 over everything before it. The unit's settings (which axis is yaw, delta angle
or rate, radians or degrees, output rate, temperature units) are a :class:`KvhFogConfig`.
"""

from __future__ import annotations

import math
import re
import struct
import zlib
from dataclasses import dataclass

from art_gyro_calibration.frame import (AXIS_INVALID, BITS_PER_BYTE, NOT_FINITE, ChunkParser, ImuReading,
                                        ProtocolDescription, RawSample, check_int16)

# Rejection reasons, the keys of ParserStats.rejected_by_reason (with NOT_FINITE and AXIS_INVALID, of frame.py):
# each is one message.
BAD_CRC = 'bad_crc'             # a header and a message's length of bytes whose CRC is wrong
OTHER_FORMAT = 'other_format'   # the header of another message format than the configured one
REPEATED_SEQUENCE = 'repeated_sequence'   # the sequence number of the message before (a duplicate)
NO_TEMPERATURE_YET = 'no_temperature_yet'   # Format C: before the connection's first temperature
NO_INTERVAL = 'no_interval'     # a delta angle whose interval is not measured yet (the first messages of a connection)
BAD_TIMESTAMP = 'bad_timestamp'   # Format B: the unit's clock disagrees with the sequence steps at its mean interval

KVH_HEADER_PREFIX = b'\xfe\x81\xff'   # every format's header; the fourth byte names the format
KVH_SEQUENCE_MODULO = 128             # the sequence number counts 0..127 and wraps
KVH_STATUS_ALL_VALID = 0x77           # the manuals' normal status: three gyros and three accelerometers valid
KVH_MAX_OUTPUT_RATE_HZ = 5000.0       # the 1775's highest =DR; the DSP-1760's is 1000
KVH_ROTATIONS = ('delta_angle', 'rate')
KVH_ANGLE_UNITS = ('rad', 'deg')
# =TEMPUNITS: degrees or hundredths of a degree, Celsius or Fahrenheit.
KVH_TEMPERATURE_UNITS = ('C', 'C_100', 'F', 'F_100')
# Where a message's stamp comes from: its arrival (any format), or Format B's clock mapped to the host's.
KVH_TIMESTAMP_SOURCES = ('arrival', 'unit_clock')
# The unit's baud rates (=BAUD, 1775 manual section 8.3).
KVH_BAUDS = (9600, 19200, 38400, 57600, 115200, 460800, 576000, 921600, 4147200)
KVH_DEFAULT_BAUD = 921600
# The stream's message interval (formats without the unit's clock) is used once measured over this long: arrival
# jitter of a few ms (a USB adapter's latency timer) then errs by a few parts in 1000, and less as it goes on.
STREAM_BASELINE_S = 1.0
# A configured output_rate_hz this far from the measured rate is an error (the unit is not set as the node is told).
RATE_TOLERANCE = 0.02
# The stream's measure confirms the configured rate within this and within RATE_CONFIRMED_SE of its standard error:
# its interval is then the unit's exactly (the unit integrates over its own period), not the measure's few parts in
# 10,000 of host-side jitter; a unit set 0.9 % off is not confirmed.
RATE_CONFIRMED = 0.001
RATE_CONFIRMED_SE = 3.0
# A and C: arrivals this long, each a whole number of sequence wraps (within a quarter of one) later than the
# stream's line, are a gap of that many messages, not a stall (which the next reads catch up).
GAP_CONFIRM_S = 0.25
# Format B's clock: a message interval longer than this (the slowest =DR is 1 Hz) is a fault of the clock.
MAX_INTERVAL_US = 1_500_000
# Format B's clock agrees with the sequence steps at its mean interval within a tick either side (timestamps are
# whole microseconds) and this share: a drift that changes with temperature is parts per million.
CLOCK_AGREE_US = 2
CLOCK_AGREE = 1e-3
_KVH_HEADER = re.compile(rb'\xfe\x81\xff[\x55-\x57]')
_KVH_AXES = re.compile(r'[+-]?[xyz]')


@dataclass(frozen=True)
class KvhFormat:
    """One message format: its header, total length and the layout between header and CRC (big-endian)."""

    name: str
    header: bytes
    length: int
    layout: struct.Struct
    multiplexed: bool = False   # Format C: no 16-bit temperature; one float is temperature or magnetometer


KVH_FORMATS = {
    'A': KvhFormat('A', KVH_HEADER_PREFIX + b'\x55', 36, struct.Struct('>6fBBh')),
    'B': KvhFormat('B', KVH_HEADER_PREFIX + b'\x56', 40, struct.Struct('>6fIBBh')),   # + timestamp, microseconds
    'C': KvhFormat('C', KVH_HEADER_PREFIX + b'\x57', 38, struct.Struct('>7fBB'), multiplexed=True),
}
# Reverses the bits of a byte: CRC-32/MPEG-2 from zlib's reflected CRC-32 (see crc32_mpeg2).
_REVERSED_BITS = bytes(int(f'{i:08b}'[::-1], 2) for i in range(256))


def crc32_mpeg2(data: bytes) -> int:
    """CRC-32/MPEG-2 (poly 0x04C11DB7, init 0xFFFFFFFF, no reflection, no final XOR), the kvh_fog CRC.

    zlib's CRC-32 is the same polynomial and initial value with input and output reflected and a
    final XOR: feeding it bit-reversed bytes and reversing its output cancels both reflections, and
    XOR with 0xFFFFFFFF undoes the final XOR. It runs in C, a few microseconds per message.
    """
    reflected = zlib.crc32(data.translate(_REVERSED_BITS)) ^ 0xFFFFFFFF
    return int.from_bytes(reflected.to_bytes(4, 'little').translate(_REVERSED_BITS), 'big')


def _check_axis(name: str, value: object) -> None:
    if isinstance(value, bool):
        # YAML 1.1 (rcl's -p and params files) reads a bare y (and yes, on, true) as true, n (no, off) as false.
        raise ValueError(f'kvh_fog.{name} must be x, y or z with an optional sign, got the boolean {value}: YAML '
                         f'reads a bare y or n as a boolean; write +y (or -y), or quote it: "y"')
    if not isinstance(value, str) or not _KVH_AXES.fullmatch(value):
        raise ValueError(f'kvh_fog.{name} must be x, y or z with an optional sign (+z, -x, ...), got {value!r}')


def _unit_vector(axis: str) -> tuple[float, float, float]:
    v = [0.0, 0.0, 0.0]
    v['xyz'.index(axis[-1])] = -1.0 if axis.startswith('-') else 1.0
    return v[0], v[1], v[2]


def _valid(bits: int) -> tuple[bool, bool, bool]:
    """The x, y, z validity of three status bits (bit 0: x)."""
    return bool(bits & 1), bool(bits & 2), bool(bits & 4)


def _choice(name: str, value: object, choices: tuple[str, ...]) -> None:
    if value not in choices:
        raise ValueError(f'kvh_fog.{name} must be one of {", ".join(choices)}, got {value!r}')


@dataclass(frozen=True)
class KvhFogConfig:
    """What a kvh_fog unit is set to send, which its messages do not say; the defaults are the manuals' factory ones.

    The fields are the node's parameters ``kvh_fog.<field>`` and errors name them so. The
    output rate matters only for delta angles: the rate is the delta angle times it.
    """

    message_format: str = 'A'       # A (default), B or C (=OUTPUTFMT)
    yaw_axis: str = '+z'            # the axis that points up on the robot: x, y or z, '-' if it points down
    rotation: str = 'delta_angle'   # =ROTFMT: delta_angle (default) or rate
    angle_units: str = 'rad'        # =ROTUNITS: rad (default) or deg
    output_rate_hz: float = 1000.0  # =DR: messages per second
    temperature_units: str = 'C'    # =TEMPUNITS: C (default), C_100, F or F_100
    forward_axis: str = ''          # the axis that points forward on the robot; '' = the one after yaw_axis in x, y, z
    timestamp_source: str = 'arrival'   # arrival, or unit_clock (Format B: its microsecond clock mapped to the host's)

    def __post_init__(self) -> None:
        _choice('message_format', self.message_format, tuple(KVH_FORMATS))
        _check_axis('yaw_axis', self.yaw_axis)
        if self.forward_axis != '':
            _check_axis('forward_axis', self.forward_axis)
            if self.forward_axis[-1] == self.yaw_axis[-1]:
                raise ValueError(f'kvh_fog.forward_axis {self.forward_axis!r} must be another axis than '
                                 f'kvh_fog.yaw_axis {self.yaw_axis!r}')
        _choice('rotation', self.rotation, KVH_ROTATIONS)
        _choice('angle_units', self.angle_units, KVH_ANGLE_UNITS)
        rate = self.output_rate_hz
        if isinstance(rate, bool) or not isinstance(rate, (int, float)) or not 0 < rate <= KVH_MAX_OUTPUT_RATE_HZ:
            raise ValueError(f'kvh_fog.output_rate_hz must be a number of Hz in (0, {KVH_MAX_OUTPUT_RATE_HZ:g}], '
                             f'got {rate!r}')
        _choice('temperature_units', self.temperature_units, KVH_TEMPERATURE_UNITS)
        _choice('timestamp_source', self.timestamp_source, KVH_TIMESTAMP_SOURCES)
        if self.timestamp_source == 'unit_clock' and self.message_format != 'B':
            raise ValueError(f'kvh_fog.timestamp_source unit_clock needs kvh_fog.message_format B (the format with the '
                             f'unit\'s clock), got {self.message_format}')

    @property
    def format(self) -> KvhFormat:
        """The message format."""
        return KVH_FORMATS[self.message_format]

    @property
    def axis_index(self) -> int:
        """0, 1, 2 for x, y, z: the rotation float and the status bit of the yaw gyro."""
        return 'xyz'.index(self.yaw_axis[-1])

    @property
    def sign(self) -> float:
        """-1.0 if the yaw axis points down (REP 103: yaw is counter-clockwise seen from above), else 1.0."""
        return -1.0 if self.yaw_axis.startswith('-') else 1.0

    @property
    def delta_angle(self) -> bool:
        """The unit sends angles per message, which become rates by the message interval."""
        return self.rotation == 'delta_angle'

    @property
    def deg_per_unit(self) -> float:
        """Degrees (delta angle) or deg/s (rate) per unit of a rotation float."""
        return math.degrees(1.0) if self.angle_units == 'rad' else 1.0

    @property
    def dps_per_unit(self) -> float:
        """Yaw rate in deg/s per unit of the yaw axis' rotation float at the configured rate (the encoder's)."""
        per_rate = float(self.output_rate_hz) if self.delta_angle else 1.0
        return self.sign * self.deg_per_unit * per_rate

    @property
    def mounting(self) -> tuple[tuple[float, float, float], ...]:
        """Rows of the rotation from the unit's axes to the robot's (REP 103: x forward, y left, z up).

        Row 0 picks the forward axis, row 2 the yaw axis (both with their sign), row 1 is z x x.
        """
        forward = self.forward_axis or 'xyz'[(self.axis_index + 1) % 3]
        x = _unit_vector(forward)
        z = _unit_vector(self.yaw_axis)
        y = (z[1] * x[2] - z[2] * x[1], z[2] * x[0] - z[0] * x[2], z[0] * x[1] - z[1] * x[0])
        return x, y, z

    @property
    def description(self) -> KvhFogDescription:
        """The unit as the driver, node and diagnostics see it (no rate-jump check: its CRC-32 is trusted)."""
        # For the robot's x, y, z: the unit's axis and its sign (each row of the mounting has one nonzero entry).
        axes = tuple((max(range(3), key=lambda i: abs(row[i])), sum(row)) for row in self.mounting)
        temperature = 'kvh_fog.temperature_units is not what the unit sends'
        return KvhFogDescription(hardware='KVH FOG', checks_rate_jumps=False,
                                 stamps_by_unit_clock=self.timestamp_source == 'unit_clock', imu_axes=axes,
                                 reports_rate=True, temperature_hint=temperature,
                                 startup_rejections=(NO_INTERVAL, NO_TEMPERATURE_YET),
                                 output_rate_hz=float(self.output_rate_hz), message_format=self.message_format)

    def max_rate_hz(self, baud: int) -> float:
        """The messages per second ``baud`` carries in this format."""
        return baud / (BITS_PER_BYTE * self.format.length)

    def _temperature_scale(self) -> tuple[float, float]:
        """(a, b) with degC = a * wire value + b."""
        unit = 0.01 if self.temperature_units.endswith('_100') else 1.0
        if self.temperature_units.startswith('F'):
            return unit * 5.0 / 9.0, -32.0 * 5.0 / 9.0
        return unit, 0.0

    def temperature_c(self, value: float) -> float:
        """The temperature in degC of a temperature as sent."""
        a, b = self._temperature_scale()
        return a * value + b

    def temperature_wire(self, temp_c: float) -> float:
        """A temperature in degC as the unit sends it (unrounded): the inverse of :meth:`temperature_c`."""
        a, b = self._temperature_scale()
        return (temp_c - b) / a


@dataclass(frozen=True)
class KvhFogDescription(ProtocolDescription):
    """A kvh_fog unit as the driver, node and diagnostics see it: the whole IMU, a checked output rate."""

    output_rate_hz: float = 1000.0
    message_format: str = 'A'

    def rate_error(self, measured_hz: float | None) -> str:
        """Why ``kvh_fog.output_rate_hz`` is wrong: the measured rate more than RATE_TOLERANCE from it ('' if not)."""
        configured = self.output_rate_hz
        if measured_hz is None or abs(configured / measured_hz - 1.0) <= RATE_TOLERANCE:
            return ''
        source = 'its clock' if self.message_format == 'B' else 'the stream'
        return (f'kvh_fog.output_rate_hz is {configured:g} Hz but the unit sends {measured_hz:.2f} messages/s '
                f'(measured by {source}): set the parameter to the unit\'s =DR; rates use the measured interval')


class StreamInterval:
    """The unit's message interval on the host's clock: least squares of arrival time against message number.

    The message number counts every interval the sequence numbers say passed (lost messages
    too), so the fit needs no assumption about the rate, and its error falls as the span grows.
    """

    __slots__ = ('_k', '_n0', '_t0', '_mean_n', '_mean_t', '_c_nt', '_c_nn', '_c_tt', '_span_s', '_last_n')

    def __init__(self) -> None:
        self.reset()

    def reset(self) -> None:
        """Forget the measure (a new connection: the unit may have been set to another rate meanwhile)."""
        self._k = 0
        self._n0 = 0
        self._t0 = 0
        self._mean_n = self._mean_t = self._c_nt = self._c_nn = self._c_tt = self._span_s = self._last_n = 0.0

    def add(self, number: int, arrival_ns: int) -> None:
        """Message ``number`` (intervals since the connection opened) arrived at ``arrival_ns`` (monotonic)."""
        if not self._k:
            self._n0, self._t0 = number, arrival_ns
        n = float(number - self._n0)
        t = (arrival_ns - self._t0) * 1e-9
        self._k += 1
        dn = n - self._mean_n
        dt = t - self._mean_t
        self._mean_n += dn / self._k
        self._mean_t += dt / self._k
        self._c_nt += dn * (t - self._mean_t)
        self._c_tt += dt * (t - self._mean_t)
        self._c_nn += dn * (n - self._mean_n)
        self._span_s, self._last_n = t, n

    def lateness(self, number: int, arrival_ns: int, configured_s: float) -> float | None:
        """Intervals by which message ``number`` arrived after the line so far; None before any message.

        The fitted line once it spans half STREAM_BASELINE_S; before, the line of ``configured_s`` (the configured
        interval) through the last message added: a gap in the first half second is counted too (a unit set to
        another rate than configured is the diagnostics' rate error).
        """
        if not self._k:
            return None
        if self._span_s < STREAM_BASELINE_S * 0.5 or self._k < 3 or self._c_nt <= 0.0:
            return ((arrival_ns - self._t0) * 1e-9 - self._span_s) / configured_s - (number - self._n0 - self._last_n)
        slope = self._c_nt / self._c_nn
        return ((arrival_ns - self._t0) * 1e-9 - self._mean_t) / slope - (number - self._n0 - self._mean_n)

    @property
    def interval_error_s(self) -> float:
        """The standard error of the fitted interval (the residuals' spread over the span of message numbers)."""
        if self._k < 3 or self._c_nn <= 0.0:
            return math.inf
        residual = max(0.0, self._c_tt - self._c_nt ** 2 / self._c_nn) / (self._k - 2)
        return math.sqrt(residual / self._c_nn)

    @property
    def interval_s(self) -> float | None:
        """Seconds per message, once measured over STREAM_BASELINE_S; else None."""
        if self._span_s < STREAM_BASELINE_S or self._k < 3 or self._c_nn <= 0.0:
            return None
        interval = self._c_nt / self._c_nn
        return interval if interval > 0.0 else None


def encode_kvh_fog(rotation: tuple[float, float, float], acceleration: tuple[float, float, float], status: int,
                   sequence: int, temperature: float, message_format: str = 'A',
                   magnetic: tuple[float, float, float] = (0.0, 0.0, 0.0), timestamp_us: int = 0) -> bytes:
    """One message of wire values (in the units the unit is set to), CRC appended.

    Formats A and B carry ``temperature`` as a signed 16-bit integer; Format C carries it as a
    float in the messages whose sequence number is 0 mod 4 and the magnetometer's x, y, z in the
    others. ``timestamp_us`` is Format B's.
    """
    fmt = KVH_FORMATS[message_format]
    if not 0 <= sequence < KVH_SEQUENCE_MODULO:
        raise ValueError(f'sequence must be 0..{KVH_SEQUENCE_MODULO - 1}, got {sequence}')
    if not 0 <= status <= 0xFF:
        raise ValueError(f'status must be a byte, got {status}')
    if fmt.multiplexed:
        mux = temperature if sequence % 4 == 0 else magnetic[sequence % 4 - 1]
        body = fmt.layout.pack(*rotation, *acceleration, mux, status, sequence)
    else:
        if temperature != int(temperature):
            raise ValueError(f'Format {message_format} carries the temperature as an integer, got {temperature}')
        check_int16('temperature', int(temperature))
        extra = (timestamp_us,) if message_format == 'B' else ()
        body = fmt.layout.pack(*rotation, *acceleration, *extra, status, sequence, int(temperature))
    message = fmt.header + body
    return message + crc32_mpeg2(message).to_bytes(4, 'big')


class KvhFogEncoder:
    """Messages of a unit set as ``config`` for samples in deg/s and degC, numbered 0..127 in turn (the fake gyro).

    The other two gyros read 0; the accelerometer reads 1 g up the yaw axis (a level unit).
    The temperature is rounded to what the unit's units carry. ``status`` goes into every
    message (a test sets it to flag a gyro invalid).
    """

    def __init__(self, config: KvhFogConfig) -> None:
        self.config = config
        self.sequence = 0
        self.status = KVH_STATUS_ALL_VALID
        self.unit_time_us = 0.0   # Format B's clock: one interval of the output rate per message

    def _rotation(self, rate_dps: float) -> float:
        config = self.config
        per_rate = float(config.output_rate_hz) if config.delta_angle else 1.0
        return rate_dps / (config.sign * config.deg_per_unit * per_rate)

    def __call__(self, rate_dps: float, temp_c: float) -> bytes:
        """The next message: ``rate_dps`` about the yaw axis, ``temp_c``."""
        config = self.config
        axis = config.axis_index
        rotation = [0.0, 0.0, 0.0]
        rotation[axis] = self._rotation(rate_dps)
        acceleration = [0.0, 0.0, 0.0]
        acceleration[axis] = config.sign
        temperature = config.temperature_wire(temp_c)
        if not config.format.multiplexed:
            temperature = round(temperature)
        sequence = self.sequence
        self.sequence = (sequence + 1) % KVH_SEQUENCE_MODULO
        timestamp = int(self.unit_time_us) % 2 ** 32
        self.unit_time_us += 1e6 / config.output_rate_hz
        return encode_kvh_fog((rotation[0], rotation[1], rotation[2]),
                              (acceleration[0], acceleration[1], acceleration[2]),
                              self.status, sequence, temperature, config.message_format, timestamp_us=timestamp)


class KvhFogParser(ChunkParser):
    """Incremental parser of kvh_fog messages of the configured format; samples in deg/s and degC.

    A candidate is the format's header and the message's length of bytes from it; a good CRC
    takes it whole. After a bad CRC the search resumes at the byte after the header's first, so
    a message cut short and followed by a whole one loses only the cut one. Every message with a
    good CRC advances the sequence number; the numbers skipped since the message before, less the
    messages rejected for their CRC in between (each is one rejected frame, not also a lost one),
    are added to ``stats.lost_frames`` (a gap of 128 or more: counted by Format B's clock where the
    arrivals show it, else a leap of the clock; in A and C by the arrival times; none is counted
    across :meth:`reset`, where the count is unknown). A good message is still rejected, and
    counted by reason, when the status byte flags
    the yaw gyro invalid, when it repeats the sequence number before it (a duplicate: publishing
    it would count the rotation twice), when a value is not finite, in Format C before the first temperature of the
    connection (the temperature comes every fourth message and is held until the next), and, for
    delta angles, while the message interval is not known. So every message the unit numbered is
    a frame, a rejection or lost; bytes between messages are ``stats.bytes_skipped``, each run of
    them counted once in ``stats.garbage_runs``, not as a rejected message.

    Delta angles become rates by the measured interval, never by an unconfirmed output rate:
    Format B's by the unit's own clock (its timestamps over the sequence steps, the mean since the
    connection opened); A's and C's by :class:`StreamInterval`, fitted to the arrival times
    ``feed`` is given (the driver's monotonic clock at the read, less the wire time of the bytes
    after each message: ``byte_ns`` per byte, at the port's baud), or the configured rate's where
    that measure confirms it (within RATE_CONFIRMED and RATE_CONFIRMED_SE standard errors of the
    fit: the unit integrates over its own period exactly; host jitter does not).
    Without arrival times, A and C delta angles stay rejected as ``no_interval``.
    """

    def __init__(self, config: KvhFogConfig, byte_ns: int = 0) -> None:
        super().__init__((BAD_CRC, OTHER_FORMAT, AXIS_INVALID, REPEATED_SEQUENCE, NOT_FINITE, NO_TEMPERATURE_YET,
                          NO_INTERVAL, BAD_TIMESTAMP))
        self._in_garbage = False
        self.config = config
        self.description = config.description
        fmt = config.format
        self.frame_bytes = fmt.length
        self.byte_ns = byte_ns   # wire time of a byte (the port's baud): arrival of a message's end within a chunk
        self._format = fmt
        self._axis = config.axis_index
        self._sign = config.sign
        self._deg_per_unit = config.deg_per_unit
        self._delta = config.delta_angle
        self._clocked = fmt.name == 'B'
        self._configured_hz = float(config.output_rate_hz)
        self.stream = StreamInterval()
        self._last_sequence: int | None = None
        self._last_arrival_ns: int | None = None   # A and C: when the message of _last_sequence was read
        self._number = 0                    # intervals since the connection opened, by the sequence numbers
        self._number_out: int | None = None   # _number of the last message returned (frames_missed)
        self._bad_crc_since = 0             # bad CRCs since the last good message (those messages are not lost)
        self._temp_c: float | None = None   # Format C: the latest temperature
        self._last_time_us: int | None = None   # Format B: the previous message's clock
        self._unit_time_us = 0                  # Format B: the clock over _unit_steps intervals (the mean interval)
        self._unit_steps = 0
        self._unwrapped_us = 0                  # Format B: the clock unwrapped since the connection opened
        self._gap: tuple[int, int] | None = None   # A and C: (wraps, first arrival) of a gap being confirmed
        # Format B, after a message rejected for its clock: (clock, steps since, unwrapped) of the one before it.
        self._good: tuple[int, int, int] | None = None

    def reset(self) -> None:
        """Drop a partly received message; the sequence, held temperature and intervals restart; statistics kept."""
        self._skip(len(self._buffer))
        self._buffer = b''
        self._in_garbage = False
        self._last_sequence = self._last_arrival_ns = None
        self._number = 0
        self._number_out = None
        self._bad_crc_since = 0
        self._temp_c = None
        self._last_time_us = None
        self._unit_time_us = self._unit_steps = self._unwrapped_us = 0
        self._gap = self._good = None
        self.stream.reset()

    def _skip(self, count: int) -> None:
        if count <= 0:
            return
        self.stats.bytes_skipped += count
        if not self._in_garbage:
            self.stats.garbage_runs += 1   # a port opened mid-message, line noise
            self._in_garbage = True

    @property
    def measured_rate_hz(self) -> float | None:
        """Messages per second as measured (Format B: the unit's clock over a second or more; else the stream)."""
        if self._clocked:
            if self._unit_time_us < STREAM_BASELINE_S * 1e6 or not self._unit_steps:
                return None
            return self._unit_steps * 1e6 / self._unit_time_us
        interval = self.stream.interval_s
        return None if interval is None else 1.0 / interval

    def feed(self, data: bytes, arrival_ns: int | None = None) -> list[tuple[RawSample, int]]:
        """Parse a chunk read at ``arrival_ns`` (monotonic); each valid message with the offset just past it."""
        buf, held = self._join(data)
        out: list[tuple[RawSample, int]] = []
        stats = self.stats
        reasons = stats.rejected_by_reason
        fmt = self._format
        length = fmt.length
        pos = 0
        keep = -1
        last_end = -1   # the end (in buf) of the chunk's last message with a good CRC
        while (match := _KVH_HEADER.search(buf, pos)) is not None:
            start = match.start()
            self._skip(start - pos)
            pos = start
            if buf[start + 3] != fmt.header[3]:
                reasons[OTHER_FORMAT] += 1
                stats.bytes_skipped += 4
                self._in_garbage = True   # the rest of that message is skipped as part of this rejection
                pos = start + 4
                continue
            end = start + length
            if end > len(buf):
                keep = start   # still arriving
                break
            if crc32_mpeg2(buf[start:end - 4]) != int.from_bytes(buf[end - 4:end], 'big'):
                reasons[BAD_CRC] += 1
                self._bad_crc_since += 1
                stats.bytes_skipped += 1
                self._in_garbage = True
                pos = start + 1
                continue
            self._in_garbage = False
            pos = end
            sample, reason = self._decode(buf, start, None if arrival_ns is None
                                          else arrival_ns - (len(buf) - end) * self.byte_ns)
            last_end = end
            if sample is None:
                reasons[reason] += 1
                stats.bytes_skipped += length
            else:
                out.append((sample, end - held))
                self.frames_missed.append(0 if self._number_out is None else self._number - self._number_out - 1)
                self._number_out = self._number
                stats.frames += 1
        if last_end >= 0 and arrival_ns is not None:
            # The read returned as its last byte came: this message's end came the bytes after it earlier.
            self._arrived(arrival_ns - (len(buf) - last_end) * self.byte_ns)
        if keep < 0:
            # A header's first bytes at the very end may be the start of the next message.
            keep = len(buf)
            for k in (3, 2, 1):
                if len(buf) - k >= pos and buf.endswith(KVH_HEADER_PREFIX[:k]):
                    keep = len(buf) - k
                    break
        self._skip(keep - pos)
        self._buffer = buf[keep:]
        return out

    def _arrived(self, arrival_ns: int) -> None:
        """The latest message arrived at ``arrival_ns``: into the stream's fit, or a gap of whole sequence wraps.

        128 lost messages or more look like 0 to 127 by the sequence alone; arrivals that stay a
        whole number of wraps late for GAP_CONFIRM_S count them (the fit waits meanwhile).
        """
        late = self.stream.lateness(self._number, arrival_ns, 1.0 / self._configured_hz)
        wraps = 0 if late is None else round(late / KVH_SEQUENCE_MODULO) * KVH_SEQUENCE_MODULO
        if late is None or wraps <= 0 or abs(late - wraps) > KVH_SEQUENCE_MODULO / 4:
            self._gap = None
            self.stream.add(self._number, arrival_ns)
        elif self._gap is None or self._gap[0] != wraps:
            self._gap = (wraps, arrival_ns)
        elif arrival_ns - self._gap[1] >= GAP_CONFIRM_S * 1e9:
            self._gap = None
            self._number += wraps
            self.stats.lost_frames += wraps
            self.stream.add(self._number, arrival_ns)

    def _decode(self, buf: bytes, start: int, arrival_ns: int | None) -> tuple[RawSample | None, str]:
        """The sample of a message whose CRC is good (its end read at ``arrival_ns``), or None and the reason."""
        values = self._format.layout.unpack_from(buf, start + 4)
        config = self.config
        timestamp: int | None = None
        if self._format.multiplexed:
            mux, status, sequence = values[6:]
        elif self._clocked:
            timestamp, status, sequence, temperature = values[6:]
        else:
            status, sequence, temperature = values[6:]
        last = self._last_sequence
        steps = 0
        if last is not None:
            steps = (sequence - last) % KVH_SEQUENCE_MODULO
            if timestamp is not None:
                steps += self._clock_wraps(timestamp, steps, arrival_ns)
            elif not steps:
                steps = self._arrival_wraps(arrival_ns)
            if not steps:
                return None, REPEATED_SEQUENCE
            # A message rejected for its CRC was received (and counted) once: not also lost.
            self.stats.lost_frames += max(0, steps - 1 - self._bad_crc_since)
        self._bad_crc_since = 0
        self._last_sequence, self._last_arrival_ns = sequence, arrival_ns
        self._number += steps
        interval_s = self._clock_interval(timestamp, steps) if self._clocked else self._stream_interval()
        if self._format.multiplexed:
            if sequence % 4 == 0:
                self._temp_c = config.temperature_c(mux)
            temp_c = self._temp_c
        else:
            temp_c = config.temperature_c(temperature)
        if not status >> self._axis & 1:
            return None, AXIS_INVALID
        if temp_c is None:
            return None, NO_TEMPERATURE_YET
        if interval_s is not None and interval_s < 0.0:
            if self._delta:
                return None, BAD_TIMESTAMP
            interval_s = None   # a rate needs no interval
        per_unit = self._deg_per_unit
        if self._delta:
            if interval_s is None:
                return None, NO_INTERVAL
            per_unit /= interval_s
        rates = (values[0] * per_unit, values[1] * per_unit, values[2] * per_unit)
        rate_dps = self._sign * rates[self._axis]
        if not (math.isfinite(rate_dps) and math.isfinite(temp_c)):
            return None, NOT_FINITE
        imu = ImuReading(rates, (values[3], values[4], values[5]), _valid(status), _valid(status >> 4))
        return RawSample(rate_dps, temp_c, None if timestamp is None else self._unwrapped_us, imu, interval_s), ''

    def _stream_interval(self) -> float | None:
        """A and C: the stream's measured interval, or the configured one where the measure confirms it."""
        stream = self.stream
        interval = stream.interval_s
        if interval is None:
            return None
        off = abs(interval * self._configured_hz - 1.0)
        if off <= RATE_CONFIRMED and off * interval <= RATE_CONFIRMED_SE * stream.interval_error_s:
            return 1.0 / self._configured_hz
        return interval

    def _arrival_wraps(self, arrival_ns: int | None) -> int:
        """A and C: the whole wraps since the last message, whose sequence number this one repeats (0 if unsure).

        127 lost messages look like a repeat by the sequence alone: the time between the two reads over the interval
        (measured, else configured) counts them, when it is a whole number of wraps within a quarter of one.
        """
        last = self._last_arrival_ns
        if arrival_ns is None or last is None:
            return 0
        intervals = (arrival_ns - last) * 1e-9 / (self.stream.interval_s or 1.0 / self._configured_hz)
        wraps = round(intervals / KVH_SEQUENCE_MODULO) * KVH_SEQUENCE_MODULO
        return wraps if wraps > 0 and abs(intervals - wraps) <= KVH_SEQUENCE_MODULO / 4 else 0

    def _clock_wraps(self, timestamp: int, steps: int, arrival_ns: int | None) -> int:
        """Format B: the whole wraps of the sequence the unit's clock says passed besides ``steps`` (0 if unsure).

        128 lost messages or more look like 0 to 127 by the sequence alone; the clock's elapsed time
        over the mean interval counts them, when it is a whole number of intervals within half of one
        and the message (read at ``arrival_ns``) came at least half of them late on the stream's line:
        one that came on time says no message was lost but the clock leapt by whole wraps (then
        rejected as any leap is).
        """
        if self._last_time_us is None or not self._unit_steps:
            return 0
        intervals = (timestamp - self._last_time_us) % 2 ** 32 * self._unit_steps / self._unit_time_us
        wraps = round((intervals - steps) / KVH_SEQUENCE_MODULO) * KVH_SEQUENCE_MODULO
        if wraps <= 0 or abs(intervals - steps - wraps) > 0.5:
            return 0
        late = None if arrival_ns is None else self.stream.lateness(self._number + steps, arrival_ns,
                                                                    self._unit_time_us * 1e-6 / self._unit_steps)
        return 0 if late is not None and late < wraps / 2 else wraps

    def _clock_interval(self, timestamp: int | None, steps: int) -> float | None:
        """Format B: seconds per message by the unit's clock; -1.0 if the clock went wrong; None before two messages.

        The mean over the connection, not the last interval alone: a microsecond tick is 0.1 % of a
        1 kHz interval. Once it is known, a message whose clock disagrees with its sequence steps at
        that mean (beyond CLOCK_AGREE) is rejected and the unwrapped time goes on by the mean; the
        next message tells which it was: one glitched stamp (it agrees with the message before the
        rejected one), a leap (it agrees with the rejected one: the clock is followed from there, a
        clock fault) or another rate (neither: the mean starts anew).
        """
        assert timestamp is not None
        last, self._last_time_us = self._last_time_us, timestamp
        if last is None or not steps:
            return None
        elapsed = (timestamp - last) % 2 ** 32   # the microsecond counter wraps after 71.6 minutes
        if self._unit_steps:
            mean_us = self._unit_time_us / self._unit_steps
            good, self._good = self._good, None
            if good is not None:
                since_us = (timestamp - good[0]) % 2 ** 32
                if _clock_agrees(since_us, good[1] + steps, mean_us):   # one glitched stamp: from the one before
                    self._unwrapped_us = good[2]
                    return self._clock_accept(since_us, good[1] + steps)
                if _clock_agrees(elapsed, steps, mean_us):
                    self.stats.clock_faults += 1   # a leap: a mapping of the clock to the host's is made anew
                else:
                    self._unit_time_us = self._unit_steps = 0   # another rate: the mean starts anew
            elif not _clock_agrees(elapsed, steps, mean_us):
                self._good = (last, steps, self._unwrapped_us)
                self._unwrapped_us += round(steps * mean_us)
                return -1.0
        if not 0 < elapsed <= steps * MAX_INTERVAL_US:
            self.stats.clock_faults += 1
            return -1.0
        return self._clock_accept(elapsed, steps)

    def _clock_accept(self, elapsed_us: int, steps: int) -> float:
        """Format B: ``elapsed_us`` over ``steps`` into the unwrapped clock and the mean; the mean interval."""
        self._unwrapped_us += elapsed_us
        self._unit_time_us += elapsed_us
        self._unit_steps += steps
        return self._unit_time_us * 1e-6 / self._unit_steps


def _clock_agrees(elapsed_us: int, steps: int, mean_us: float) -> bool:
    """Format B: ``elapsed_us`` is ``steps`` intervals of ``mean_us`` within CLOCK_AGREE_US and CLOCK_AGREE."""
    expected = steps * mean_us
    return abs(elapsed_us - expected) <= CLOCK_AGREE_US + CLOCK_AGREE * expected
