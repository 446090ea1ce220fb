"""Tests of the RD2100 ASCII lines: line breaks, malformed and out-of-range lines, bounded buffer, reset."""

from test_protocols import samples

from art_gyro_calibration.frame import UNLOCKED, RawSample
from art_gyro_calibration.protocols.rd2100_ascii import (LINE_TOO_LONG, MALFORMED, MAX_LINE_BYTES, OUT_OF_RANGE,
                                                         AsciiFrameParser)


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


def test_a_locked_ascii_parser_accepts_a_line_only_after_lock_frames_in_a_row():
    """A line of digits among noise is no gyro: three valid lines in a row lock the stream."""
    parser = AsciiFrameParser(lock_frames=3)
    assert parser.feed(b'1 2\nxx\n3 4\n\x07\n') == []
    assert parser.stats.rejected_by_reason[UNLOCKED] == 2 and parser.stats.rejected_by_reason[MALFORMED] == 2
    assert samples(parser.feed(b'5 6\n7 8\r\n\r\n9 10\n')) == [(9, 10)]   # a blank line keeps the lock
    assert samples(parser.feed(b'99999 1\n1 1\n2 2\n3 3\n')) == [(3, 3)]   # out of range loses it
    assert parser.stats.rejected_by_reason[OUT_OF_RANGE] == 1
