"""kvh_fog sequence and clock faults told apart by the clocks that disagree."""

import pytest
from test_kvh_fog import read_like_a_port

from art_gyro_calibration.protocols.kvh_fog import BAD_TIMESTAMP, KvhFogConfig, KvhFogEncoder, KvhFogParser


def stream(config, rate_hz, seconds, lost=range(0)):
    """(message, true send time s) of a unit at rate_hz turning at 30 deg/s, the messages numbered in ``lost`` lost."""
    encoder = KvhFogEncoder(KvhFogConfig(message_format=config.message_format, output_rate_hz=rate_hz))
    for i in range(int(seconds * rate_hz)):
        message = encoder(30.0, 25.0)
        if i not in lost:
            yield message, i / rate_hz


def test_format_b_gap_of_a_whole_wrap_is_counted_by_the_units_clock():
    """128 messages lost: the sequence says 0 or 1 steps, the unit's clock says 128 or 129 intervals."""
    config = KvhFogConfig(message_format='B')
    for lost in (range(2000, 2128), range(2000, 2129), range(2000, 2385)):
        parser = KvhFogParser(config)
        samples = read_like_a_port(parser, stream(config, 1000.0, 4.0, lost))
        rates = [s.raw_rate for s in samples]
        assert rates == pytest.approx([30.0] * len(rates), rel=1e-3), (lost, min(rates))
        assert parser.stats.lost_frames == len(lost)


@pytest.mark.parametrize('rate_hz', [1000.0, 200.0])
@pytest.mark.parametrize('at', [100, 2000])
@pytest.mark.parametrize('wraps', [1, 2])
def test_format_b_whole_wraps_lost_while_arrivals_pause_are_lost_not_a_leap(rate_hz, at, wraps):
    """128 or 256 messages really lost (arrivals pause as long): counted, whether read promptly or late."""
    config = KvhFogConfig(message_format='B', output_rate_hz=rate_hz)
    lost = range(at, at + 128 * wraps)
    for chunk_s, jitter_s in ((0.004, 0.002), (0.016, 0.016)):
        parser = KvhFogParser(config)
        samples = read_like_a_port(parser, stream(config, rate_hz, 4000 / rate_hz, lost), chunk_s, jitter_s)
        assert parser.stats.lost_frames == len(lost), (chunk_s, parser.stats.rejected_by_reason)
        assert parser.stats.rejected_by_reason[BAD_TIMESTAMP] == 0 and len(samples) == 4000 - len(lost) - 1
    parser = KvhFogParser(config)   # no arrival times to contradict it: the unit's clock says
    parser.feed(b''.join(m for m, _ in stream(config, rate_hz, 4000 / rate_hz, lost)))
    assert parser.stats.lost_frames == len(lost)


@pytest.mark.parametrize('message_format', ['A', 'C'])
@pytest.mark.parametrize('lost', [range(2500, 2630), range(2500, 2756), range(700, 830)])
def test_stream_gap_of_a_whole_wrap_is_counted_by_arrival_time(message_format, lost):
    """130 messages lost look like 2 by the sequence: arrival time says 130, so the interval fit stays right."""
    config = KvhFogConfig(message_format=message_format)
    parser = KvhFogParser(config)
    samples = read_like_a_port(parser, stream(config, 1000.0, 8.0, lost))
    off = [s.raw_rate for s in samples if abs(s.raw_rate / 30.0 - 1.0) > 3e-3]
    assert not off, (len(off), min(off), max(off))
    assert parser.stats.lost_frames == len(lost)
    assert parser.measured_rate_hz == pytest.approx(1000.0, rel=1e-3)


@pytest.mark.parametrize('message_format', ['A', 'C'])
@pytest.mark.parametrize('lost', [range(200, 330), range(100, 228)])
def test_a_gap_in_the_first_half_second_is_counted_by_the_configured_interval(message_format, lost):
    """Before the stream's interval is measured, the configured one tells the wraps a gap of 128 or more hides.

    Before: 2 (130 lost) and 0 (128 lost) counted, and every rate after it off by 1 to 10 % (2,991 of 3,000).
    """
    config = KvhFogConfig(message_format=message_format)
    parser = KvhFogParser(config)
    samples = read_like_a_port(parser, stream(config, 1000.0, 4.0, lost))
    assert parser.stats.lost_frames == len(lost)
    assert [s.raw_rate for s in samples] == pytest.approx([30.0] * len(samples), rel=3e-3)


