"""Tests of the RD2100 frame parsers and encoders."""

import itertools

import pytest

from art_gyro_calibration.frame import (BAD_CHECKSUM, GARBAGE, LINE_TOO_LONG, MALFORMED, MAX_LINE_BYTES,
                                        OUT_OF_RANGE, AsciiFrameParser, BinaryFrameParser, RawSample,
                                        encode_ascii, encode_binary, make_encoder, make_parser)

EXTREMES = (-32768, -32767, -256, -129, -128, -1, 0, 1, 127, 128, 255, 256, 12345, 32766, 32767)
PAIRS = list(itertools.product(EXTREMES, repeat=2))


def samples(results):
    return [(s.raw_rate, s.raw_temp) for s, _ in results]


def test_binary_frame_layout_follows_the_e_core_description():
    frame = encode_binary(-2, 500)
    assert len(frame) == 8
    assert frame[0] & 0x80 and not any(b & 0x80 for b in frame[1:])
    bits = 0
    for b in frame:
        bits = (bits << 7) | (b & 0x7F)
    m = bits.to_bytes(7, 'big')
    assert m[0] == -sum(m[1:]) & 0xFF
    assert m[1] == m[2] == 0
    assert int.from_bytes(m[3:5], 'big', signed=True) == 500
    assert int.from_bytes(m[5:7], 'big', signed=True) == -2


@pytest.mark.parametrize('protocol', ['binary', 'ascii'])
def test_round_trip_of_many_values_including_extremes(protocol):
    encode = make_encoder(protocol)
    data = b''.join(encode(r, t) for r, t in PAIRS)
    parser = make_parser(protocol)
    out = parser.feed(data)
    assert samples(out) == PAIRS
    assert out[-1][1] == len(data)
    assert parser.stats.frames == len(PAIRS) and parser.stats.rejected == 0 and parser.stats.bytes_skipped == 0


@pytest.mark.parametrize('protocol', ['binary', 'ascii'])
def test_one_byte_at_a_time_gives_the_same_frames_with_offsets(protocol):
    encode = make_encoder(protocol)
    data = b''.join(encode(r, t) for r, t in PAIRS[:40])
    parser = make_parser(protocol)
    got = []
    for i in range(len(data)):
        for sample, end in parser.feed(data[i:i + 1]):
            assert end == 1   # the frame completes with the byte just fed
            got.append((sample.raw_rate, sample.raw_temp))
    assert got == PAIRS[:40]


def test_binary_offsets_point_just_past_each_frame_in_the_chunk():
    frames = [encode_binary(i, -i) for i in range(5)]
    parser = BinaryFrameParser()
    assert parser.feed(frames[0][:3]) == []
    out = parser.feed(frames[0][3:] + frames[1] + frames[2][:7])
    assert out == [(RawSample(0, 0), 5), (RawSample(1, -1), 13)]
    assert parser.feed(frames[2][7:]) == [(RawSample(2, -2), 1)]


def test_binary_garbage_before_and_between_is_skipped_and_counted():
    parser = BinaryFrameParser()
    data = (b'\x00\x7f\xff\x80\x81' + encode_binary(10, 20) + b'\xfe\x01\x02' + encode_binary(-5, 7)
            + b'\x90' + encode_binary(3, 4))
    assert samples(parser.feed(data)) == [(10, 20), (-5, 7), (3, 4)]
    assert parser.stats.rejected_by_reason == {BAD_CHECKSUM: 0, GARBAGE: 3}
    assert parser.stats.bytes_skipped == 5 + 3 + 1


def test_binary_bad_checksum_counted_and_the_next_good_frame_kept():
    good = encode_binary(100, 200)
    bad = bytearray(encode_binary(1, 2))
    bad[7] ^= 0x01   # flip a rate bit: still well framed, checksum now wrong
    parser = BinaryFrameParser()
    assert samples(parser.feed(bytes(bad) + good)) == [(100, 200)]
    assert parser.stats.rejected_by_reason[BAD_CHECKSUM] == 1
    assert parser.stats.rejected == 1 and parser.stats.frames == 1


def test_binary_truncated_frame_followed_by_a_frame_loses_only_the_truncated_one():
    truncated = encode_binary(7, 8)[:5]
    parser = BinaryFrameParser()
    assert samples(parser.feed(truncated)) == []
    assert samples(parser.feed(encode_binary(9, 10))) == [(9, 10)]
    assert parser.stats.rejected_by_reason == {BAD_CHECKSUM: 0, GARBAGE: 1}
    assert parser.stats.bytes_skipped == 5


