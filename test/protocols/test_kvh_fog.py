"""Tests of the KVH kvh_fog message: the manual's sample, CRC, formats, units, faults, sequence numbers, config."""

import math
import random
import re
import struct
import zlib

import pytest

from art_gyro_calibration.frame import AXIS_INVALID, NOT_FINITE, RawSample
from art_gyro_calibration.protocols import make_encoder, make_parser
from art_gyro_calibration.protocols.kvh_fog import (BAD_CRC, BAD_TIMESTAMP, KVH_FORMATS, NO_INTERVAL,
                                                    NO_TEMPERATURE_YET, OTHER_FORMAT, REPEATED_SEQUENCE, KvhFogConfig,
                                                    KvhFogParser, crc32_mpeg2, encode_kvh_fog)


# The 1775 IMU technical manual's sample message (section 5.2.1), Format A, all sensors valid.
MANUAL_SAMPLE = bytes.fromhex('FE 81 FF 55 37 A9 6A 6E 38 58 6C 1F B7 5B F8 62 BF 80 3E 78 BB 65 0D 28 3B 0A 37 AC '
                              '77 3D 00 28 4B FA 34 D8')
MANUAL_ROTATION = (2.0196e-05, 5.1599e-05, -1.3111e-05)
MANUAL_ACCELERATION = (-1.00191, -0.0034950, 0.0021090)


def crc32_mpeg2_bitwise(data: bytes) -> int:
    """CRC-32/MPEG-2 from its definition, a bit at a time: poly 0x04C11DB7, init all ones, MSB first, no XOR out."""
    crc = 0xFFFFFFFF
    for byte in data:
        crc ^= byte << 24
        for _ in range(8):
            crc = ((crc << 1) ^ 0x04C11DB7 if crc & 0x80000000 else crc << 1) & 0xFFFFFFFF
    return crc


RATES = KvhFogConfig(rotation='rate')   # rates in rad/s: no interval needed


def kvh_samples(parser, data):
    return [(s.raw_rate, s.raw_temp) for s, _ in parser.feed(data)]


def test_kvh_crc_is_crc32_mpeg2_checked_on_the_manual_sample_and_the_catalogue_check_value():
    assert crc32_mpeg2(MANUAL_SAMPLE[:32]) == crc32_mpeg2_bitwise(MANUAL_SAMPLE[:32]) == 0x4BFA34D8
    assert MANUAL_SAMPLE[32:] == bytes.fromhex('4BFA34D8')
    # The CRC catalogue's check value of CRC-32/MPEG-2 (and zlib's reflected CRC-32 differs).
    assert crc32_mpeg2(b'123456789') == crc32_mpeg2_bitwise(b'123456789') == 0x0376E6E7
    assert zlib.crc32(MANUAL_SAMPLE[:32]) != 0x4BFA34D8


def test_kvh_manual_sample_decodes_to_the_manuals_values():
    rx, ry, rz, ax, ay, az, status, sequence, temperature = KVH_FORMATS['A'].layout.unpack_from(MANUAL_SAMPLE, 4)
    assert (rx, ry, rz) == pytest.approx(MANUAL_ROTATION, rel=1e-4)
    assert (ax, ay, az) == pytest.approx(MANUAL_ACCELERATION, rel=1e-4)
    assert (status, sequence, temperature) == (0x77, 61, 40)
    # The encoder writes exactly the manual's bytes for those values.
    assert encode_kvh_fog((rx, ry, rz), (ax, ay, az), 0x77, 61, 40) == MANUAL_SAMPLE


