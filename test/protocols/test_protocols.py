"""Tests of the protocol registry over the RD2100 protocols: round trips through make_encoder/make_parser, errors."""

import itertools

import pytest

from art_gyro_calibration.protocols import describe, make_encoder, make_parser
from art_gyro_calibration.protocols.kvh_fog import KvhFogConfig
from art_gyro_calibration.protocols.rd2100_ascii import encode_ascii
from art_gyro_calibration.protocols.rd2100_binary import encode_binary

EXTREMES = (-32768, -32767, -256, -129, -128, -1, 0, 1, 127, 128, 255, 256, 12345, 32766, 32767)
PAIRS = list(itertools.product(EXTREMES, repeat=2))


def samples(results):
    return [(s.raw_rate, s.raw_temp) for s, _ in results]


@pytest.mark.parametrize('protocol', ['binary', 'ascii'])
def test_round_trip_of_many_values_including_extremes(protocol):
    encode = make_encoder(protocol)
    pairs = [p for p in PAIRS if protocol != 'binary' or p != (0, 0)]   # binary: the all-zero frame is refused
    data = b''.join(encode(r, t) for r, t in pairs)
    parser = make_parser(protocol)
    out = parser.feed(data)
    assert samples(out) == pairs
    assert out[-1][1] == len(data)
    assert parser.stats.frames == len(pairs) and parser.stats.rejected == 0 and parser.stats.bytes_skipped == 0


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


@pytest.mark.parametrize('protocol, bad', [('binary', encode_binary(5, 500)[:7] + b'\x7f'), ('ascii', b'5 x\r\n')])
def test_frames_missed_counts_the_frames_refused_before_each_one_returned(protocol, bad):
    """The stream lock's held-back frames and a refused frame count; bytes between frames and blank lines do not.

    Read whole or a byte at a time alike: the frame guard is told of them however the backlog was read.
    """
    encode = make_encoder(protocol)
    good = [encode(r, 500) for r in range(12)]
    filler = b'\x05\x06' if protocol == 'binary' else b'\r\n'
    stream = b''.join(good[:5]) + filler + b''.join(good[5:8]) + bad + b''.join(good[8:])
    for size in (len(stream), 1):
        parser = make_parser(protocol, lock_frames=3)
        got, missed = [], []
        for i in range(0, len(stream), size):
            got += [s.raw_rate for s, _ in parser.feed(stream[i:i + size])]
            missed += parser.frames_missed
        # Binary: 0, 1 held back; the garbage breaks the lock (5, 6 held back); the bad frame, then 8, 9.
        # Ascii: the blank line breaks nothing; the malformed line, then 8, 9 held back.
        assert got == ([2, 3, 4, 7, 10, 11] if protocol == 'binary' else [2, 3, 4, 5, 6, 7, 10, 11]), size
        assert missed == ([2, 0, 0, 2, 3, 0] if protocol == 'binary' else [2, 0, 0, 0, 0, 0, 3, 0]), size


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


def test_the_kvh_fog_description_says_when_the_output_rate_is_not_the_units():
    description = describe('kvh_fog', KvhFogConfig(output_rate_hz=1000.0))
    assert description.rate_error(None) == '' and description.rate_error(1010.0) == ''   # within 2 %
    assert description.rate_error(200.0).startswith('kvh_fog.output_rate_hz is 1000 Hz but the unit sends 200.00 '
                                                    'messages/s (measured by the stream)')
