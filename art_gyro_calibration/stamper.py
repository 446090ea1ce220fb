"""Stamps of serial frames from the reads that returned them: the wire time taken off, the gyro's period kept.

Frame times are kept on the monotonic clock (the arrival of the chunk less its time on the
wire, frames of one chunk spaced by the gyro's own period, estimated from the stream) and put
on the caller's clock (wall or ROS time) by its offset from the monotonic clock. A step of that
clock (set by hand, NTP, a simulation reset) re-anchors the stamps to it once, instead of
freezing them or spreading it. Pure: no I/O.
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Sequence

from art_gyro_calibration.frame import BITS_PER_BYTE

# A change of the clock's offset from the monotonic clock between two reads beyond this is a step
# (NTP slews at most 0.5 ms/s). A simulated /clock published at 100 Hz reaches the node's clock
# late, by up to a few hundred ms when its executor is busy: within
# this it is jitter, which stamps never follow backwards.
CLOCK_STEP_NS = 1_000_000_000
# A stamp held from going back is this much after the last, if the read's frames fit so before it returned: a CSV
# log keeps microseconds, and a float of seconds since 1970 (a bag's reader, a ROS consumer's) resolves 2.4e-7 s;
# stamps a nanosecond apart were one there. A backlog read faster than that shares what fits.
STAMP_STEP_NS = 1_000
# A read of the caller's clock that took longer than this and 4 times the quickest was preempted between the
# monotonic clock's reads around it: the offset it gives is off by up to its duration, and the one before is kept.
CLOCK_READ_NS = 20_000
# A measured interval per frame this far from the period estimate is a lost frame or a reopen, not the period.
PERIOD_ACCEPT = (0.6, 1.6)
PERIOD_SMOOTHING = 16   # the estimate averages about this many chunks
# A unit's clock (kvh_fog Format B) is mapped once the mapping spans this long.
UNIT_CLOCK_BASELINE_S = 1.0
# The mapping is the line under the least delayed arrivals of this long: the drift a temperature change brings is
# followed, and a delay that grows for good after this long.
UNIT_CLOCK_WINDOW_S = 20.0
UNIT_CLOCK_BUCKET_S = 0.25   # the least delayed arrival is kept per this long
# The mapping is slewed, never stepped, at most this fast (s/s): stamps stay the unit's period apart within 0.1 %.
UNIT_CLOCK_SLEW = 1e-3


def wire_byte_ns(baud: int) -> int:
    """The wire time of a byte at ``baud``, in whole nanoseconds."""
    return BITS_PER_BYTE * 1_000_000_000 // baud


class WireStamper:
    """Stamps of the frames of each read chunk: wire time subtracted, spaced by the gyro's period, on a clock.

    Times are kept on the monotonic clock and moved onto the caller's clock by its current
    offset; the period is the mean, over about PERIOD_SMOOTHING chunks, of the time between the
    last frames of consecutive chunks divided by the frames in the later one, which stays right
    when frames queued during a stall arrive in one burst.

    :meth:`stamp` takes these steps, each a method with one reason:

    1. :meth:`_clock_offset`: the caller's clock against the monotonic one (a preempted read of it
       skipped); a step of it is taken once two reads agree on it.
    2. :meth:`_last_departure`: when the chunk's last frame left the gyro (its arrival less the wire
       time of it and of the bytes after it).
    3. :meth:`_spread`: the chunk's earlier frames before it, a period apart at least (frames queued
       by a stall left the gyro a period apart, not a wire time apart), a period more for each frame the
       parser refused between two.
    4. :meth:`_floor`: none before the previous chunk's last frame and its wire time.
    5. :meth:`_ceiling`: none after it arrived (bytes faster than the baud allows), less its wire
       time at the byte rate measured.
    6. :meth:`_hand_out`: on the caller's clock, never back; the steady time never back either.
    """

    __slots__ = ('byte_ns', 'frame_ns', 'period_ns', '_updates', '_last_steady', '_last_stamp', '_last_out',
                 '_offset_ns', '_pending_ns', '_quickest_read_ns', 'steps_ns', 'step_ns', '_frame_bytes', '_bytes',
                 '_first_ns', 'baud', 'too_fast', 'ahead')

    def __init__(self, baud: int, frame_bytes: int) -> None:
        self.byte_ns = wire_byte_ns(baud)
        self.frame_ns = frame_bytes * self.byte_ns
        self.period_ns = 0.0            # 0: not known yet
        self._updates = 0
        self._last_steady: int | None = None   # monotonic time of the last frame stamped
        self._last_stamp = 0
        self._last_out = 0                     # the last steady time handed out
        self._offset_ns: int | None = None     # caller's clock minus the monotonic clock
        self._pending_ns: int | None = None    # an offset one read saw beyond a step, not yet confirmed
        self._quickest_read_ns = math.inf   # the quickest read of the caller's clock
        self.steps_ns = 0               # sum of the clock steps re-anchored to
        self.step_ns = 0                # the step found by the latest chunk, 0 if none
        self.baud = baud
        self._frame_bytes = frame_bytes
        self._bytes = 0                 # bytes read, and when the first chunk's read returned: the byte rate
        self._first_ns: int | None = None
        self.too_fast = ''              # set once, when frames first came faster than the baud allows: why
        self.ahead = 0                  # frames that would have been stamped after they arrived (fell back)

    def restart(self) -> None:
        """After a reopen: the next chunk does not measure the period (the link was down meanwhile)."""
        self._last_steady = None

    @property
    def offset_ns(self) -> int:
        """The caller's clock less the monotonic clock, as the latest chunk was stamped with."""
        return self._offset_ns or 0

    def stamp(self, clock_ns: int, monotonic_ns: int, chunk_bytes: int, ends: list[int],
              clock_read_ns: int = 0, missed: Sequence[int] = ()) -> list[tuple[int, int]]:
        """(stamp, steady) of the frames ending at ``ends`` of a chunk whose read returned at the given times.

        The caller's clock was read between ``monotonic_ns - clock_read_ns`` and ``monotonic_ns``. ``missed``: for
        each frame, the gyro's frames the parser refused or lost just before it (``FrameParser.frames_missed``;
        none if not given), which left the gyro a period each.
        """
        offset = self._clock_offset(clock_ns - monotonic_ns + clock_read_ns // 2, clock_read_ns)
        if not ends:
            return []
        if missed and len(missed) != len(ends):
            raise ValueError(f'{len(missed)} counts of frames missed for {len(ends)} frames')
        previous = self._last_steady
        slots = [1 + m for m in missed] if missed else [1] * len(ends)   # periods from the frame before each
        steady = self._spread(self._last_departure(monotonic_ns, chunk_bytes, ends[-1]), previous, ends, slots)
        if previous is not None:
            self._floor(steady, previous)
        self._ceiling(steady, monotonic_ns, chunk_bytes, ends)
        self._last_steady = steady[-1]
        return self._hand_out(steady, offset, monotonic_ns + offset)

    def _clock_offset(self, offset: int, read_ns: int) -> int:
        """The offset to stamp this chunk with: ``offset`` read now (in ``read_ns``), or the one before.

        The one before while a step is unconfirmed, or when the read was preempted.
        """
        self.step_ns = 0
        self._quickest_read_ns = min(self._quickest_read_ns, read_ns)
        if self._offset_ns is not None and read_ns > max(CLOCK_READ_NS, 4 * self._quickest_read_ns):
            return self._offset_ns
        if self._offset_ns is not None and abs(offset - self._offset_ns) > CLOCK_STEP_NS:
            # A step is taken when a second read agrees on it: one read of a clock that goes back and
            # forth (a simulated /clock whose messages two executor threads apply out of order) is none.
            if self._pending_ns is not None and abs(offset - self._pending_ns) <= CLOCK_STEP_NS:
                self.step_ns = offset - self._offset_ns
                self.steps_ns += self.step_ns
                self._pending_ns = None
            else:
                self._pending_ns, offset = offset, self._offset_ns   # this chunk stays on the clock as it was
        else:
            self._pending_ns = None
        self._offset_ns = offset
        return offset

    def _last_departure(self, monotonic_ns: int, chunk_bytes: int, last_end: int) -> int:
        """When the chunk's last frame (ending at ``last_end``) left the gyro, on the monotonic clock."""
        # The read returned when the chunk's last byte arrived: the last frame's first byte left
        # the gyro its own and every later byte's wire time earlier.
        return monotonic_ns - (chunk_bytes - last_end) * self.byte_ns - self.frame_ns

    def _spread(self, last: int, previous: int | None, ends: list[int], slots: list[int]) -> list[int]:
        """The chunk's frames, the last at ``last``, each earlier one its wire spacing or its periods before the next.

        ``slots``: the gyro's periods from the frame before each (one, and one more per frame missed between).
        The period is measured here (from the previous chunk's last frame), and the step between two
        frames is never more than that measure, so the first never goes before the previous chunk's last.
        """
        n = len(ends)
        step = self.period_ns
        if previous is not None and last > previous:
            per_frame = (last - previous) / sum(slots)
            self._update_period(per_frame)
            step = min(self.period_ns, per_frame)
        # Frames queued by a stall (or before an open) left the gyro a period apart, not a wire time apart; a frame
        # after frames the parser refused, a period more for each.
        spacing = [max(float((ends[i + 1] - ends[i]) * self.byte_ns), step * slots[i + 1]) for i in range(n - 1)]
        steady = [last] * n
        for i in range(n - 2, -1, -1):
            steady[i] = steady[i + 1] - int(spacing[i])
        return steady

    def _floor(self, steady: list[int], previous: int) -> None:
        """Frames at least their wire time after the previous chunk's last (``previous``) and after each other."""
        floor = previous + self.frame_ns
        for i in range(len(steady)):
            if steady[i] < floor:
                steady[i] = floor
            floor = steady[i] + self.frame_ns

    def _ceiling(self, steady: list[int], monotonic_ns: int, chunk_bytes: int, ends: list[int]) -> None:
        """Never after a frame arrived, less its wire time at the byte rate measured (at most the baud's).

        Bytes faster than the baud allows (a pty, USB-CDC, a wrong baud) pushed each frame a wire
        time after the last, without bound; such frames are counted (``ahead``) and said once (``too_fast``).
        """
        measured = self._byte_ns(monotonic_ns, chunk_bytes)
        byte_ns = min(float(self.byte_ns), measured)
        for i in range(len(steady)):
            ceiling = monotonic_ns - int((chunk_bytes - ends[i] + self._frame_bytes) * byte_ns)
            if steady[i] > ceiling:
                steady[i] = ceiling
                self.ahead += 1
                if not self.too_fast and measured < self.byte_ns:   # not a late read alone: bytes beyond the baud
                    self.too_fast = (f'frames arrive faster than {self.baud} baud allows ({1e9 / byte_ns:.0f} '
                                     f'bytes/s measured, {self.baud // BITS_PER_BYTE} at most): stamped at arrival '
                                     'less their wire time at the measured rate; check the baud parameter')

    def _hand_out(self, steady: list[int], offset: int, read_at: int) -> list[tuple[int, int]]:
        """(stamp, steady) on the caller's clock by ``offset``: neither goes back (but a stamp at a clock step).

        ``read_at``: when the read returned, on the caller's clock.
        """
        out = []
        for i, t in enumerate(steady):
            stamp = t + offset
            if not self.step_ns and stamp < self._last_stamp + STAMP_STEP_NS:   # jitter of a coarse clock: never back
                stamp = held_after(self._last_stamp, read_at, len(steady) - i)
            self._last_stamp = stamp
            # The steady time never goes back either, a step's chunk included: the stamps before it may have
            # been held up by a stale clock read (a /clock 50 ms late, then a step: the raw log went 20 ms back).
            clean = max(stamp - self.steps_ns, self._last_out + 1)
            self._last_out = clean
            out.append((stamp, clean))
        return out

    def _byte_ns(self, monotonic_ns: int, chunk_bytes: int) -> float:
        """Mean time per byte received since the first read (idle time included: an upper bound)."""
        if self._first_ns is None:
            self._first_ns = monotonic_ns
            return math.inf
        self._bytes += chunk_bytes
        return (monotonic_ns - self._first_ns) / self._bytes

    def _update_period(self, per_frame: float) -> None:
        period = self.period_ns
        # Outliers are refused only once the estimate has settled: a wrong first measure (queued frames read in
        # two chunks a wire time apart) would otherwise refuse every right one after it, for good.
        if self._updates >= PERIOD_SMOOTHING and not PERIOD_ACCEPT[0] < per_frame / period < PERIOD_ACCEPT[1]:
            return
        self._updates += 1
        self.period_ns = period + (per_frame - period) / min(self._updates, PERIOD_SMOOTHING)


def held_after(last_ns: int, read_at_ns: int, frames: int) -> int:
    """A stamp held from going back, the first of ``frames`` left in a read that returned at ``read_at_ns``.

    STAMP_STEP_NS after ``last_ns``, or less so that all fit by ``read_at_ns`` (a nanosecond at least).
    """
    return last_ns + max(1, min(STAMP_STEP_NS, (read_at_ns - last_ns) // frames))


class UnitClock:
    """Format B's microsecond clock mapped onto the host's monotonic clock: drift and offset tracked.

    A stamp is when the message left the unit, not when a busy host read it: the mapping is the line
    under every (unit time, arrival) of the last UNIT_CLOCK_WINDOW_S that lies closest to them on
    the whole (an edge of their lower hull: the least delayed arrivals, by linear programming as
    Moon, Skelly and Towsley, "Estimation and removal of clock skew from network delay
    measurements", INFOCOM 1999). A least-squares line would follow the mean delay, which the
    host's load moves. The hull is of the least delayed arrival of each UNIT_CLOCK_BUCKET_S. Ready
    once it has spanned UNIT_CLOCK_BASELINE_S; :meth:`reset` when the clock is broken (a reopen, a
    clock fault), after which the driver stamps by arrival again.
    """

    __slots__ = ('_n0', '_t0', '_first_ns', '_last_ns', '_lows', '_bucket', '_bucket_end_ns', '_line', '_mapped')

    def __init__(self) -> None:
        self.reset()

    def reset(self) -> None:
        """Forget the mapping."""
        self._n0 = self._t0 = 0
        self._first_ns = self._last_ns = 0
        # (unit time, arrival) since the first, in us and ns: the least delayed of each past bucket, of the current.
        self._lows: deque[tuple[float, float]] = deque(maxlen=round(UNIT_CLOCK_WINDOW_S / UNIT_CLOCK_BUCKET_S))
        self._bucket: tuple[float, float] | None = None
        self._bucket_end_ns: int | None = None
        self._line: tuple[float, float, float] | None = None   # (unit time, arrival) on it, and its slope
        self._mapped: tuple[int, float] | None = None   # the last (unit time, mapped time) given

    @property
    def ready(self) -> bool:
        """The mapping spans UNIT_CLOCK_BASELINE_S."""
        return self._line is not None and self._last_ns - self._first_ns >= UNIT_CLOCK_BASELINE_S * 1e9

    def add(self, unit_us: int, arrival_ns: int) -> None:
        """A message of unit time ``unit_us`` (unwrapped) arrived at ``arrival_ns`` (monotonic, wire time less)."""
        if self._bucket_end_ns is None:
            self._n0, self._t0, self._first_ns = unit_us, arrival_ns, arrival_ns
            self._bucket_end_ns = arrival_ns
        self._last_ns = arrival_ns
        n, t = float(unit_us - self._n0), float(arrival_ns - self._t0)
        bucket = self._bucket
        slope = self._line[2] if self._line is not None else 1e3
        if bucket is None or t - bucket[1] < slope * (n - bucket[0]):   # less delayed than the bucket's least
            bucket = self._bucket = (n, t)
        if arrival_ns >= self._bucket_end_ns:
            self._lows.append(bucket)
            self._bucket = None
            self._bucket_end_ns = arrival_ns + int(UNIT_CLOCK_BUCKET_S * 1e9)
            self._line = _support_line(self._lows) or self._line

    @property
    def ns_per_us(self) -> float:
        """Host nanoseconds per unit microsecond (1000 less the unit clock's drift)."""
        return self._line[2] if self._line is not None else math.nan

    def map(self, unit_us: int) -> int:
        """The monotonic time at which the message of unit time ``unit_us`` left the unit (call when ready).

        The line moves as arrivals come: the mapping follows it by at most UNIT_CLOCK_SLEW from the
        last time it gave, so stamps never jump; never after the latest arrival, and the messages after
        one held there go on from it.
        """
        assert self._line is not None
        n = float(unit_us - self._n0)
        n_on, t_on, slope = self._line
        target = t_on + slope * (n - n_on)
        if self._bucket is not None:
            target = min(target, self._bucket[1] + slope * (n - self._bucket[0]))
        if self._mapped is not None and unit_us > self._mapped[0]:
            elapsed_us = unit_us - self._mapped[0]
            predicted = self._mapped[1] + elapsed_us * slope
            step = UNIT_CLOCK_SLEW * elapsed_us * 1e3
            target = predicted + min(step, max(-step, target - predicted))
        target = min(target, float(self._last_ns - self._t0))   # the latest arrival
        self._mapped = (unit_us, target)
        return self._t0 + int(target)


def _support_line(points: deque[tuple[float, float]]) -> tuple[float, float, float] | None:
    """The edge of the points' lower hull over their mean abscissa: under them all, closest to them on the whole.

    ``points`` go by abscissa; (a point on the line, its slope), or None while there are fewer than two.
    """
    hull: list[tuple[float, float]] = []
    for p in points:   # Andrew's monotone chain, lower half
        while len(hull) >= 2 and ((hull[-1][0] - hull[-2][0]) * (p[1] - hull[-2][1])
                                  - (hull[-1][1] - hull[-2][1]) * (p[0] - hull[-2][0])) <= 0.0:
            hull.pop()
        hull.append(p)
    if len(hull) < 2:
        return None
    middle = sum(p[0] for p in points) / len(points)
    for a, b in zip(hull, hull[1:]):
        if b[0] >= middle:
            break
    return a[0], a[1], (b[1] - a[1]) / (b[0] - a[0])
