"""The RD2100's 8-byte binary frames: encoder and incremental parser (pure: no I/O, no ROS).

No RD2100 manual is public. The protocol follows the best public description of the E-Core
family's output (a public driver for the E-Core 2000):

- a frame is 8 bytes; the first has its top bit set, the other seven have it clear;
- dropping the top bit of each byte and joining the 8 x 7 bits big-endian gives 7 bytes
  ``m[0..6]``; ``m[0] = -(m[1] + ... + m[6]) mod 256`` is the checksum;
- the rate is the signed 16-bit ``m[5]:m[6]`` in counts (x rate_scale_factor deg/s).

The temperature is not documented: this package carries it as the signed 16-bit
``m[3]:m[4]`` in counts (x 0.05 degC). ``m[1]``, ``m[2]`` are status bits of unknown
meaning: encoded as 0 and not exposed, but a status that changes for one frame is refused
(``STATUS_CHANGE``): most two-bit errors that pass the checksum flip a status bit.
"""

from __future__ import annotations

import re

from art_gyro_calibration.frame import BinaryChunkParser, ProtocolDescription, RawSample, check_int16

# Rejection reasons, keys of ParserStats.rejected_by_reason (with GARBAGE, of frame.py).
BAD_CHECKSUM = 'bad_checksum'   # well-framed 8 bytes whose checksum is wrong
# A frame whose status m[1]:m[2] differs from the last delivered one's, unless the frame before was refused with the
# same status (a new status that persists is trusted from its second frame): a unit's status holds for many
# frames, and more than a third of the two-bit errors that pass the checksum and change the rate or temperature
# flip a status bit with it (134 of 346, all bit pairs of five frames).
STATUS_CHANGE = 'status_change'
# 0x80 and seven 0x00: its checksum passes, but it is what a line held low (a gyro at 9600 baud read at 115200,
# a break) decodes to, not a gyro: dropped, even from a still gyro at exactly 0.00 degC reading 0 counts.
ALL_ZERO = 'all_zero'

BINARY_FRAME_BYTES = 8
# The rate changes of two flipped bits that pass the checksum (-(m[1] + ... + m[6]) mod 256, the rate m[5]:m[6]):
# a checksum bit and a rate bit, +-2^a (m[6]) or +-2^(a+8) (m[5]); a bit of each rate byte that cancel,
# +-255 * 2^a (both top bits: 2^15 + 2^7, which the 16-bit field wraps to -255 * 2^7).
CORRUPT_RATE_STEPS = tuple(sorted({1 << a for a in range(16)} | {255 << a for a in range(8)}))

# A candidate binary frame: a top-bit byte followed by seven clear bytes. A top-bit byte
# not followed by seven clear bytes can never start a valid frame, so the regex jumps
# straight to the next byte that can (the scan runs in C, not per byte in Python).
_CANDIDATE = re.compile(rb'[\x80-\xff][\x00-\x7f]{7}')
# A frame still arriving: a top-bit byte followed by at most six clear bytes, at the end.
_PARTIAL = re.compile(rb'[\x80-\xff][\x00-\x7f]{0,6}\Z')


def encode_binary(raw_rate: int, raw_temp: int, status: int = 0) -> bytes:
    """The 8-byte binary frame of one sample; ``status``: m[1]:m[2] (0..65535, 0 by default)."""
    check_int16('raw_rate', raw_rate)
    check_int16('raw_temp', raw_temp)
    if not 0 <= status <= 0xFFFF:
        raise ValueError(f'status must be 0..65535, got {status}')
    payload = (status << 32) | ((raw_temp & 0xFFFF) << 16) | (raw_rate & 0xFFFF)   # m[1..6]
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


class BinaryFrameParser(BinaryChunkParser):
    """Incremental parser of 8-byte binary frames.

    Every well-framed window (a top-bit byte then seven clear ones) is a candidate; two
    candidates cannot overlap, so after a bad checksum the next candidate is the next
    top-bit byte after the bad one, and a valid frame right after garbage is never lost.
    """

    frame_bytes = BINARY_FRAME_BYTES
    description = ProtocolDescription(corrupt_rate_steps=CORRUPT_RATE_STEPS, continuous_temperature=True)

    def __init__(self, lock_frames: int = 1) -> None:
        """``lock_frames``: valid frames in a row before one is accepted (the driver's LOCK_FRAMES, 1 for none)."""
        super().__init__((BAD_CHECKSUM, ALL_ZERO, STATUS_CHANGE), lock_frames)
        self._status: int | None = None           # m[1]:m[2] of the last frame delivered
        self._refused_status: int | None = None   # of the last frame, if it was refused for it

    def reset(self) -> None:
        """Drop a partly received frame, the lock and the status learnt (a reopened unit's may differ)."""
        super().reset()
        self._status = self._refused_status = None

    def feed(self, data: bytes, arrival_ns: int | None = None) -> list[tuple[RawSample, int]]:
        """Parse a chunk (``arrival_ns`` unused); each valid frame with the offset just past it in ``data``."""
        buf, held = self._join(data)
        out: list[tuple[RawSample, int]] = []
        pos = 0
        search = _CANDIDATE.search
        while (match := search(buf, pos)) is not None:
            start, end = match.span()
            self._skip(start - pos)
            bits = _decode_bits(match.group())
            if sum(bits.to_bytes(7, 'big')) & 0xFF:
                self._refuse(BAD_CHECKSUM, BINARY_FRAME_BYTES)
                self._run = 0
            elif not bits:
                self._refuse(ALL_ZERO, BINARY_FRAME_BYTES)
                self._run = 0
            elif (status := (bits >> 32) & 0xFFFF) != self._status and status != self._refused_status \
                    and self._status is not None:
                self._refuse(STATUS_CHANGE, BINARY_FRAME_BYTES)
                self._refused_status = status
            else:
                self._status, self._refused_status = status, None
                self._accept(RawSample(_int16(bits & 0xFFFF), _int16((bits >> 16) & 0xFFFF)), end - held,
                             BINARY_FRAME_BYTES, out)
            self._in_garbage = False
            pos = end
        partial = _PARTIAL.search(buf, max(pos, len(buf) - BINARY_FRAME_BYTES + 1))
        keep = partial.start() if partial is not None else len(buf)
        self._skip(keep - pos)
        self._buffer = buf[keep:]
        return out
