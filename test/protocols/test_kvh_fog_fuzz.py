"""Property tests of the kvh_fog parser on arbitrary bytes, in arbitrary chunks.

Messages with any sequence number and status (so gaps, repeats and invalid flags all occur), messages
with a bit flipped, cut short, of another format, and noise, cut into any chunks: the parser gives
exactly what a slow reading of the manual's byte tables gives (header, CRC, status, sequence,
temperature); a flipped bit is never accepted; a message between arbitrary bytes is always found.
"""

import math
import struct

from hypothesis import given, strategies as st

from test_kvh_fog import crc32_mpeg2_bitwise
from test_rd2100_binary_fuzz import chunks

from art_gyro_calibration.frame import INT16_MAX, INT16_MIN
from art_gyro_calibration.protocols.kvh_fog import (KVH_HEADER_PREFIX, KvhFogConfig, KvhFogParser, crc32_mpeg2,
                                                    encode_kvh_fog)


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