@pytest.mark.parametrize('message_format', ['A', 'C'])
@pytest.mark.parametrize('at', [200, 2500])
def test_127_messages_lost_are_127_not_a_repeated_sequence(message_format, at):
    """The message after 127 lost repeats the last one's sequence number: arrival time says 128 intervals passed.

    Before: it was rejected as repeated_sequence and the gap counted 128 (0 in the first half second).
    """
    config = KvhFogConfig(message_format=message_format)
    parser = KvhFogParser(config)
    samples = read_like_a_port(parser, stream(config, 1000.0, 4.0, range(at, at + 127)))
    assert parser.stats.lost_frames == 127 and parser.stats.rejected_by_reason['repeated_sequence'] == 0
    assert [s.raw_rate for s in samples] == pytest.approx([30.0] * len(samples), rel=3e-3)


@pytest.mark.parametrize('stall_s', [0.128, 0.3, 1.0])
def test_a_stalled_read_is_not_a_gap(stall_s):
    """The host reads nothing for stall_s, then everything queued at once: no message lost, none counted."""
    config = KvhFogConfig()
    parser = KvhFogParser(config)
    messages = list(stream(config, 1000.0, 6.0))
    samples = read_like_a_port(parser, ((m, 3.0 + stall_s if 3.0 <= t < 3.0 + stall_s else t) for m, t in messages))
    assert parser.stats.lost_frames == 0
    assert [s.raw_rate for s in samples] == pytest.approx([30.0] * len(samples), rel=3e-3)


@pytest.mark.parametrize('message_format', ['A', 'C'])
@pytest.mark.parametrize('unit_rate_hz', [1009.0, 995.0, 1000.0])
def test_configured_rate_is_used_only_where_the_measure_cannot_tell_it_apart(message_format, unit_rate_hz):
    """A unit at 1009 Hz told 1000 is measured, not "confirmed": its rates are right, not 0.9 % low."""
    config = KvhFogConfig(message_format=message_format)
    parser = KvhFogParser(config)
    samples = read_like_a_port(parser, stream(config, unit_rate_hz, 4.0))
    late = samples[len(samples) // 2:]
    assert [s.raw_rate for s in late] == pytest.approx([30.0] * len(late), rel=5e-4)
    if unit_rate_hz == 1000.0:   # the unit's own period, not the measure's jitter
        assert {s.interval_s for s in late} == {1e-3}


def leapt_stream(leap_us, at=2000, glitch=False, seconds=4.0):
    """Format B at 1 kHz turning at 30 deg/s whose clock leaps by leap_us at message ``at`` (for it alone: a glitch)."""
    encoder = KvhFogEncoder(KvhFogConfig(message_format='B'))
    for i in range(int(seconds * 1000)):
        if i == at:
            encoder.unit_time_us += leap_us
        message = encoder(30.0, 25.0)
        if i == at and glitch:
            encoder.unit_time_us -= leap_us
        yield message, i / 1000


@pytest.mark.parametrize('glitch', [False, True])
@pytest.mark.parametrize('leap_us', [300_000, 2_000, 20, -300, 1_400_000, 128_000, 256_000, 127_500])
def test_format_b_clock_leap_the_sequence_contradicts_is_rejected_and_the_clock_followed(leap_us, glitch):
    """A leap under MAX_INTERVAL_US (or one glitched stamp): one message rejected, no rate off, unit time continuous.

    A leap of whole sequence wraps (128 or 256 intervals) is one too: arrivals went on at the interval, so no
    message was lost. Before: counted as 128 (256) lost, the message published and unit time 128 ms ahead.
    """
    parser = KvhFogParser(KvhFogConfig(message_format='B'))
    samples = read_like_a_port(parser, leapt_stream(leap_us, glitch=glitch))
    rates = [s.raw_rate for s in samples]
    assert rates == pytest.approx([30.0] * len(rates), rel=1e-3), (min(rates), max(rates))
    assert parser.stats.lost_frames == 0
    assert parser.stats.rejected_by_reason[BAD_TIMESTAMP] == 1
    assert parser.stats.clock_faults == (0 if glitch else 1)   # a leap: the driver maps the clock anew
    assert len(samples) == 4000 - 2
    steps = {round((b.unit_time_us - a.unit_time_us) * 1e-3) for a, b in zip(samples, samples[1:])}
    assert steps == {1, 2}, steps   # the rejected message is a step of two, never the leap


@pytest.mark.parametrize('rate_hz', [5000.0, 1000.0])
def test_a_late_reading_adapter_is_not_a_gap(rate_hz):
    """Reads every 16 ms, each up to 16 ms late (a USB adapter's latency timer): 128 messages are 25.6 ms at 5 kHz."""
    config = KvhFogConfig(output_rate_hz=rate_hz)
    for seed in range(3):
        parser = KvhFogParser(config)
        read_like_a_port(parser, stream(config, rate_hz, 4.0), chunk_s=0.016, jitter_s=0.016, seed=seed)
        assert parser.stats.lost_frames == 0
