r"""Property tests of the RD2100 ASCII parser on arbitrary bytes, in arbitrary chunks.

Arbitrary bytes before a line are part of that line unless they end with a line break, so the
property is: a valid line preceded by arbitrary bytes ending in ``\n`` (or by nothing) and followed
by anything is found; and whatever the bytes, the parser never raises and its buffer stays bounded.
"""

from hypothesis import given, strategies as st

from test_rd2100_binary_fuzz import chunks, int16

from art_gyro_calibration.frame import INT16_MAX, INT16_MIN
from art_gyro_calibration.protocols.rd2100_ascii import MAX_LINE_BYTES, AsciiFrameParser, encode_ascii


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
