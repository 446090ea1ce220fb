r"""RD2100 frames on the wire: incremental parsers and encoders (pure: no I/O, no ROS).

No RD2100 manual is public. The binary protocol follows the best public description of
the E-Core family's output (a public driver for the E-Core 2000):

- a frame is 8 bytes; the first has its top bit set, the other seven have it clear;
- dropping the top bit of each byte and joining the 8 x 7 bits big-endian gives 7 bytes
  ``m[0..6]``; ``m[0] = -(m[1] + ... + m[6]) mod 256`` is the checksum;
- the rate is the signed 16-bit ``m[5]:m[6]`` in counts (x rate_scale_factor deg/s).

The temperature is not documented: this package carries it as the signed 16-bit
``m[3]:m[4]`` in counts (x 0.05 degC). ``m[1]``, ``m[2]`` are status bits of unknown
meaning: encoded as 0 and not exposed.

The ASCII protocol is one line per sample, ``<raw_rate> <raw_temp>\r\n`` (signed integers,
counts), for loggers and front-ends that re-emit the gyro's data as text.

The ``kvh_fog`` protocol is the binary message of KVH's DSP-1750/1760 gyros and 1725/1750/1775
IMUs, whose manuals are public (1775 IMU technical manual, section 5): a 4-byte header
(``FE 81 FF 55`` Format A, 36 bytes; ``56`` Format B, 40 bytes, with a microsecond timestamp;
``57`` Format C, 38 bytes, whose temperature float is multiplexed with the magnetometer by the
sequence number modulo 4), six big-endian IEEE-754 floats (X, Y, Z rotation, then X, Y, Z
acceleration, reserved on the DSP-1760), a status byte (bits 0-2: gyro X, Y, Z valid; 4-6: the
accelerometers; 3 and 7 always 0), a sequence number 0..127 that wraps, the temperature (signed
16-bit integer in A and B) and a CRC-32/MPEG-2 over everything before it. The unit's settings
(which axis is yaw, delta angle or rate, radians or degrees, output rate, temperature units) are a
:class:`KvhFogConfig`.

Parsers take bytes in arbitrary chunks (a frame may straddle reads), resynchronise after
garbage or a bad frame, and count every rejection by reason.
"""

from __future__ import annotations

import math
import re
import struct
import zlib
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Protocol

KVH_FOG = 'kvh_fog'
PROTOCOLS = ('binary', 'ascii', KVH_FOG)
INT16_MIN = -0x8000
INT16_MAX = 0x7FFF

# Rejection reasons, the keys of ParserStats.rejected_by_reason.
BAD_CHECKSUM = 'bad_checksum'   # binary: well-framed 8 bytes whose checksum is wrong
GARBAGE = 'garbage'             # binary: a run of bytes that cannot start a frame (counted once per run)
MALFORMED = 'malformed'         # ascii: a line that is not two integers
OUT_OF_RANGE = 'out_of_range'   # ascii: an integer outside the signed 16-bit range
LINE_TOO_LONG = 'line_too_long'  # ascii: no newline within MAX_LINE_BYTES
BAD_CRC = 'bad_crc'             # kvh_fog: a header and a message's length of bytes whose CRC is wrong
OTHER_FORMAT = 'other_format'   # kvh_fog: the header of another message format than the configured one
AXIS_INVALID = 'axis_invalid'   # kvh_fog: the status byte says the yaw axis' gyro data is invalid
REPEATED_SEQUENCE = 'repeated_sequence'   # kvh_fog: the sequence number of the message before (a duplicate)
NOT_FINITE = 'not_finite'       # kvh_fog: a NaN or infinite rotation or temperature (the CRC passed)
NO_TEMPERATURE_YET = 'no_temperature_yet'   # kvh_fog Format C: before the connection's first temperature

BINARY_FRAME_BYTES = 8
# Longest valid line is b'-32768 -32768\r\n' (15 bytes); leave room for stray spaces but
# bound the buffer so a stream without newlines cannot grow memory.
MAX_LINE_BYTES = 64

# A candidate binary frame: a top-bit byte followed by seven clear bytes. A top-bit byte
# not followed by seven clear bytes can never start a valid frame, so the regex jumps
# straight to the next byte that can (the scan runs in C, not per byte in Python).
_CANDIDATE = re.compile(rb'[\x80-\xff][\x00-\x7f]{7}')
# A frame still arriving: a top-bit byte followed by at most six clear bytes, at the end.
_PARTIAL = re.compile(rb'[\x80-\xff][\x00-\x7f]{0,6}\Z')
_ASCII_LINE = re.compile(rb'\s*([+-]?\d{1,10})[ \t]+([+-]?\d{1,10})\s*')
_BLANK = re.compile(rb'\s*')


