"""The one parser interface of every wire protocol, and what they share: the sample, the stamped frame, statistics.

Pure: no I/O, no ROS. Each protocol is a module of :mod:`.protocols` (``rd2100_binary``,
``rd2100_ascii``, ``kvh_fog``) with its own rejection reasons; :mod:`.protocols` picks one by
name. Parsers take bytes in arbitrary chunks (a frame may straddle reads), resynchronise after
garbage or a bad frame, and count every rejection by reason. The driver, the node and the
diagnostics see a protocol only through :class:`FrameParser`, the :class:`RawSample` it parses
and its :class:`ProtocolDescription`: they import no protocol module.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Protocol

INT16_MIN = -0x8000
INT16_MAX = 0x7FFF
BITS_PER_BYTE = 10   # on a serial line: start + 8 data + stop

# Reasons more than one place counts (the keys of ParserStats.rejected_by_reason, and the node's drops).
GARBAGE = 'garbage'             # binary, kvh_fog: a run of bytes that cannot start a frame (counted once per run)
# kvh_fog: a NaN or infinite rotation or temperature (the CRC passed); the node: a non-finite compensated rate.
NOT_FINITE = 'not_finite'
# A frame whose gyro says its yaw axis' data is invalid (kvh_fog's status byte): the diagnostics warn of these.
AXIS_INVALID = 'axis_invalid'
# RD2100 protocols: a valid frame before the stream is locked (fewer than the lock's frames in a row, contiguous).
UNLOCKED = 'unlocked'
# An RD2100 frame's 8-bit checksum passes one random window in 256: a run of this many valid frames, each
# starting where the last ended, is what a gyro sends and noise does not (about 1 in 256**3 windows).
LOCK_FRAMES = 3
STANDARD_GRAVITY = 9.80665   # m/s^2 per g (an IMU's acceleration unit)


@dataclass(frozen=True, slots=True)
class ImuReading:
    """The three axes of a unit that measures them all, in the unit's axes: rates in deg/s, accelerations in g.

    ``rate_valid`` and ``acceleration_valid``: per axis, whether the unit flags that sensor's data valid.
    """

    rates_dps: tuple[float, float, float]
    acceleration_g: tuple[float, float, float]
    rate_valid: tuple[bool, bool, bool] = (True, True, True)
    acceleration_valid: tuple[bool, bool, bool] = (True, True, True)


@dataclass(frozen=True, slots=True)
class RawSample:
    """One sample, as the gyro sent it: what the calibration's scale factors multiply, and what else it said.

    RD2100 protocols carry signed counts (ints). A ``kvh_fog`` unit sends IEEE-754 floats whose
    units are settings of the unit (radians or degrees, delta angle or rate, temperature in
    degrees or hundredths, Celsius or Fahrenheit): its parser turns them into deg/s and degC
    here, so that its calibration file has scale factors 1.0. A calibration is a property of
    the gyro, in deg/s and degC; were the unit's units in it, changing the unit's output rate
    (which a delta angle depends on) would silently invalidate every calibration fitted before.
    The node's ``log_path`` and ``calibrate record`` log these values as they are, and
    ``calibrate fit`` and ``apply`` read them back with the same 1.0 scale factors.

    ``unit_time_us`` is the unit's own clock (microseconds since the connection opened) if it sends one,
    ``imu`` the whole IMU if it measures one, ``interval_s`` the message interval the rate was taken over
    if the protocol measures one: None otherwise (the RD2100 protocols send a rate and a temperature only).
    """

    raw_rate: float
    raw_temp: float
    unit_time_us: int | None = None
    imu: ImuReading | None = None
    interval_s: float | None = None


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
    # Runs of bytes that were no message, when the protocol counts them apart from its rejected messages (kvh_fog).
    garbage_runs: int = 0
    clock_faults: int = 0   # times the unit's clock went back, stood still or leapt (kvh_fog Format B)

    @property
    def rejected(self) -> int:
        """Rejections of all reasons."""
        return sum(self.rejected_by_reason.values())


@dataclass(frozen=True)
class ProtocolDescription:
    """What the driver, the node and the diagnostics need of a protocol beyond its frames; the RD2100's by default.

    ``hardware``: the diagnostics' hardware_id before the serial number. ``checks_rate_jumps``: samples
    are counts behind a checksum weak enough (or none) that the driver's frame guard
    (:mod:`art_gyro_calibration.frame_guard`) refuses a frame that departs from its neighbours by a step a
    corruption makes (``corrupt_rate_steps``) or whose temperature jumps. ``stamps_by_unit_clock``: stamp
    samples by their ``unit_time_us`` once mapped.
    ``imu_axes``: for the robot's x, y and z (REP 103), the unit's axis and its sign, when samples
    carry the whole IMU; empty otherwise. ``reports_rate``: the parser measures the unit's output
    rate (the diagnostics report it and :meth:`rate_error`). ``startup_rejections``: reasons the
    parser rejects frames for at the start of every connection by design, not a sign of a wrong
    link. ``temperature_hint``: what a temperature outside the plausible range says of the settings.
    ``corrupt_rate_steps``: the rate changes (counts) a corruption that passes the protocol's check makes (the
    frame guard refuses a departure of that size from the motion's prediction). ``continuous_temperature``: the
    temperature moves less than a count between frames, so the frame guard refuses a frame whose temperature jumps.
    """

    hardware: str = 'KVH RD2100'
    checks_rate_jumps: bool = True
    stamps_by_unit_clock: bool = False
    imu_axes: tuple[tuple[int, float], ...] = ()
    reports_rate: bool = False
    startup_rejections: tuple[str, ...] = ()
    temperature_hint: str = 'the temperature field is not m[3]:m[4] on this unit'   # m: the RD2100's 7-bit groups
    corrupt_rate_steps: tuple[int, ...] = ()
    continuous_temperature: bool = False

    def rate_error(self, measured_hz: float | None) -> str:
        """Why the unit is not sending at the rate it is said to ('' when it is, or nothing is said or measured)."""
        return ''


class FrameParser(Protocol):
    """An incremental parser of one protocol: the interface the driver reads every protocol through.

    ``frame_bytes`` is a frame's length on the wire (nominal for text lines), for stamping.
    ``frames_missed``: for each frame the last :meth:`feed` returned, how many of the gyro's frames came between
    it and the frame returned before and were refused or lost, as far as the parser can tell (the frame guard
    bridges them: a backlog read in one chunk has no time gap to tell them by).
    """

    frame_bytes: int
    stats: ParserStats
    description: ProtocolDescription
    frames_missed: list[int]

    def feed(self, data: bytes, arrival_ns: int | None = None) -> list[tuple[RawSample, int]]:
        """Parse a chunk whose read returned at ``arrival_ns`` (monotonic, if known).

        Each valid frame with the offset just past its last byte within ``data``. A protocol that measures
        its message interval from arrivals (kvh_fog) uses ``arrival_ns``; the others ignore it.
        """

    def reset(self) -> None:
        """Drop a partly received frame (the link was lost); statistics are kept."""

    @property
    def measured_rate_hz(self) -> float | None:
        """Frames per second as the parser measures them, or None (not measured, or not yet)."""


def check_int16(name: str, value: int) -> None:
    """Refuse what a signed 16-bit field of a frame cannot carry, naming the field."""
    if not INT16_MIN <= value <= INT16_MAX:
        raise ValueError(f'{name} must be a signed 16-bit count ({INT16_MIN}..{INT16_MAX}), got {value}')


class ChunkParser:
    """What every parser shares: the bytes held between chunks, the statistics and the stream lock.

    With ``lock_frames`` > 1 a valid frame is accepted only as the ``lock_frames``-th or later of a run of
    valid frames each starting where the last ended: the first ones of a run are counted as UNLOCKED, and
    any byte skipped or frame rejected between them (garbage, a bad frame, a reopen) ends the run.
    """

    description = ProtocolDescription()

    def __init__(self, reasons: tuple[str, ...], lock_frames: int = 1) -> None:
        if not isinstance(lock_frames, int) or lock_frames < 1:
            raise ValueError(f'lock_frames must be a positive integer, got {lock_frames!r}')
        if lock_frames > 1:
            reasons += (UNLOCKED,)
        self.stats = ParserStats(rejected_by_reason=dict.fromkeys(reasons, 0))
        self._buffer = b''
        self.lock_frames = lock_frames
        self._run = 0   # valid frames in a row so far
        self.frames_missed: list[int] = []
        self._missed = 0   # frames refused since the last one accepted

    @property
    def measured_rate_hz(self) -> float | None:
        """Frames per second as measured: none by default."""
        return None

    @property
    def locked(self) -> bool:
        """Whether the next valid frame, if contiguous, is accepted."""
        return self._run >= self.lock_frames - 1

    def _accept(self, sample: RawSample, end: int, frame_bytes: int, out: list[tuple[RawSample, int]]) -> None:
        """A valid frame: accepted if the stream is locked, else counted as UNLOCKED (its bytes skipped)."""
        self._run += 1
        if self._run >= self.lock_frames:
            out.append((sample, end))
            self.frames_missed.append(self._missed)
            self._missed = 0
            self.stats.frames += 1
        else:
            self._refuse(UNLOCKED, frame_bytes)

    def _refuse(self, reason: str, frame_bytes: int) -> None:
        """A frame of the gyro's refused for ``reason``: counted, its bytes skipped, missed before the next one."""
        self.stats.rejected_by_reason[reason] += 1
        self.stats.bytes_skipped += frame_bytes
        self._missed += 1

    def _join(self, data: bytes) -> tuple[bytes, int]:
        """A chunk's start: the held bytes, then ``data``; how many were held (offsets in ``data`` start there).

        ``frames_missed`` is the new chunk's from here.
        """
        self.frames_missed = []
        held = len(self._buffer)
        return (self._buffer + data if held else bytes(data)), held


class BinaryChunkParser(ChunkParser):
    """What the binary parsers share: bytes between frames are skipped, each run counted once as garbage."""

    def __init__(self, reasons: tuple[str, ...], lock_frames: int = 1) -> None:
        super().__init__(reasons + (GARBAGE,), lock_frames)
        self._in_garbage = False

    def reset(self) -> None:
        """Drop a partly received frame and the lock; statistics are kept."""
        self._skip(len(self._buffer))
        self._buffer = b''
        self._in_garbage = False
        self._run = 0

    def _skip(self, count: int) -> None:
        if count <= 0:
            return
        self._run = 0
        self.stats.bytes_skipped += count
        if not self._in_garbage:
            self.stats.rejected_by_reason[GARBAGE] += 1
            self._in_garbage = True
