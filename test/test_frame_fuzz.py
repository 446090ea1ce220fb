r"""Property tests of the frame parsers on arbitrary bytes, in arbitrary chunks.

Binary: a well-framed window is 8 bytes, a top-bit byte then seven clear ones. Two such
windows cannot overlap (the second's top-bit byte would have to be one of the first's
seven clear ones), so arbitrary bytes around a frame can add frames of their own (garbage
may legitimately contain a well-framed window with a good checksum) but can never hide or
shift a frame. The exact property tested: for any bytes cut into any chunks, the parser
returns exactly the well-framed windows with a good checksum, in order, each at its end
offset; it follows that no bad checksum is ever accepted and that a valid frame
surrounded by arbitrary bytes is always found.

ASCII: arbitrary bytes before a line are part of that line unless they end with a line
break, so the property is: a valid line preceded by arbitrary bytes ending in ``\n`` (or by
nothing) and followed by anything is found.

kvh_fog: the parser gives exactly what a slow reading of the manual's byte tables gives
(header, CRC, status, sequence, temperature), for any chunking; a flipped bit is never
accepted; a message between arbitrary bytes is always found.
"""

import math
import struct

from hypothesis import assume, given, strategies as st

from test_kvh_fog import crc32_mpeg2_bitwise

from art_gyro_calibration.frame import INT16_MAX, INT16_MIN
from art_gyro_calibration.protocols.kvh_fog import (KVH_HEADER_PREFIX, KvhFogConfig, KvhFogParser, crc32_mpeg2,
                                                    encode_kvh_fog)
from art_gyro_calibration.protocols.rd2100_ascii import MAX_LINE_BYTES, AsciiFrameParser, encode_ascii
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
    """(raw_rate, raw_temp, end) of every well-framed window with a good checksum: the slow, obvious way."""
    found = []
    for i in range(len(data) - 7):
        window = data[i:i + 8]
        if not window[0] & 0x80 or any(b & 0x80 for b in window[1:]):
            continue
        bits = 0
        for b in window:
            bits = (bits << 7) | (b & 0x7F)
        m = bits.to_bytes(7, 'big')
        if sum(m) % 256 == 0 and any(m):   # an all-zero frame is no gyro's (issue 25)
            found.append((int.from_bytes(m[5:7], 'big', signed=True),
                          int.from_bytes(m[3:5], 'big', signed=True), i + 8))
    return found


def chunks(data: bytes, cuts: list[int]) -> list[bytes]:
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
    assume((raw_rate, raw_temp) != (0, 0))   # the all-zero frame is refused (issue 25)
    data = prefix + encode_binary(raw_rate, raw_temp) + suffix
    assert (raw_rate, raw_temp, len(prefix) + 8) in parse_binary(chunks(data, cuts))[1]


@given(st.binary(max_size=200), st.lists(st.integers(0, 1000), max_size=10))
def test_ascii_parser_never_raises_and_stays_bounded(data, cuts):
    parser = AsciiFrameParser()
    for piece in chunks(data, cuts):
        for sample, end in parser.feed(piece):
            assert INT16_MIN <= sample.raw_rate <= INT16_MAX and INT16_MIN <= sample.raw_temp <= INT16_MAX
            assert 1 <= end <= len(piece) and piece[end - 1:end] == b'\n'
        assert len(parser._buffer) <= MAX_LINE_BYTES


@given(st.binary(max_size=100), int16, int16, st.binary(max_size=100), st.lists(st.integers(0, 300), max_size=6))
def test_ascii_line_after_a_line_break_is_found(prefix, raw_rate, raw_temp, suffix, cuts):
    data = prefix + b'\n' + encode_ascii(raw_rate, raw_temp) + suffix
    parser = AsciiFrameParser()
    got, base = [], 0
    for piece in chunks(data, cuts):
        got += [(s.raw_rate, s.raw_temp, base + end) for s, end in parser.feed(piece)]
        base += len(piece)
    assert (raw_rate, raw_temp, len(data) - len(suffix)) in got


# --- kvh_fog -------------------------------------------------------------------------------------
# Messages with any sequence number and status (so gaps, repeats and invalid flags all occur),
# messages with a bit flipped, cut short, of another format, and noise, cut into any chunks: the
# parser must give what the slow, obvious reading of the manual gives.

@given(st.binary(max_size=300))
def test_kvh_crc_matches_the_bitwise_definition(data):
    assert crc32_mpeg2(data) == crc32_mpeg2_bitwise(data)


floats32 = st.floats(width=32)   # NaN and infinities included
kvh_formats = st.sampled_from('AC')


def kvh_messages(fmt: str) -> st.SearchStrategy[bytes]:
    return st.builds(lambda r, seq, status, t, f: encode_kvh_fog((r, -r, r), (0.0, 0.0, 1.0), status, seq,
                                                                 float(t) if f == 'C' else t, f),
                     floats32, st.integers(0, 127), st.sampled_from([0x77, 0x73, 0x71, 0x04, 0x00]),
                     st.integers(INT16_MIN, INT16_MAX), st.just(fmt))


