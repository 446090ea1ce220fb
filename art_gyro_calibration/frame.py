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

Parsers take bytes in arbitrary chunks (a frame may straddle reads), resynchronise after
garbage or a bad frame, and count every rejection by reason.
"""

from __future__ import annotations

import re
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Protocol

PROTOCOLS = ('binary', 'ascii')
INT16_MIN = -0x8000
INT16_MAX = 0x7FFF

# Rejection reasons, the keys of ParserStats.rejected_by_reason.
BAD_CHECKSUM = 'bad_checksum'   # binary: well-framed 8 bytes whose checksum is wrong
GARBAGE = 'garbage'             # binary: a run of bytes that cannot start a frame (counted once per run)
MALFORMED = 'malformed'         # ascii: a line that is not two integers
OUT_OF_RANGE = 'out_of_range'   # ascii: an integer outside the signed 16-bit range
LINE_TOO_LONG = 'line_too_long'  # ascii: no newline within MAX_LINE_BYTES

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
    """One sample in signed counts, as the gyro sent it."""

    raw_rate: int
    raw_temp: int


@dataclass(slots=True)
class ParserStats:
    """What a parser accepted and rejected so far."""

    frames: int = 0
    rejected_by_reason: dict[str, int] = field(default_factory=dict)
    bytes_skipped: int = 0   # bytes that were not part of an accepted frame

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
    """What both parsers share: the bytes held between chunks and the statistics."""

    def __init__(self, reasons: tuple[str, ...]) -> None:
        self.stats = ParserStats(rejected_by_reason=dict.fromkeys(reasons, 0))
        self._buffer = b''

    def _join(self, data: bytes) -> tuple[bytes, int]:
        """The held bytes followed by ``data``, and how many were held (offsets in ``data`` start there)."""
        held = len(self._buffer)
        return (self._buffer + data if held else bytes(data)), held


class BinaryFrameParser(_ChunkParser):
    """Incremental parser of 8-byte binary frames.

    Every well-framed window (a top-bit byte then seven clear ones) is a candidate; two
    candidates cannot overlap, so after a bad checksum the next candidate is the next
    top-bit byte after the bad one, and a valid frame right after garbage is never lost.
    """

    frame_bytes = BINARY_FRAME_BYTES

    def __init__(self) -> None:
        super().__init__((BAD_CHECKSUM, GARBAGE))
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


def check_protocol(protocol: str) -> str:
    """``protocol`` if it is one of :data:`PROTOCOLS`, else a clear error."""
    if protocol not in PROTOCOLS:
        raise ValueError(f'unknown protocol {protocol!r}: expected one of {", ".join(PROTOCOLS)}')
    return protocol


def make_parser(protocol: str) -> BinaryFrameParser | AsciiFrameParser:
    """A fresh parser for ``protocol`` (one of :data:`PROTOCOLS`)."""
    return BinaryFrameParser() if check_protocol(protocol) == 'binary' else AsciiFrameParser()


def make_encoder(protocol: str) -> Callable[[int, int], bytes]:
    """The encoder of ``protocol``: ``(raw_rate, raw_temp) -> bytes``."""
    return encode_binary if check_protocol(protocol) == 'binary' else encode_ascii