@dataclass(frozen=True, slots=True)
class RawSample:
    """One sample, as the gyro sent it: what the calibration's scale factors multiply.

    RD2100 protocols carry signed counts (ints). A ``kvh_fog`` unit sends IEEE-754 floats whose
    units are settings of the unit (radians or degrees, delta angle or rate, temperature in
    degrees or hundredths, Celsius or Fahrenheit): its parser turns them into deg/s and degC
    here, so that its calibration file has scale factors 1.0. A calibration is a property of
    the gyro, in deg/s and degC; were the unit's units in it, changing the unit's output rate
    (which a delta angle depends on) would silently invalidate every calibration fitted before.
    The node's ``log_path`` and ``calibrate record`` log these values as they are, and
    ``calibrate fit`` and ``apply`` read them back with the same 1.0 scale factors.
    """

    raw_rate: float
    raw_temp: float


@dataclass(frozen=True, slots=True)
class Frame:
    """A sample and its stamps, as the driver hands it on: when its first byte left the gyro, estimated.

    ``stamp_ns`` is on the driver's clock (it steps when that clock steps); ``steady_ns`` is
    the same time without those steps, continuous and increasing, for the signals.
    """

    sample: RawSample
    stamp_ns: int
    steady_ns: int


@dataclass(slots=True)
class ParserStats:
    """What a parser accepted and rejected so far."""

    frames: int = 0
    rejected_by_reason: dict[str, int] = field(default_factory=dict)
    bytes_skipped: int = 0   # bytes that were not part of an accepted frame
    # Messages the gyro numbered but that never came through (gaps in a sequence number: kvh_fog).
    lost_frames: int = 0

    @property
    def rejected(self) -> int:
        """Rejections of all reasons."""
        return sum(self.rejected_by_reason.values())


class FrameParser(Protocol):
    """An incremental parser of one protocol."""

    frame_bytes: int
    stats: ParserStats

    def feed(self, data: bytes) -> list[tuple[RawSample, int]]:
        """Parse a chunk; each valid frame with the offset just past its last byte within ``data``."""

    def reset(self) -> None:
        """Drop a partly received frame (the link was lost); statistics are kept."""


def _check_int16(name: str, value: int) -> None:
    if not INT16_MIN <= value <= INT16_MAX:
        raise ValueError(f'{name} must be a signed 16-bit count ({INT16_MIN}..{INT16_MAX}), got {value}')


def encode_binary(raw_rate: int, raw_temp: int) -> bytes:
    """The 8-byte binary frame of one sample (status bytes 0)."""
    _check_int16('raw_rate', raw_rate)
    _check_int16('raw_temp', raw_temp)
    payload = ((raw_temp & 0xFFFF) << 16) | (raw_rate & 0xFFFF)   # m[1..6], m[1] = m[2] = 0
    checksum = -sum(payload.to_bytes(6, 'big')) & 0xFF
    bits = (checksum << 48) | payload                              # 56 bits, m[0] first
    frame = bytearray(BINARY_FRAME_BYTES)
    for i in range(BINARY_FRAME_BYTES):
        frame[i] = (bits >> (7 * (BINARY_FRAME_BYTES - 1 - i))) & 0x7F
    frame[0] |= 0x80
    return bytes(frame)


def _decode_bits(frame: bytes) -> int:
    """The 56 payload bits of a well-framed 8-byte frame (7-bit groups packed by masks, no loop)."""
    v = int.from_bytes(frame, 'big') & 0x7F7F7F7F7F7F7F7F
    v = ((v & 0x7F007F007F007F00) >> 1) | (v & 0x007F007F007F007F)   # pairs: 14 bits per 16
    v = ((v & 0x3FFF00003FFF0000) >> 2) | (v & 0x00003FFF00003FFF)   # quads: 28 bits per 32
    return ((v & 0x0FFFFFFF00000000) >> 4) | (v & 0x000000000FFFFFFF)


def _int16(value: int) -> int:
    return value - 0x10000 if value & 0x8000 else value


