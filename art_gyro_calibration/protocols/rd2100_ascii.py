r"""RD2100 samples as text lines, ``<raw_rate> <raw_temp>\r\n``: encoder and incremental parser (pure).

One line per sample (signed integers, counts), for loggers and front-ends that re-emit the
gyro's data as text.
"""

from __future__ import annotations

import re

from art_gyro_calibration.frame import INT16_MAX, INT16_MIN, ChunkParser, ProtocolDescription, RawSample, check_int16

# Rejection reasons, the keys of ParserStats.rejected_by_reason.
MALFORMED = 'malformed'         # a line that is not two integers
OUT_OF_RANGE = 'out_of_range'   # an integer outside the signed 16-bit range
LINE_TOO_LONG = 'line_too_long'  # no newline within MAX_LINE_BYTES

# Longest valid line is b'-32768 -32768\r\n' (15 bytes); leave room for stray spaces but
# bound the buffer so a stream without newlines cannot grow memory.
MAX_LINE_BYTES = 64

# No checksum: a digit replaced by another changes the rate by k * 10^j counts.
CORRUPT_RATE_STEPS = tuple(sorted(k * 10 ** j for k in range(1, 10) for j in range(5)))

_ASCII_LINE = re.compile(rb'\s*([+-]?\d{1,10})[ \t]+([+-]?\d{1,10})\s*')
_BLANK = re.compile(rb'\s*')


class AsciiFrameParser(ChunkParser):
    r"""Incremental parser of ``<raw_rate> <raw_temp>\r\n`` lines (``\n`` alone is accepted too)."""

    # Nominal: a typical line such as b'-1234 500\r\n' (wire-time stamping needs a figure).
    frame_bytes = 11
    description = ProtocolDescription(corrupt_rate_steps=CORRUPT_RATE_STEPS, continuous_temperature=True)

    def __init__(self, lock_frames: int = 1) -> None:
        """``lock_frames``: valid lines in a row before one is accepted (the driver's LOCK_FRAMES, 1 for none)."""
        super().__init__((MALFORMED, OUT_OF_RANGE, LINE_TOO_LONG), lock_frames)
        self._discarding = False   # inside the rest of an overlong line, or of a line cut by a reset

    def reset(self) -> None:
        """Drop a partly received line, and the next bytes up to a line break; statistics are kept.

        A port opened or reopened mid-line gets the tail of a line, which may parse as a
        wrong sample (``34 500`` of ``-1234 500``): it is skipped, not counted as a rejection.
        """
        self.stats.bytes_skipped += len(self._buffer)
        self._buffer = b''
        self._discarding = True
        self._run = 0

    def feed(self, data: bytes, arrival_ns: int | None = None) -> list[tuple[RawSample, int]]:
        """Parse a chunk (``arrival_ns`` unused); each valid line with the offset just past its newline in ``data``."""
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
                self._run = 0
            elif newline - pos > MAX_LINE_BYTES:
                self._refuse(LINE_TOO_LONG, end - pos)
                self._run = 0
            elif (match := _ASCII_LINE.fullmatch(buf, pos, newline)) is not None:
                raw_rate, raw_temp = int(match.group(1)), int(match.group(2))
                if INT16_MIN <= raw_rate <= INT16_MAX and INT16_MIN <= raw_temp <= INT16_MAX:
                    self._accept(RawSample(raw_rate, raw_temp), end - held, end - pos, out)
                else:
                    self._refuse(OUT_OF_RANGE, end - pos)
                    self._run = 0
            elif _BLANK.fullmatch(buf, pos, newline) is None:
                self._refuse(MALFORMED, end - pos)
                self._run = 0
            else:   # blank lines are not frames, nor break the lock
                stats.bytes_skipped += end - pos
            pos = end
        rest = len(buf) - pos
        if self._discarding or rest > MAX_LINE_BYTES:
            if not self._discarding:
                reasons[LINE_TOO_LONG] += 1
                self._missed += 1
                self._discarding = True
                self._run = 0
            stats.bytes_skipped += rest
            pos = len(buf)
        self._buffer = buf[pos:]
        return out


def encode_ascii(raw_rate: int, raw_temp: int) -> bytes:
    """The text line of one sample."""
    check_int16('raw_rate', raw_rate)
    check_int16('raw_temp', raw_temp)
    return b'%d %d\r\n' % (raw_rate, raw_temp)
