"""Tests of the protocol registry over the RD2100 protocols: round trips through make_encoder/make_parser, errors."""

import itertools

import pytest

from art_gyro_calibration.frame import ProtocolDescription
from art_gyro_calibration.protocols import PROTOCOLS, describe, make_encoder, make_parser
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


def test_the_driver_node_and_diagnostics_see_protocols_only_through_the_seam():
    """They import no protocol module (only the registry) and name no protocol: a new one needs no change there."""
    import ast
    from pathlib import Path

    package = Path(__file__).resolve().parent.parent / 'art_gyro_calibration'
    for path in (package / 'driver.py', package / 'ros' / 'node.py', package / 'ros' / 'diagnostics.py'):
        source = path.read_text(encoding='utf-8')
        for node in ast.walk(ast.parse(source)):
            if isinstance(node, ast.ImportFrom):
                assert not (node.module or '').startswith('art_gyro_calibration.protocols.'), (path.name, node.module)
            if isinstance(node, ast.Constant) and isinstance(node.value, str):
                assert node.value not in PROTOCOLS, (path.name, node.value)
            if isinstance(node, ast.Name):
                assert node.id not in ('KVH_FOG', 'KvhFogParser', 'KvhSample'), (path.name, node.id)


@pytest.mark.parametrize('protocol', PROTOCOLS)
def test_every_parser_offers_the_one_interface_and_describes_its_protocol(protocol):
    """feed(data, arrival_ns), reset, measured_rate_hz and the description the node gets from the registry."""
    config = KvhFogConfig(rotation='rate')
    parser = make_parser(protocol, config, lock_frames=1, byte_ns=86_805)
    assert parser.description == describe(protocol, config)
    frame = make_encoder(protocol, config)(7, 500)
    [(sample, end)] = parser.feed(frame, 1_000_000_000)
    assert (sample.raw_rate, sample.raw_temp, end) == (pytest.approx(7), pytest.approx(500), len(frame))
    parser.reset()
    assert parser.stats.frames == 1 and parser.measured_rate_hz is None   # a rate needs a second of messages
    description = parser.description
    if protocol == 'kvh_fog':   # the whole IMU, its own clock if set so, a CRC-32 trusted without a rate check
        assert sample.imu is not None and description.imu_axes and not description.checks_rate_jumps
        assert description.hardware == 'KVH FOG' and description.reports_rate
    else:   # the RD2100's: a rate and a temperature, counts behind an 8-bit checksum
        assert (sample.imu, sample.unit_time_us, sample.interval_s) == (None, None, None)
        assert description == ProtocolDescription() and description.checks_rate_jumps
        assert description.hardware == 'KVH RD2100' and description.rate_error(10.0) == ''


def test_the_kvh_fog_description_says_when_the_output_rate_is_not_the_units():
    description = describe('kvh_fog', KvhFogConfig(output_rate_hz=1000.0))
    assert description.rate_error(None) == '' and description.rate_error(1010.0) == ''   # within 2 %
    assert description.rate_error(200.0).startswith('kvh_fog.output_rate_hz is 1000 Hz but the unit sends 200.00 '
                                                    'messages/s (measured by the stream)')
