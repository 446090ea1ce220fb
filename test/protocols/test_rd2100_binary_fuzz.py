r"""Property tests of the RD2100 binary parser on arbitrary bytes, in arbitrary chunks.

A well-framed window is 8 bytes, a top-bit byte then seven clear ones. Two such
windows cannot overlap (the second's top-bit byte would have to be one of the first's
seven clear ones), so arbitrary bytes around a frame can add frames of their own (garbage
may legitimately contain a well-framed window with a good checksum) but can never shift a frame, and hides one
only by a status of its own (below). The exact property tested: for any bytes cut into any chunks, the parser
returns exactly the well-framed windows with a good checksum, in order, each at its end
offset, but a window whose status m[1]:m[2] differs from the last one returned (unless the window refused just
before had it too: a new status is trusted from its second frame); it follows that no bad checksum is ever accepted
and that a valid frame surrounded by arbitrary bytes is always found (unless a frame of garbage before it set
another status).
"""

from hypothesis import assume, example, given, strategies as st

from art_gyro_calibration.frame import INT16_MAX, INT16_MIN
from art_gyro_calibration.protocols.rd2100_binary import BinaryFrameParser, encode_binary

int16 = st.integers(INT16_MIN, INT16_MAX)
good_frames = st.builds(encode_binary, int16, int16)


def flip_bit(frame: bytes, bit: int) -> bytes:
    """A frame with one of its 56 payload bits flipped: still well framed, checksum now wrong."""
    out = bytearray(frame)
    out[bit // 7] ^= 1 << (bit % 7)
    return bytes(out)


bad_frames = st.builds(flip_bit, good_frames, st.integers(0, 55))
framed_windows = st.binary(min_size=8, max_size=8).map(lambda b: bytes([b[0] | 0x80]) + bytes(x & 0x7F for x in b[1:]))
# Bytes rich in frames, corrupted frames and framed windows, cut and joined anywhere, so
# framing and checksums are exercised, not just noise.
stream_bytes = st.lists(st.one_of(st.binary(max_size=20), good_frames, bad_frames, framed_windows,
                                  good_frames.flatmap(lambda f: st.integers(1, 7).map(lambda n: f[:n]))),
                        max_size=12).map(b''.join)


def reference_frames(data: bytes) -> list[tuple[int, int, int]]:
    """(raw_rate, raw_temp, end) of every well-framed window with a good checksum: the slow, obvious way.

    But for the status rule (STATUS_CHANGE): a window whose status is neither the last returned one's nor the one
    refused last is refused.
    """
    found = []
    status = refused = None
    for i in range(len(data) - 7):
        window = data[i:i + 8]
        if not window[0] & 0x80 or any(b & 0x80 for b in window[1:]):
            continue
        bits = 0
        for b in window:
            bits = (bits << 7) | (b & 0x7F)
        m = bits.to_bytes(7, 'big')
        if sum(m) % 256 == 0 and any(m):   # an all-zero frame is no gyro's: refused (ALL_ZERO)
            if status is not None and m[1:3] != status and m[1:3] != refused:
                refused = m[1:3]
                continue
            status, refused = m[1:3], None
            found.append((int.from_bytes(m[5:7], 'big', signed=True),
                          int.from_bytes(m[3:5], 'big', signed=True), i + 8))
    return found


def chunks(data: bytes, cuts: list[int]) -> list[bytes]:
    """``data`` cut at ``cuts`` (taken modulo its length, any order, repeats ignored)."""
    points = sorted({c % (len(data) + 1) for c in cuts})
    return [data[a:b] for a, b in zip([0] + points, points + [len(data)])]


def parse_binary(pieces: list[bytes]) -> tuple[BinaryFrameParser, list[tuple[int, int, int]]]:
    parser = BinaryFrameParser()
    out, base = [], 0
    for piece in pieces:
        out += [(s.raw_rate, s.raw_temp, base + end) for s, end in parser.feed(piece)]
        base += len(piece)
    return parser, out


@given(stream_bytes, st.lists(st.integers(0, 1000), max_size=10))
# A framed window of garbage with a good checksum and a status, then a frame of status 0: the reference returned
# both, the parser (rightly) refuses the second's new status (found by hypothesis at CI time, not by a change).
@example(data=b'\xfd\x08a\x03v\x11\x1f\n\xff@\x00\x00\x00\x04\x00\x00', cuts=[])
def test_binary_parser_returns_exactly_the_valid_windows_for_any_chunking(data, cuts):
    parser, out = parse_binary(chunks(data, cuts))
    expected = reference_frames(data)
    assert out == expected
    assert parser.stats.frames == len(expected)
    assert parser.stats.bytes_skipped + 8 * len(expected) + len(parser._buffer) == len(data)


@given(st.lists(bad_frames, min_size=1, max_size=20).map(b''.join))
def test_binary_parser_never_accepts_a_bad_checksum(data):
    parser, out = parse_binary([data])
    assert out == []
    assert parser.stats.rejected_by_reason['bad_checksum'] == len(data) // 8


@given(st.binary(max_size=300), st.lists(st.integers(0, 1000), max_size=10))
def test_binary_parser_on_uniform_noise(data, cuts):
    assert parse_binary(chunks(data, cuts))[1] == reference_frames(data)


@given(st.binary(max_size=64), int16, int16, st.binary(max_size=64), st.lists(st.integers(0, 200), max_size=6))
def test_binary_frame_between_arbitrary_bytes_is_found(prefix, raw_rate, raw_temp, suffix, cuts):
    assume((raw_rate, raw_temp) != (0, 0))   # the all-zero frame is refused (ALL_ZERO)
    assume(not reference_frames(prefix))   # a frame of garbage before it would set another status (STATUS_CHANGE)
    data = prefix + encode_binary(raw_rate, raw_temp) + suffix
    assert (raw_rate, raw_temp, len(prefix) + 8) in parse_binary(chunks(data, cuts))[1]