@pytest.mark.parametrize('axis, value', list(zip('xyz', MANUAL_ROTATION)))
def test_kvh_parser_takes_the_manual_sample_on_each_axis(axis, value):
    """Rate in degrees: the float itself; in radians: times 180/pi; with sign; temperature 40 degC."""
    parser = make_parser('kvh_fog', KvhFogConfig(yaw_axis=axis, rotation='rate', angle_units='deg'))
    [(sample, end)] = parser.feed(MANUAL_SAMPLE)
    assert (RawSample(sample.raw_rate, sample.raw_temp), end) == (RawSample(pytest.approx(value, rel=1e-4), 40.0), 36)
    assert sample.imu.rates_dps == pytest.approx(MANUAL_ROTATION, rel=1e-4)
    assert sample.imu.acceleration_g == pytest.approx(MANUAL_ACCELERATION, rel=1e-4)
    assert sample.imu.rate_valid == sample.imu.acceleration_valid == (True, True, True)   # status 0x77
    down = KvhFogParser(KvhFogConfig(yaw_axis=f'-{axis}', rotation='rate', angle_units='rad'))
    assert kvh_samples(down, MANUAL_SAMPLE) == [(pytest.approx(-math.degrees(value), rel=1e-4), 40.0)]
    assert parser.frame_bytes == 36 and parser.stats.rejected == 0 and parser.stats.lost_frames == 0


def test_kvh_delta_angle_needs_a_measured_interval_not_the_configured_rate():
    """Without arrival times (or before a second of them) a delta angle in A is rejected, never scaled by 1000 Hz."""
    parser = make_parser('kvh_fog')   # defaults: A, +z, delta_angle, rad, 1000 Hz, C
    assert kvh_samples(parser, MANUAL_SAMPLE) == []
    assert parser.stats.rejected_by_reason[NO_INTERVAL] == 1 and parser.measured_rate_hz is None


@pytest.mark.parametrize('units, wire, expected_c', [('C', 40, 40.0), ('C_100', 4012, 40.12), ('F', 104, 40.0),
                                                     ('F_100', -4000, -40.0)])
def test_kvh_temperature_units(units, wire, expected_c):
    message = encode_kvh_fog((0.0, 0.0, 0.0), (0.0, 0.0, 1.0), 0x77, 0, wire)
    parser = KvhFogParser(KvhFogConfig(rotation='rate', temperature_units=units))
    assert kvh_samples(parser, message) == [(0.0, pytest.approx(expected_c, abs=1e-12))]


def kvh_message(sequence, status=0x77, temperature=40, message_format='A', z=0.001):
    return encode_kvh_fog((0.0, 0.0, z), (0.0, 0.0, 1.0), status, sequence, temperature, message_format,
                          magnetic=(0.25, -0.5, 0.75))


def test_kvh_stream_with_the_sample_cut_repeated_bit_flipped_and_a_sequence_gap():
    """Only whole, new, good messages come out; each fault is counted by its reason; lost frames are the gaps."""
    cut = kvh_message(60)[:17]
    flipped = bytearray(kvh_message(62))
    flipped[20] ^= 0x08
    stream = (b'\x00\xfe\x81' + cut + MANUAL_SAMPLE + MANUAL_SAMPLE + bytes(flipped) + kvh_message(63)
              + kvh_message(66) + b'\xfe\x81\xff' + kvh_message(67) + kvh_message(0)[:30])
    config = KvhFogConfig(rotation='rate', angle_units='deg')
    results = {}
    for size in (len(stream), 1, 7, 36, 37):   # whole, a byte at a time, and chunks across the messages
        parser = KvhFogParser(config)
        got, missed = [], []
        for i in range(0, len(stream), size):
            got += kvh_samples(parser, stream[i:i + size])
            missed += parser.frames_missed
        stats = parser.stats
        results[size] = (got, stats.rejected_by_reason, stats.lost_frames, stats.frames, stats.bytes_skipped,
                         parser.stats.garbage_runs, missed)
    got, reasons, lost, frames, skipped, garbage_runs, missed = results[len(stream)]
    assert all(r == results[len(stream)] for r in results.values())
    assert got == [(pytest.approx(-1.3111e-05, rel=1e-4), 40.0)] + [(pytest.approx(0.001), 40.0)] * 3
    assert frames == 4
    # The cut message and the flipped one fail their CRC; the second copy of the sample repeats sequence 61.
    # Garbage: the bytes before the cut message, and the lone header start before message 67.
    assert reasons == {BAD_CRC: 2, OTHER_FORMAT: 0, AXIS_INVALID: 0, REPEATED_SEQUENCE: 1,
                       NOT_FINITE: 0, NO_TEMPERATURE_YET: 0, NO_INTERVAL: 0, BAD_TIMESTAMP: 0}
    assert garbage_runs == 2 and parser.stats.rejected == 3   # runs of garbage are no rejected messages
    # 64 and 65 never sent; 62 came with a bad CRC: one rejected frame, not also a lost one.
    assert lost == 2
    # What the frame guard is told came between the messages returned (61, 63, 66, 67): 62, then 64 and 65.
    assert missed == [0, 1, 2, 0]
    # Every byte is in an accepted message, skipped, or held (the last message, still arriving).
    assert skipped + 36 * frames + len(parser._buffer) == len(stream) and len(parser._buffer) == 30