def test_binary_garbage_straddling_feeds_counts_as_one_run():
    parser = BinaryFrameParser()
    parser.feed(b'\x01\x02')
    parser.feed(b'\x03\xff')
    parser.feed(b'\x05' + encode_binary(1, 1))
    assert parser.stats.rejected_by_reason[GARBAGE] == 1
    assert parser.stats.bytes_skipped == 5


def test_reset_drops_a_partial_frame():
    parser = BinaryFrameParser()
    frame = encode_binary(4, 5)
    parser.feed(frame[:4])
    parser.reset()
    assert parser.feed(frame[4:]) == []
    assert samples(parser.feed(frame)) == [(4, 5)]


def test_ascii_reset_skips_to_the_next_line_break_so_a_cut_line_gives_no_wrong_sample():
    parser = AsciiFrameParser()
    assert samples(parser.feed(b'-1234 500\r\n-12')) == [(-1234, 500)]
    parser.reset()   # the link was lost mid-line; the port reopens mid-line of another sample
    assert parser.feed(b'34 5') == []
    assert parser.feed(b'00\r\n-1234 500\r\n') == [(RawSample(-1234, 500), 15)]
    assert parser.stats.rejected == 0 and parser.stats.bytes_skipped == 3 + 8
    parser.reset()   # at a line start, the first whole line is skipped too: it cannot be told from a tail
    assert samples(parser.feed(b'1 2\n3 4\n')) == [(3, 4)]


def test_ascii_accepts_lf_and_crlf_and_counts_malformed_lines():
    parser = AsciiFrameParser()
    data = b'12 -34\r\n5 6\nabc\r\n1 2 3\r\n7\r\n\r\n1.5 2\r\n-7 +8\r\n 9 10 \r\n'
    assert samples(parser.feed(data)) == [(12, -34), (5, 6), (-7, 8), (9, 10)]
    assert parser.stats.rejected_by_reason == {MALFORMED: 4, OUT_OF_RANGE: 0, LINE_TOO_LONG: 0}


def test_ascii_out_of_range_numbers_are_rejected():
    parser = AsciiFrameParser()
    assert samples(parser.feed(b'32768 0\r\n0 -32769\r\n32767 -32768\r\n99999999999 1\r\n')) == [(32767, -32768)]
    assert parser.stats.rejected_by_reason[OUT_OF_RANGE] == 2
    assert parser.stats.rejected_by_reason[MALFORMED] == 1   # more digits than any count has


def test_ascii_stream_without_newline_does_not_grow_the_buffer():
    parser = AsciiFrameParser()
    for _ in range(1000):
        assert parser.feed(b'1' * 1000) == []
        assert len(parser._buffer) <= MAX_LINE_BYTES
    assert parser.stats.rejected_by_reason[LINE_TOO_LONG] == 1
    # The rest of the overlong line is dropped at its newline; the next line is read.
    assert samples(parser.feed(b'23\r\n4 5\r\n')) == [(4, 5)]
    assert parser.stats.rejected_by_reason == {MALFORMED: 0, OUT_OF_RANGE: 0, LINE_TOO_LONG: 1}


def test_ascii_overlong_complete_line_is_counted():
    parser = AsciiFrameParser()
    assert samples(parser.feed(b' ' * (MAX_LINE_BYTES + 1) + b'\n1 2\n')) == [(1, 2)]
    assert parser.stats.rejected_by_reason[LINE_TOO_LONG] == 1


@pytest.mark.parametrize('value', [32768, -32769, 1 << 20])
@pytest.mark.parametrize('encode', [encode_binary, encode_ascii])
def test_encoders_refuse_values_outside_16_bits(encode, value):
    with pytest.raises(ValueError, match='signed 16-bit'):
        encode(value, 0)
    with pytest.raises(ValueError, match='raw_temp'):
        encode(0, value)


def test_unknown_protocol_is_a_clear_error():
    with pytest.raises(ValueError, match=r"unknown protocol 'nmea'.*binary, ascii"):
        make_parser('nmea')
    with pytest.raises(ValueError, match='unknown protocol'):
        make_encoder('')
