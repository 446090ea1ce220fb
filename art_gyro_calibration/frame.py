"""What every wire protocol shares: the sample as sent, the stamped frame, parser statistics and bases.

Pure: no I/O, no ROS. Each protocol is a module of :mod:`.protocols` (``rd2100_binary``,
``rd2100_ascii``, ``kvh_fog``) with its own rejection reasons; :mod:`.protocols` picks one by
name. Parsers take bytes in arbitrary chunks (a frame may straddle reads), resynchronise after
garbage or a bad frame, and count every rejection by reason.
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
# RD2100 protocols: a valid frame before the stream is locked (fewer than the lock's frames in a row, contiguous).
UNLOCKED = 'unlocked'
# An RD2100 frame's 8-bit checksum passes one random window in 256: a run of this many valid frames, each
# starting where the last ended, is what a gyro sends and noise does not (about 1 in 256**3 windows).
LOCK_FRAMES = 3


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

    def __init__(self, reasons: tuple[str, ...], lock_frames: int = 1) -> None:
        if not isinstance(lock_frames, int) or lock_frames < 1:
            raise ValueError(f'lock_frames must be a positive integer, got {lock_frames!r}')
        if lock_frames > 1:
            reasons += (UNLOCKED,)
        self.stats = ParserStats(rejected_by_reason=dict.fromkeys(reasons, 0))
        self._buffer = b''
        self.lock_frames = lock_frames
        self._run = 0   # valid frames in a row so far

    @property
    def locked(self) -> bool:
        """Whether the next valid frame, if contiguous, is accepted."""
        return self._run >= self.lock_frames - 1

    def _accept(self, sample: RawSample, end: int, frame_bytes: int, out: list[tuple[RawSample, int]]) -> None:
        """A valid frame: accepted if the stream is locked, else counted as UNLOCKED (its bytes skipped)."""
        self._run += 1
        if self._run >= self.lock_frames:
            out.append((sample, end))
            self.stats.frames += 1
        else:
            self.stats.rejected_by_reason[UNLOCKED] += 1
            self.stats.bytes_skipped += frame_bytes

    def _join(self, data: bytes) -> tuple[bytes, int]:
        """The held bytes followed by ``data``, and how many were held (offsets in ``data`` start there)."""
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