def test_kvh_offsets_point_just_past_each_message_in_the_chunk():
    parser = KvhFogParser(RATES)
    messages = [kvh_message(i) for i in range(3)]
    assert parser.feed(messages[0][:10]) == []
    out = parser.feed(messages[0][10:] + messages[1] + messages[2][:35])
    assert [end for _, end in out] == [26, 62]
    assert [end for _, end in parser.feed(messages[2][35:])] == [1]


def test_kvh_invalid_yaw_gyro_is_not_published_and_counted_other_axes_do_not_matter():
    z_invalid = kvh_message(1, status=0x73)   # gyro z (bit 2) invalid
    only_z = kvh_message(2, status=0x04)      # everything but gyro z invalid
    parser = KvhFogParser(RATES)
    assert len(parser.feed(kvh_message(0) + z_invalid + only_z)) == 2
    assert parser.stats.rejected_by_reason[AXIS_INVALID] == 1 and parser.stats.lost_frames == 0
    x_parser = KvhFogParser(KvhFogConfig(yaw_axis='x', rotation='rate'))
    assert len(x_parser.feed(z_invalid + only_z)) == 1
    assert x_parser.stats.rejected_by_reason[AXIS_INVALID] == 1


def test_kvh_format_c_holds_the_temperature_of_every_fourth_message():
    """Format C: 38 bytes; sequence 0 mod 4 carries the temperature, 1-3 the magnetometer (never a temperature)."""
    config = KvhFogConfig(message_format='C', rotation='rate', angle_units='deg')
    parser = make_parser('kvh_fog', config)
    assert parser.frame_bytes == 38
    data = b''.join(kvh_message(s, temperature=20.0 + s, message_format='C') for s in (1, 2, 3, 4, 5, 6, 7, 8))
    assert len(data) == 8 * 38
    assert [t for _, t in kvh_samples(parser, data)] == [24.0, 24.0, 24.0, 24.0, 28.0]
    assert parser.stats.rejected_by_reason[NO_TEMPERATURE_YET] == 3
    parser.reset()   # a new connection: the held temperature is gone
    assert kvh_samples(parser, kvh_message(9, message_format='C')) == []
    assert parser.stats.rejected_by_reason[NO_TEMPERATURE_YET] == 4


def test_kvh_format_b_has_a_timestamp_and_40_bytes():
    config = KvhFogConfig(message_format='B', rotation='rate', angle_units='deg')
    message = encode_kvh_fog((0.0, 0.0, 1.5), (0.0, 0.0, 1.0), 0x77, 5, -12, 'B', timestamp_us=123456789)
    assert len(message) == 40 and message[:4] == bytes.fromhex('FE81FF56')
    assert kvh_samples(make_parser('kvh_fog', config), message) == [(1.5, -12.0)]