class _ChunkParser:
    """What every parser shares: the bytes held between chunks and the statistics."""

    def __init__(self, reasons: tuple[str, ...]) -> None:
        self.stats = ParserStats(rejected_by_reason=dict.fromkeys(reasons, 0))
        self._buffer = b''

    def _join(self, data: bytes) -> tuple[bytes, int]:
        """The held bytes followed by ``data``, and how many were held (offsets in ``data`` start there)."""
        held = len(self._buffer)
        return (self._buffer + data if held else bytes(data)), held


class _BinaryChunkParser(_ChunkParser):
    """What the binary parsers share: bytes between frames are skipped, each run counted once as garbage."""

    def __init__(self, reasons: tuple[str, ...]) -> None:
        super().__init__(reasons + (GARBAGE,))
        self._in_garbage = False

    def reset(self) -> None:
        """Drop a partly received frame; statistics are kept."""
        self._skip(len(self._buffer))
        self._buffer = b''
        self._in_garbage = False

    def _skip(self, count: int) -> None:
        if count <= 0:
            return
        self.stats.bytes_skipped += count
        if not self._in_garbage:
            self.stats.rejected_by_reason[GARBAGE] += 1
            self._in_garbage = True


class BinaryFrameParser(_BinaryChunkParser):
    """Incremental parser of 8-byte binary frames.

    Every well-framed window (a top-bit byte then seven clear ones) is a candidate; two
    candidates cannot overlap, so after a bad checksum the next candidate is the next
    top-bit byte after the bad one, and a valid frame right after garbage is never lost.
    """

    frame_bytes = BINARY_FRAME_BYTES

    def __init__(self) -> None:
        super().__init__((BAD_CHECKSUM,))

    def feed(self, data: bytes) -> list[tuple[RawSample, int]]:
        """Parse a chunk; each valid frame with the offset just past its last byte within ``data``."""
        buf, held = self._join(data)
        out: list[tuple[RawSample, int]] = []
        stats = self.stats
        pos = 0
        search = _CANDIDATE.search
        while (match := search(buf, pos)) is not None:
            start, end = match.span()
            self._skip(start - pos)
            bits = _decode_bits(match.group())
            if sum(bits.to_bytes(7, 'big')) & 0xFF:
                stats.rejected_by_reason[BAD_CHECKSUM] += 1
                stats.bytes_skipped += BINARY_FRAME_BYTES
            else:
                out.append((RawSample(_int16(bits & 0xFFFF), _int16((bits >> 16) & 0xFFFF)), end - held))
                stats.frames += 1
            self._in_garbage = False
            pos = end
        partial = _PARTIAL.search(buf, max(pos, len(buf) - BINARY_FRAME_BYTES + 1))
        keep = partial.start() if partial is not None else len(buf)
        self._skip(keep - pos)
        self._buffer = buf[keep:]
        return out


class AsciiFrameParser(_ChunkParser):
    r"""Incremental parser of ``<raw_rate> <raw_temp>\r\n`` lines (``\n`` alone is accepted too)."""

    # Nominal: a typical line such as b'-1234 500\r\n' (wire-time stamping needs a figure).
    frame_bytes = 11

    def __init__(self) -> None:
        super().__init__((MALFORMED, OUT_OF_RANGE, LINE_TOO_LONG))
        self._discarding = False   # inside the rest of an overlong line, or of a line cut by a reset

    def reset(self) -> None:
        """Drop a partly received line, and the next bytes up to a line break; statistics are kept.

        A port opened or reopened mid-line gets the tail of a line, which may parse as a
        wrong sample (``34 500`` of ``-1234 500``): it is skipped, not counted as a rejection.
        """
        self.stats.bytes_skipped += len(self._buffer)
        self._buffer = b''
        self._discarding = True

    def feed(self, data: bytes) -> list[tuple[RawSample, int]]:
        """Parse a chunk; each valid line with the offset just past its newline within ``data``."""
        buf, held = self._join(data)
        out: list[tuple[RawSample, int]] = []
        stats = self.stats
        reasons = stats.rejected_by_reason
        pos = 0
        while (newline := buf.find(b'\n', pos)) >= 0:
            end = newline + 1
            if self._discarding:
                self._discarding = False
                stats.bytes_skipped += end - pos
            elif newline - pos > MAX_LINE_BYTES:
                reasons[LINE_TOO_LONG] += 1
                stats.bytes_skipped += end - pos
            elif (match := _ASCII_LINE.fullmatch(buf, pos, newline)) is not None:
                raw_rate, raw_temp = int(match.group(1)), int(match.group(2))
                if INT16_MIN <= raw_rate <= INT16_MAX and INT16_MIN <= raw_temp <= INT16_MAX:
                    out.append((RawSample(raw_rate, raw_temp), end - held))
                    stats.frames += 1
                else:
                    reasons[OUT_OF_RANGE] += 1
                    stats.bytes_skipped += end - pos
            else:
                if _BLANK.fullmatch(buf, pos, newline) is None:   # blank lines are not frames
                    reasons[MALFORMED] += 1
                stats.bytes_skipped += end - pos
            pos = end
        rest = len(buf) - pos
        if self._discarding or rest > MAX_LINE_BYTES:
            if not self._discarding:
                reasons[LINE_TOO_LONG] += 1
                self._discarding = True
            stats.bytes_skipped += rest
            pos = len(buf)
        self._buffer = buf[pos:]
        return out


