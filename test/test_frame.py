"""``frame``: the one interface every protocol's parser offers, its shared lock and counters, and the seam.

The driver, the node and the diagnostics read every protocol through :class:`~art_gyro_calibration.frame.FrameParser`
and :class:`~art_gyro_calibration.frame.ProtocolDescription` only.
"""

import ast
from pathlib import Path

import pytest

from art_gyro_calibration.frame import (INT16_MAX, INT16_MIN, LOCK_FRAMES, UNLOCKED, ChunkParser, ParserStats,
                                        ProtocolDescription, check_int16)
from art_gyro_calibration.protocols import PROTOCOLS, describe, make_encoder, make_parser
from art_gyro_calibration.protocols.kvh_fog import KvhFogConfig


def test_the_driver_node_and_diagnostics_see_protocols_only_through_the_seam():
    """They import no protocol module (only the registry) and name no protocol: a new one needs no change there."""
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
        assert description == ProtocolDescription(corrupt_rate_steps=description.corrupt_rate_steps,
                                                  continuous_temperature=True)
        assert description.checks_rate_jumps and description.corrupt_rate_steps
        assert description.hardware == 'KVH RD2100' and description.rate_error(10.0) == ''


@pytest.mark.parametrize('protocol', PROTOCOLS)
def test_a_checksummed_protocol_accepts_a_frame_only_once_the_stream_is_locked(protocol):
    """RD2100: the first LOCK_FRAMES - 1 contiguous valid frames are counted UNLOCKED and skipped.

    kvh_fog's CRC-32 needs no lock: its parser takes every valid message from the first.
    """
    config = KvhFogConfig(rotation='rate')
    encode = make_encoder(protocol, config)
    frames = [encode(7 + k, 500) for k in range(LOCK_FRAMES + 2)]
    parser = make_parser(protocol, config, lock_frames=LOCK_FRAMES, byte_ns=86_805)
    got = parser.feed(b''.join(frames), 1_000_000_000)
    unlocked = 0 if protocol == 'kvh_fog' else LOCK_FRAMES - 1
    assert [round(s.raw_rate) for s, _ in got] == [7 + k for k in range(unlocked, LOCK_FRAMES + 2)]
    assert got[-1][1] == sum(map(len, frames))
    assert parser.stats.frames == len(frames) - unlocked
    assert parser.stats.rejected_by_reason.get(UNLOCKED, 0) == unlocked
    assert parser.stats.bytes_skipped == sum(map(len, frames[:unlocked]))


@pytest.mark.parametrize('lock_frames', [0, -1, 1.5, '3'])
def test_a_lock_that_is_not_a_positive_integer_is_refused(lock_frames):
    with pytest.raises(ValueError, match=f'lock_frames must be a positive integer, got {lock_frames!r}'):
        ChunkParser(('garbage',), lock_frames)


def test_only_a_locking_parser_counts_unlocked_frames():
    assert list(ChunkParser(('bad',)).stats.rejected_by_reason) == ['bad']
    assert ChunkParser(('bad',), 2).stats.rejected_by_reason == {'bad': 0, UNLOCKED: 0}


def test_rejected_is_the_sum_over_every_reason():
    assert ParserStats(rejected_by_reason={'a': 2, 'b': 0, 'c': 5}).rejected == 7
    assert ParserStats().rejected == 0


def test_check_int16_takes_the_bounds_and_refuses_beyond_them_naming_the_field():
    check_int16('raw_rate', INT16_MIN)
    check_int16('raw_rate', INT16_MAX)
    for value in (INT16_MIN - 1, INT16_MAX + 1):
        with pytest.raises(ValueError, match=f'raw_temp must be a signed 16-bit count .*got {value}'):
            check_int16('raw_temp', value)


def test_the_default_description_is_the_rd2100s_and_never_reports_a_rate_error():
    description = ProtocolDescription()
    assert description.hardware == 'KVH RD2100' and description.checks_rate_jumps
    assert not (description.stamps_by_unit_clock or description.reports_rate or description.imu_axes)
    assert description.rate_error(None) == '' and description.rate_error(1e6) == ''