def test_kvh_other_formats_are_counted_and_skipped():
    parser = KvhFogParser(RATES)
    data = kvh_message(0, message_format='C') + kvh_message(1) + kvh_message(2, message_format='B') + kvh_message(3)
    assert len(parser.feed(data)) == 2
    assert parser.stats.rejected_by_reason[OTHER_FORMAT] == 2
    assert parser.stats.garbage_runs == 0 and parser.stats.rejected_by_reason[BAD_CRC] == 0
    assert parser.stats.bytes_skipped == 38 + 40
    assert parser.stats.lost_frames == 1   # 2 came in a format this parser does not read


def test_kvh_non_finite_values_are_rejected():
    parser = KvhFogParser(RATES)
    assert kvh_samples(parser, kvh_message(0, z=math.nan) + kvh_message(1, z=math.inf) + kvh_message(2)) != []
    assert parser.stats.rejected_by_reason[NOT_FINITE] == 2 and parser.stats.frames == 1


def test_kvh_sequence_wraps_after_127_and_reset_forgets_it():
    parser = KvhFogParser(RATES)
    parser.feed(b''.join(kvh_message(s) for s in (126, 127, 0, 1, 3)))
    assert parser.stats.frames == 5 and parser.stats.lost_frames == 1
    parser.feed(kvh_message(4)[:20])
    parser.reset()   # the link was lost: the partial message is dropped, and a gap across it is unknown
    assert kvh_samples(parser, kvh_message(4)[20:] + kvh_message(90)) == [(pytest.approx(math.degrees(0.001)), 40.0)]
    assert parser.stats.lost_frames == 1 and parser.stats.frames == 6


@pytest.mark.parametrize('message_format', ['A', 'B', 'C'])
@pytest.mark.parametrize('rotation, angle_units, temperature_units', [
    ('delta_angle', 'rad', 'C'), ('rate', 'deg', 'C_100'), ('delta_angle', 'deg', 'F'), ('rate', 'rad', 'F_100')])