def encode_ascii(raw_rate: int, raw_temp: int) -> bytes:
    """The text line of one sample."""
    _check_int16('raw_rate', raw_rate)
    _check_int16('raw_temp', raw_temp)
    return b'%d %d\r\n' % (raw_rate, raw_temp)


# --- kvh_fog: the binary message of KVH's DSP-1750/1760 gyros and 1725/1750/1775 IMUs ------------

KVH_HEADER_PREFIX = b'\xfe\x81\xff'   # every format's header; the fourth byte names the format
KVH_SEQUENCE_MODULO = 128             # the sequence number counts 0..127 and wraps
KVH_STATUS_ALL_VALID = 0x77           # the manuals' normal status: three gyros and three accelerometers valid
KVH_MAX_OUTPUT_RATE_HZ = 5000.0       # the 1775's highest =DR; the DSP-1760's is 1000
KVH_ROTATIONS = ('delta_angle', 'rate')
KVH_ANGLE_UNITS = ('rad', 'deg')
# =TEMPUNITS: degrees or hundredths of a degree, Celsius or Fahrenheit.
KVH_TEMPERATURE_UNITS = ('C', 'C_100', 'F', 'F_100')
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

    def __post_init__(self) -> None:
        _choice('message_format', self.message_format, tuple(KVH_FORMATS))
        if not isinstance(self.yaw_axis, str) or not _KVH_AXES.fullmatch(self.yaw_axis):
            raise ValueError(f'kvh_fog.yaw_axis must be x, y or z with an optional sign (+z, -x, ...), '
                             f'got {self.yaw_axis!r}')
        _choice('rotation', self.rotation, KVH_ROTATIONS)
        _choice('angle_units', self.angle_units, KVH_ANGLE_UNITS)
        rate = self.output_rate_hz
        if isinstance(rate, bool) or not isinstance(rate, (int, float)) or not 0 < rate <= KVH_MAX_OUTPUT_RATE_HZ:
            raise ValueError(f'kvh_fog.output_rate_hz must be a number of Hz in (0, {KVH_MAX_OUTPUT_RATE_HZ:g}], '
                             f'got {rate!r}')
        _choice('temperature_units', self.temperature_units, KVH_TEMPERATURE_UNITS)

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
    def dps_per_unit(self) -> float:
        """Yaw rate in deg/s per unit of the yaw axis' rotation float."""
        per_angle = math.degrees(1.0) if self.angle_units == 'rad' else 1.0
        per_rate = float(self.output_rate_hz) if self.rotation == 'delta_angle' else 1.0
        return self.sign * per_angle * per_rate

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
        _check_int16('temperature', int(temperature))
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

    def __call__(self, rate_dps: float, temp_c: float) -> bytes:
        """The next message: ``rate_dps`` about the yaw axis, ``temp_c``."""
        config = self.config
        axis = config.axis_index
        rotation = [0.0, 0.0, 0.0]
        rotation[axis] = rate_dps / config.dps_per_unit
        acceleration = [0.0, 0.0, 0.0]
        acceleration[axis] = config.sign
        temperature = config.temperature_wire(temp_c)
        if not config.format.multiplexed:
            temperature = round(temperature)
        sequence = self.sequence
        self.sequence = (sequence + 1) % KVH_SEQUENCE_MODULO
        return encode_kvh_fog((rotation[0], rotation[1], rotation[2]),
                              (acceleration[0], acceleration[1], acceleration[2]),
                              self.status, sequence, temperature, config.message_format)