def kvh_stream(fmt: str) -> st.SearchStrategy[bytes]:
    good = kvh_messages(fmt)
    flipped = st.builds(lambda m, bit: bytes(b ^ (1 << bit % 8) if i == bit // 8 else b for i, b in enumerate(m)),
                        good, st.integers(0, 8 * 36 - 1))
    cut = good.flatmap(lambda m: st.integers(1, len(m) - 1).map(lambda n: m[:n]))
    other = kvh_messages('C' if fmt == 'A' else 'A')
    return st.lists(st.one_of(good, good, flipped, cut, other, st.binary(max_size=40),
                              st.just(KVH_HEADER_PREFIX)), max_size=12).map(b''.join)


def reference_kvh(data: bytes, config: KvhFogConfig) -> tuple[list[tuple[float, float, int]], int]:
    """(rate, temperature, end) of every accepted message and the lost count: byte offsets from the manual's tables.

    A delta angle has no interval without arrival times: none is accepted. A message with a bad CRC
    between two good ones is rejected, not also lost.
    """
    header = {'A': b'\xfe\x81\xff\x55', 'C': b'\xfe\x81\xff\x57'}[config.message_format]
    length = {'A': 36, 'C': 38}[config.message_format]
    out, lost, last, held_temp, i, bad_crc = [], 0, None, None, 0, 0
    while i + length <= len(data):
        message = data[i:i + length]
        if message[:4] != header or crc32_mpeg2_bitwise(message[:-4]) != int.from_bytes(message[-4:], 'big'):
            bad_crc += message[:4] == header
            i += 1
            continue
        i += length
        rotation = struct.unpack('>f', message[4 + 4 * config.axis_index:8 + 4 * config.axis_index])[0]
        status, sequence = message[{'A': 28, 'C': 32}[config.message_format]:][:2]
        if config.message_format == 'C':
            if sequence % 4 == 0:
                held_temp = config.temperature_c(struct.unpack('>f', message[28:32])[0])
            temp = held_temp
        else:
            temp = config.temperature_c(int.from_bytes(message[30:32], 'big', signed=True))
        if last is not None:
            if sequence == last:
                continue
            lost += max(0, (sequence - last - 1) % 128 - bad_crc)
        last, bad_crc = sequence, 0
        rate = rotation * config.dps_per_unit
        if (status >> config.axis_index & 1 and temp is not None and math.isfinite(rate) and math.isfinite(temp)
                and not config.delta_angle):
            out.append((rate, temp, i))
    return out, lost


def parse_kvh(pieces: list[bytes], config: KvhFogConfig) -> tuple[KvhFogParser, list[tuple[float, float, int]]]:
    parser = KvhFogParser(config)
    out, base = [], 0
    for piece in pieces:
        out += [(s.raw_rate, s.raw_temp, base + end) for s, end in parser.feed(piece)]
        base += len(piece)
    return parser, out


kvh_configs = st.builds(KvhFogConfig, kvh_formats, st.sampled_from(['+x', '-y', 'z']),
                        st.sampled_from(['delta_angle', 'rate']), st.sampled_from(['rad', 'deg']),
                        st.sampled_from([1.0, 100.0, 1000.0]), st.sampled_from(['C', 'C_100', 'F_100']))


@given(kvh_configs.flatmap(lambda c: st.tuples(st.just(c), kvh_stream(c.message_format))),
       st.lists(st.integers(0, 1000), max_size=10))
def test_kvh_parser_gives_what_the_manual_gives_for_any_chunking(config_and_data, cuts):
    config, data = config_and_data
    parser, out = parse_kvh(chunks(data, cuts), config)
    expected, lost = reference_kvh(data, config)
    assert out == expected
    assert parser.stats.frames == len(expected) and parser.stats.lost_frames == lost
    assert parser.stats.bytes_skipped + config.format.length * len(expected) + len(parser._buffer) == len(data)


@given(kvh_messages('A'), st.integers(0, 8 * 32 - 1))
def test_kvh_parser_never_accepts_a_flipped_bit(message, bit):
    corrupted = bytearray(message)
    corrupted[4 + bit // 8] ^= 1 << bit % 8   # anywhere after the header, the CRC included
    parser, out = parse_kvh([bytes(corrupted)], KvhFogConfig())
    assert out == [] and parser.stats.rejected_by_reason['bad_crc'] == 1


@given(st.binary(max_size=80), st.floats(-1e3, 1e3, width=32), st.integers(0, 127),
       st.integers(INT16_MIN, INT16_MAX), st.binary(max_size=80), st.lists(st.integers(0, 300), max_size=6))
def test_kvh_message_between_arbitrary_bytes_is_found(prefix, rate, sequence, temperature, suffix, cuts):
    config = KvhFogConfig(rotation='rate', angle_units='deg')
    data = prefix + encode_kvh_fog((0.0, 0.0, rate), (0.0, 0.0, 1.0), 0x77, sequence, temperature) + suffix
    got = parse_kvh(chunks(data, cuts), config)[1]
    assert (rate, float(temperature), len(prefix) + 36) in got