@pytest.mark.parametrize('yaw_axis', ['+z', '-y', 'x'])
def test_kvh_encoder_and_parser_round_trip(message_format, rotation, angle_units, temperature_units, yaw_axis):
    """Samples in deg/s and degC survive the unit's float32 and its temperature resolution."""
    config = KvhFogConfig(message_format, yaw_axis, rotation, angle_units, 250.0, temperature_units)
    encode = make_encoder('kvh_fog', config)
    parser = make_parser('kvh_fog', config)
    # A second of messages first, each read as it comes at 250 Hz: a delta angle's interval is then measured.
    for i in range(300):
        parser.feed(encode(0.0, 20.0), arrival_ns=i * 4_000_000)
    assert encode.sequence % 4 == 0   # Format C's temperature comes with the first message below
    rates = [0.0, 1e-4, -0.5, 30.0, -400.0]
    got = [(s.raw_rate, s.raw_temp) for i, rate in enumerate(rates * 2)   # 10 messages: C has temperatures
           for s, _ in parser.feed(encode(rate, 25.3 - i), arrival_ns=(300 + i) * 4_000_000)]
    skipped = 0 if message_format != 'C' else 0   # the encoder starts at sequence 0, a temperature message
    assert [r for r, _ in got] == pytest.approx((rates * 2)[skipped:], rel=1e-6, abs=1e-9)
    temps = [t for _, t in got]
    if message_format == 'C':   # a float every fourth message, held between
        assert temps == pytest.approx([25.3 - 4 * (i // 4) for i in range(10)], abs=1e-4)
    else:
        resolution = {'C': 1.0, 'C_100': 0.01, 'F': 5 / 9, 'F_100': 0.01 * 5 / 9}[temperature_units]
        assert temps == pytest.approx([25.3 - i for i in range(10)], abs=resolution / 2 + 1e-9)


@pytest.mark.parametrize('field, value, message', [
    ('message_format', 'D', 'kvh_fog.message_format must be one of A, B, C'),
    ('yaw_axis', 'up', 'kvh_fog.yaw_axis must be x, y or z'),
    ('yaw_axis', '+-z', 'kvh_fog.yaw_axis'),
    ('rotation', 'angle', 'kvh_fog.rotation must be one of delta_angle, rate'),
    ('angle_units', 'grad', 'kvh_fog.angle_units'),
    ('output_rate_hz', 0.0, 'kvh_fog.output_rate_hz must be a number of Hz in'),
    ('output_rate_hz', 6000.0, 'kvh_fog.output_rate_hz'),
    ('output_rate_hz', math.nan, 'kvh_fog.output_rate_hz'),
    ('temperature_units', 'K', 'kvh_fog.temperature_units must be one of C, C_100, F, F_100'),
])
def test_kvh_config_refuses_bad_settings_naming_the_parameter(field, value, message):
    with pytest.raises(ValueError, match=re.escape(message)):
        KvhFogConfig(**{field: value})


def test_kvh_encoder_refuses_what_the_message_cannot_carry():
    with pytest.raises(ValueError, match='sequence'):
        encode_kvh_fog((0.0,) * 3, (0.0,) * 3, 0x77, 128, 0)
    with pytest.raises(ValueError, match='integer'):
        encode_kvh_fog((0.0,) * 3, (0.0,) * 3, 0x77, 0, 25.5)
    with pytest.raises(ValueError, match='signed 16-bit'):
        encode_kvh_fog((0.0,) * 3, (0.0,) * 3, 0x77, 0, 40000)


# --- rates from the measured interval ---------------------------------------------------------------------------------

def manual_message(message_format, rotation, acceleration, status, sequence, temperature=25, timestamp_us=0):
    """A message laid out byte by byte as the 1775 manual's tables 5-1..5-6 say, its CRC computed bit by bit.

    Header FE 81 FF 55/56/57; X, Y, Z rotation, X, Y, Z acceleration (big-endian IEEE-754 single);
    Format B: a big-endian uint32 of microseconds; status byte; sequence byte; A and B: a big-endian
    int16 temperature, C: a float (temperature at sequence 0 mod 4); CRC-32/MPEG-2, big-endian.
    """
    body = b''.join(struct.pack('>f', v) for v in (*rotation, *acceleration))
    if message_format == 'B':
        body += timestamp_us.to_bytes(4, 'big')
    if message_format == 'C':
        body += struct.pack('>f', temperature) + bytes([status, sequence])
    else:
        body += bytes([status, sequence]) + temperature.to_bytes(2, 'big', signed=True)
    message = bytes([0xFE, 0x81, 0xFF, {'A': 0x55, 'B': 0x56, 'C': 0x57}[message_format]]) + body
    return message + crc32_mpeg2_bitwise(message).to_bytes(4, 'big')


def unit_stream(message_format, unit_rate_hz, yaw_dps, seconds, clock_ppm=0.0):
    """(message, true send time s) of a factory-set unit (delta angles in rad) turning at yaw_dps about +z."""
    period = 1.0 / unit_rate_hz
    delta = math.radians(yaw_dps) * period
    for i in range(int(seconds * unit_rate_hz)):
        # The unit's clock runs clock_ppm fast: its timestamps, not the host, say how long an interval is.
        stamp = round(i * period * 1e6 * (1 + clock_ppm * 1e-6)) % 2 ** 32
        yield manual_message(message_format, (1e-7, -2e-7, delta * (1 + clock_ppm * 1e-6)), (0.01, -0.02, 1.0),
                             0x77, i % 128, 25, timestamp_us=stamp), i * period


def read_like_a_port(parser, stream, chunk_s=0.004, jitter_s=0.002, seed=0):
    """Feed the messages in reads every chunk_s, each returning late by up to jitter_s (a USB adapter)."""
    rng = random.Random(seed)
    out, chunk, due = [], b'', chunk_s
    for message, t in stream:
        while t > due:
            out += parser.feed(chunk, arrival_ns=int((due + rng.uniform(0, jitter_s)) * 1e9))
            chunk, due = b'', due + chunk_s
        chunk += message
    return [s for s, _ in out + parser.feed(chunk, arrival_ns=int((due + rng.uniform(0, jitter_s)) * 1e9))]


@pytest.mark.parametrize('message_format', ['A', 'C'])
@pytest.mark.parametrize('unit_rate_hz', [100, 500, 1000])
def test_kvh_delta_angles_by_the_streams_interval_with_output_rate_left_at_default(message_format, unit_rate_hz):
    """A unit at 100, 500 or 1000 Hz, the node told 1000 (the default): 30 deg/s is 30 deg/s, not 300 or 15."""
    parser = KvhFogParser(KvhFogConfig(message_format=message_format))
    assert parser.config.output_rate_hz == 1000.0
    samples = read_like_a_port(parser, unit_stream(message_format, unit_rate_hz, 30.0, 3.0))
    # The first second (and Format C's first temperature) is spent measuring: those are rejected, counted.
    assert parser.stats.rejected_by_reason[NO_INTERVAL] >= unit_rate_hz - 4
    assert len(samples) >= 1.8 * unit_rate_hz
    assert [s.raw_rate for s in samples] == pytest.approx([30.0] * len(samples), rel=3e-3)
    assert parser.measured_rate_hz == pytest.approx(unit_rate_hz, rel=1e-3)
    assert all(s.interval_s == pytest.approx(1.0 / unit_rate_hz, rel=3e-3) for s in samples)


@pytest.mark.parametrize('unit_rate_hz', [100, 500, 1000])
def test_kvh_format_b_rates_come_from_the_units_clock_with_its_drift(unit_rate_hz):
    """Format B: every interval by the unit's clock (here 200 ppm fast), from the second message on, arrival unused."""
    parser = KvhFogParser(KvhFogConfig(message_format='B'))
    data = b''.join(m for m, _ in unit_stream('B', unit_rate_hz, -45.0, 1.5, clock_ppm=200.0))
    samples = [s for s, _ in parser.feed(data)]
    assert parser.stats.rejected_by_reason[NO_INTERVAL] == 1 and len(samples) == int(1.5 * unit_rate_hz) - 1
    # The mean interval so far: a microsecond tick (0.1 % of 1 ms) at first, 1 us over the span after.
    assert [s.raw_rate for s in samples] == pytest.approx([-45.0] * len(samples), rel=1.1e-3)
    late = samples[unit_rate_hz // 10:]
    assert [s.raw_rate for s in late] == pytest.approx([-45.0] * len(late), rel=1e-5)
    assert parser.measured_rate_hz == pytest.approx(unit_rate_hz / (1 + 200e-6), rel=1e-6)
    unit_times = [s.unit_time_us for s in samples]
    assert unit_times[0] == round(1e6 / unit_rate_hz * (1 + 200e-6)) and unit_times == sorted(unit_times)


def test_kvh_format_b_clock_wraps_and_a_clock_fault_is_rejected_not_scaled():
    parser = KvhFogParser(KvhFogConfig(message_format='B'))
    base = 2 ** 32 - 1500
    stamps = [base, base + 1000, base + 2000, base + 3000, base + 2500, base + 3500, base + 4500]
    data = b''.join(manual_message('B', (0.0, 0.0, math.radians(0.001)), (0.0, 0.0, 1.0), 0x77, i, 25,
                                   timestamp_us=t % 2 ** 32) for i, t in enumerate(stamps))
    rates = [s.raw_rate for s, _ in parser.feed(data)]
    # Across the wrap: 1 ms each. The clock going back 500 us: rejected, and measured again from there.
    assert rates == pytest.approx([1.0] * 5, rel=1e-6)
    assert parser.stats.rejected_by_reason[BAD_TIMESTAMP] == 1
    assert parser.stats.rejected_by_reason[NO_INTERVAL] == 1


def test_kvh_lost_message_does_not_stretch_the_interval():
    """A delta angle covers one interval: with message 2 lost, message 3's is still 1 ms (the clock over 2 steps)."""
    parser = KvhFogParser(KvhFogConfig(message_format='B'))
    data = b''.join(manual_message('B', (0.0, 0.0, math.radians(0.001)), (0.0, 0.0, 1.0), 0x77, i, 25,
                                   timestamp_us=1000 * i) for i in (0, 1, 3))
    assert [s.raw_rate for s, _ in parser.feed(data)] == pytest.approx([1.0, 1.0])
    assert parser.stats.lost_frames == 1


@pytest.mark.parametrize('value', [True, False])
def test_kvh_yaw_axis_given_as_a_yaml_boolean_is_refused_with_the_hint_to_quote_it(value):
    with pytest.raises(ValueError, match=r'kvh_fog.yaw_axis .*boolean.*write \+y .*quote it'):
        KvhFogConfig(yaw_axis=value)


@pytest.mark.parametrize('yaw, forward, rows', [
    ('+z', '', ((1, 0, 0), (0, 1, 0), (0, 0, 1))),
    ('-z', '', ((1, 0, 0), (0, -1, 0), (0, 0, -1))),       # upside down: rolled 180 deg about x
    ('x', '', ((0, 1, 0), (0, 0, 1), (1, 0, 0))),
    ('+y', '-x', ((-1, 0, 0), (0, 0, 1), (0, 1, 0))),
])
def test_kvh_mounting_is_a_right_handed_rotation_from_the_unit_to_rep103(yaw, forward, rows):
    assert KvhFogConfig(yaw_axis=yaw, forward_axis=forward).mounting == rows


def test_kvh_forward_axis_must_be_another_axis_and_max_rate_is_what_the_baud_carries():
    with pytest.raises(ValueError, match='kvh_fog.forward_axis .* must be another axis than kvh_fog.yaw_axis'):
        KvhFogConfig(yaw_axis='-z', forward_axis='z')
    assert KvhFogConfig().max_rate_hz(921600) == 2560.0
    assert KvhFogConfig(message_format='B').max_rate_hz(921600) == pytest.approx(2304.0)


def test_kvh_bad_crc_is_one_rejected_frame_not_also_a_lost_one():
    """Messages 1 and 2 hit on the wire (bad CRC), 4 never sent: 2 rejected, 1 lost; garbage runs apart.

    Every message the unit numbered (0..6) is a frame, a rejection or lost: garbage adds none.
    """
    hit = [bytearray(kvh_message(s)) for s in (1, 2)]
    for message in hit:
        message[10] ^= 0x01
    parser = KvhFogParser(RATES)
    got = parser.feed(b'\x07' * 5 + kvh_message(0) + b'\x00\x01' + bytes(hit[0]) + bytes(hit[1]) + kvh_message(3)
                      + b'\xfe\x81\xff' + kvh_message(5) + b'\xfe\x81' + kvh_message(6))
    assert len(got) == 4
    assert parser.stats.rejected_by_reason[BAD_CRC] == 2 and parser.stats.lost_frames == 1
    assert parser.stats.frames + parser.stats.rejected + parser.stats.lost_frames == 7
    assert parser.stats.garbage_runs == 4


# --- stamps from Format B's clock -------------------------------------------------------------------------------------

def test_unit_clock_source_needs_format_b():
    with pytest.raises(ValueError, match='kvh_fog.timestamp_source unit_clock needs kvh_fog.message_format B'):
        KvhFogConfig(timestamp_source='unit_clock')
    with pytest.raises(ValueError, match='kvh_fog.timestamp_source must be one of arrival, unit_clock'):
        KvhFogConfig(timestamp_source='device')