class KvhFogParser(_BinaryChunkParser):
    """Incremental parser of kvh_fog messages of the configured format; samples in deg/s and degC.

    A candidate is the format's header and the message's length of bytes from it; a good CRC
    takes it whole. After a bad CRC the search resumes at the byte after the header's first, so
    a message cut short and followed by a whole one loses only the cut one. Every message with a
    good CRC advances the sequence number; the numbers skipped since the message before are added
    to ``stats.lost_frames`` (a gap of 128 or more cannot be told from a shorter one; none is
    counted across :meth:`reset`, where the count is unknown). A good message is still rejected,
    and counted by reason, when the status byte flags the yaw gyro invalid, when it repeats the
    sequence number before it (a duplicate: publishing it would count the rotation twice), when a
    value is not finite, and in Format C before the first temperature of the connection (the
    temperature comes every fourth message and is held until the next).
    """

    def __init__(self, config: KvhFogConfig) -> None:
        super().__init__((BAD_CRC, OTHER_FORMAT, AXIS_INVALID, REPEATED_SEQUENCE, NOT_FINITE, NO_TEMPERATURE_YET))
        self.config = config
        fmt = config.format
        self.frame_bytes = fmt.length
        self._format = fmt
        self._axis = config.axis_index
        self._dps_per_unit = config.dps_per_unit
        self._last_sequence: int | None = None
        self._temp_c: float | None = None   # Format C: the latest temperature

    def reset(self) -> None:
        """Drop a partly received message; the sequence and held temperature restart; statistics are kept."""
        super().reset()
        self._last_sequence = None
        self._temp_c = None

    def feed(self, data: bytes) -> list[tuple[RawSample, int]]:
        """Parse a chunk; each valid message with the offset just past its last byte within ``data``."""
        buf, held = self._join(data)
        out: list[tuple[RawSample, int]] = []
        stats = self.stats
        reasons = stats.rejected_by_reason
        fmt = self._format
        length = fmt.length
        pos = 0
        keep = -1
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
                stats.bytes_skipped += 1
                self._in_garbage = True
                pos = start + 1
                continue
            self._in_garbage = False
            pos = end
            sample, reason = self._decode(buf, start)
            if sample is None:
                reasons[reason] += 1
                stats.bytes_skipped += length
            else:
                out.append((sample, end - held))
                stats.frames += 1
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

    def _decode(self, buf: bytes, start: int) -> tuple[RawSample | None, str]:
        """The sample of a message whose CRC is good, or None and the reason it is rejected."""
        values = self._format.layout.unpack_from(buf, start + 4)
        config = self.config
        if self._format.multiplexed:
            mux, status, sequence = values[6:]
        else:
            status, sequence, temperature = values[-3:]
        last = self._last_sequence
        if last is not None:
            if sequence == last:
                return None, REPEATED_SEQUENCE
            self.stats.lost_frames += (sequence - last - 1) % KVH_SEQUENCE_MODULO
        self._last_sequence = sequence
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
        rate_dps = values[self._axis] * self._dps_per_unit
        if not (math.isfinite(rate_dps) and math.isfinite(temp_c)):
            return None, NOT_FINITE
        return RawSample(rate_dps, temp_c), ''


def check_protocol(protocol: str) -> str:
    """``protocol`` if it is one of :data:`PROTOCOLS`, else a clear error."""
    if protocol not in PROTOCOLS:
        raise ValueError(f'unknown protocol {protocol!r}: expected one of {", ".join(PROTOCOLS)}')
    return protocol


def make_parser(protocol: str, kvh_fog: KvhFogConfig | None = None) -> FrameParser:
    """A fresh parser for ``protocol`` (one of :data:`PROTOCOLS`); ``kvh_fog`` configures that protocol's."""
    check_protocol(protocol)
    if protocol == KVH_FOG:
        return KvhFogParser(kvh_fog or KvhFogConfig())
    return BinaryFrameParser() if protocol == 'binary' else AsciiFrameParser()


def make_encoder(protocol: str, kvh_fog: KvhFogConfig | None = None) -> Callable[..., bytes]:
    """The encoder of ``protocol``: ``(raw_rate, raw_temp) -> bytes``, as :class:`RawSample` holds them.

    The ``kvh_fog`` encoder numbers its messages, so each call of :func:`make_encoder` starts a new stream.
    """
    check_protocol(protocol)
    if protocol == KVH_FOG:
        return KvhFogEncoder(kvh_fog or KvhFogConfig())
    return encode_binary if protocol == 'binary' else encode_ascii
