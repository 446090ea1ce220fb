"""The frame guard: refuses a frame that passed a weak check (the RD2100's 8-bit checksum, or none) but is corrupt.

A corrupt frame is told from real motion by two things the motion cannot do (doc/benchmark.md measures both):

- its temperature jumps (``continuous_temperature``): a unit's temperature moves a fraction of a count between
  frames, so a frame whose temperature is TEMPERATURE_JUMP_COUNTS or more from the last delivered one's is refused,
  unless the frame before was refused with about the same temperature (a new level that persists is trusted from
  its second frame);
- its rate departs from what the motion's own recent frames predict by one of the changes the protocol's
  corruptions make (``ProtocolDescription.corrupt_rate_steps``: a checksum-passing two-bit error changes the
  rate by +-2^a or +-255 * 2^a counts; a digit replaced, by k * 10^j), to within the prediction's envelope.
  A departure of any other size is motion (a bump, a turn's onset): delivered, and the envelope widens with it.

The prediction follows vibration whatever its frequency: a sinusoid with an offset obeys
``x[n] = x[n-3] + g * (x[n-1] - x[n-2])`` with ``g = 1 + 2 cos(w)`` (a ramp: g = 3), and g is fitted on the
recent frames. Frames the parser refused (it says how many: ``FrameParser.frames_missed``, which a backlog read in
one chunk needs) or that never came (a gap in the stamps) are filled with the prediction (guesses: a frame predicted
from them is tested with a wider tolerance, and neither refits g nor widens the envelope); after a refusal it
starts again from the next frames (a motion wrongly refused is not followed by a guess). By default there is no
latency: each frame is decided as it comes. With ``look_ahead`` a frame whose departure is a smaller corruption's
step is decided by the next frame (a one-frame spike that returns is refused), at a frame of latency.

What no test here can refuse (doc/benchmark.md counts them): a two-bit error of the checksum and a low rate bit is
the valid frame of a rate 1 to 16 counts off, within the noise.
"""

from __future__ import annotations

import bisect
import math

# Why each value (bench/bench_guards.py, binary then ascii; doc/benchmark.md has the runs):
# A real temperature moves a fraction of a count (0.05 degC) between frames (a unit warming 5 degC a minute: a
# sixth of a count a frame at 10 Hz), a count at a quantisation edge; 2 or more in a frame is corrupt (a count more
# for each frame lost or refused since). 3 instead: 5 to 7 more corrupt frames passed per rate, no real one kept.
TEMPERATURE_JUMP_COUNTS = 2
# g's least-squares fit forgets by this per frame (about ten frames): a vibration's frequency, or a bump's ringing,
# is followed within a few cycles. 0.8 or 0.95 pass the same binary frames; 0.95 lost 2 real ascii frames at 100 Hz
# and 0.8 passed 177 more ascii corruptions at 10 Hz.
FIT_MEMORY = 0.9
# The prediction error's mean square, the envelope, is the mean of about this many frames' (of the first ones at the
# start): long enough to be a measure, short enough to widen within a bump. 20 lost a real binary frame at 100 Hz;
# 100 passed 525 more ascii corruptions at 10 Hz and lost one more real ascii frame at 1 kHz.
ERROR_FRAMES = 50
# A frame is refused when its departure is one of corrupt_rate_steps to within ERROR_MARGIN rms errors (at
# least FLOOR_COUNTS), and that step is more than STEP_MARGIN times that tolerance: a smaller one is noise, or a
# motion's own departure (a turn's onset) as likely as a corruption. ERROR_MARGIN 2.5 lost a real binary frame at
# 100 Hz; 4 passed 2 or 3 more binary corruptions per rate. STEP_MARGIN 6 lost a real binary frame at 100 Hz for
# none fewer passed; 10 passed 2 more per rate.
ERROR_MARGIN = 3.0
STEP_MARGIN = 8.0
# A quiet gyro (noise under a count) has no envelope to measure: at this floor the smallest step refused is over
# 32 counts (0.1 deg/s at 0.00305 deg/s a count, five times an RD2100's noise); the bench's noise (6.6 counts)
# never reaches it.
FLOOR_COUNTS = 4.0
# Frames whose errors make the envelope before the rate is tested (0.8 s at 10 Hz); 4 to 16 measure the same.
WARMUP_FRAMES = 8
# Frames the parser lost in a row that the prediction bridges; more, and it starts again. A corrupt frame the
# parser refuses costs three (it, and the two the stream lock holds back): 1 passes 1 or 2 more corruptions per
# rate (the three frames after each start are not tested); 6 measures as 3.
MAX_BRIDGED = 3
INT16_SPAN = 65536
# With look_ahead: a delivered frame whose departure is a corruption's step more than SPIKE_MARGIN tolerances is
# held one frame, and refused if the next frame returns, to within SPIKE_RETURN tolerances, to what the frames
# before it predict: a one-frame spike. A margin of 4 passed 1 or 2 more binary corruptions per rate, one of 2 lost
# 2, 2 and 4 real binary frames at 10 Hz, 100 Hz and 1 kHz (bumps, vibration, turns); a return of 1.5 passed one
# fewer at 1 kHz, one of 2 lost 3 real bump frames at 100 Hz.
SPIKE_MARGIN = 3.0
SPIKE_RETURN = 1.0
RATE_JUMP = 'rate_jump'
RATE_SPIKE = 'rate_spike'
TEMPERATURE_JUMP = 'temperature_jump'
GUARD_REASONS = (RATE_JUMP, RATE_SPIKE, TEMPERATURE_JUMP)


def _wrapped(counts: float) -> float:
    """A change of a 16-bit count, as the two's complement field wraps it (-32768..32767)."""
    return (counts + INT16_SPAN / 2) % INT16_SPAN - INT16_SPAN / 2


class FrameGuard:
    """Decides frame by frame whether a frame is delivered; counts what it refuses in ``rejected_by_reason``."""

    __slots__ = ('_steps', '_jump', '_temp', '_refused_temp', '_rates', '_gain_uv', '_gain_vv', '_mean_square',
                 '_trusted', '_steady', '_guessed', '_skipped', '_fitted', '_look_ahead', '_held',
                 'rejected_by_reason')

    def __init__(self, corrupt_rate_steps: tuple[int, ...], continuous_temperature: bool = False,
                 look_ahead: bool = False) -> None:
        """``corrupt_rate_steps``: the rate changes (counts, positive) the protocol's undetected corruptions make.

        ``continuous_temperature``: a temperature jump is refused too. ``look_ahead``: a frame that passes may be a
        one-frame spike, which :meth:`confirm` tells with the next frame (the caller holds it until then).
        """
        self._steps = sorted(set(corrupt_rate_steps))
        self._jump = TEMPERATURE_JUMP_COUNTS if continuous_temperature else math.inf
        self._look_ahead = look_ahead
        self.rejected_by_reason = dict.fromkeys(GUARD_REASONS, 0)
        self.reset()

    def reset(self) -> None:
        """After a reopen: everything is learnt anew (a new temperature level is trusted at once)."""
        self._temp: float | None = None           # the last delivered frame's temperature
        self._refused_temp: float | None = None   # the last frame's, if it was refused for it
        self._rates: list[float] = []   # the last three rates: x[n-3], x[n-2], x[n-1] (a refused one predicted)
        self._gain_uv = 0.0
        self._gain_vv = 0.0
        self._mean_square = 0.0
        self._trusted = 0
        self._fitted = False   # g fitted on a frame at least
        self._steady = 0
        self._guessed = 0   # bits: which of the three rates the prediction filled in (frames lost or refused)
        # look_ahead: the last frame delivered, if a spike: (its prediction, tolerance, the fit and envelope before it)
        self._held: tuple[float, float, float, float, float, int] | None = None
        self._skipped = 0   # frames lost or refused since the last delivered one

    @property
    def rejected(self) -> int:
        """Frames refused, of all reasons."""
        return sum(self.rejected_by_reason.values())

    def passes(self, raw_rate: float, raw_temp: float, steady_ns: int, period_ns: float,
               missed_frames: int = 0) -> bool:
        """Whether a frame is delivered; one that is not is counted.

        ``steady_ns``: its monotonic stamp; ``period_ns``: the gyro's period as estimated (0: unknown): frames
        lost between two are bridged by the prediction. ``missed_frames``: the frames the parser refused or lost
        just before this one (:attr:`FrameParser.frames_missed`), which a backlog read in one chunk shows no gap for.
        """
        # Frames lost since the last one (none for a frame closer than a period: an extra one is tested as the next).
        missed = max(round((steady_ns - self._steady) / period_ns) - 1, 0) if period_ns > 0 and self._steady else 0
        missed = max(missed, missed_frames)
        self._steady = steady_ns
        # The temperature may move a count for each frame since the one it is compared with.
        temp, refused, skipped = self._temp, self._refused_temp, self._skipped + missed
        temp_ok = (temp is None or abs(raw_temp - temp) < self._jump + skipped
                   or refused is not None and abs(raw_temp - refused) < self._jump + missed)
        self._refused_temp = None if temp_ok else raw_temp
        self._skipped = skipped + 1   # until delivered
        rates = self._rates
        if missed > MAX_BRIDGED or missed and len(rates) < 3:   # the rates must be consecutive: start again
            rates.clear()
            self._guessed = 0
        for _ in range(missed if len(rates) == 3 else 0):
            self._push(self._predict(), guess=True)
        if not temp_ok:
            self.rejected_by_reason[TEMPERATURE_JUMP] += 1
            if len(rates) == 3:
                self._push(self._predict(), guess=True)
            else:
                rates.clear()   # the rates must be consecutive: start again
            return False
        if len(rates) < 3:
            rates.append(raw_rate)
            self._temp, self._skipped = raw_temp, 0
            return True
        predicted = self._predict()
        error = raw_rate - predicted
        guessed = self._guessed
        # The envelope, widened by g's own uncertainty: its fit's variance (mean square over sum v^2) times v^2 now
        # (a turn that starts after a still stretch, where g was fitted on noise, is not taken for a corruption).
        v = rates[2] - rates[1]
        uncertainty = v * v / self._gain_vv if self._gain_vv > 0 else (0.0 if v == 0 else math.inf)
        tolerance = (max(ERROR_MARGIN * math.sqrt(self._mean_square * (1 + uncertainty)), FLOOR_COUNTS)
                     * (1 + guessed.bit_count()))
        if self._trusted >= WARMUP_FRAMES and self._corrupt(error, tolerance, STEP_MARGIN):
            self.rejected_by_reason[RATE_JUMP] += 1
            rates.clear()   # learnt anew from the next frames: a motion wrongly refused is not followed by a guess
            self._guessed = 0
            return False
        if self._look_ahead and self._trusted >= WARMUP_FRAMES and self._corrupt(error, tolerance, SPIKE_MARGIN):
            self._held = (predicted, tolerance, self._gain_uv, self._gain_vv, self._mean_square, self._trusted)
        if not guessed:   # a departure from a guess tells neither g nor the prediction's envelope
            if self._fitted:   # the error of a prediction by a fitted g (the mean of the first ones, then recent)
                self._trusted += 1
                self._mean_square += (error * error - self._mean_square) / min(self._trusted, ERROR_FRAMES)
            x3, x2, x1 = rates
            u, v = raw_rate - x3, x1 - x2
            self._gain_uv = FIT_MEMORY * self._gain_uv + u * v
            self._gain_vv = FIT_MEMORY * self._gain_vv + v * v
            self._fitted = True
        self._push(raw_rate)
        self._temp, self._skipped = raw_temp, 0
        return True

    def confirm(self, raw_rate: float, steady_ns: int, period_ns: float, missed_frames: int = 0) -> bool:
        """With ``look_ahead``, before :meth:`passes` of the next frame: whether the last frame delivered stays so.

        It does unless its departure was a corruption's step (held by :meth:`passes`) and this frame, the next one
        (none missed between: ``missed_frames`` as :meth:`passes` takes it), is back on what the frames before it
        predict: then it is counted refused (RATE_SPIKE) and replaced by its prediction, the fit and envelope as
        before it.
        """
        held, self._held = self._held, None
        if held is None or period_ns <= 0 or missed_frames or round((steady_ns - self._steady) / period_ns) != 1:
            return True
        predicted, tolerance, gain_uv, gain_vv, mean_square, trusted = held
        x3, x2, x1 = self._rates
        gain = min(max(gain_uv / gain_vv, -1.0), 3.0) if gain_vv > 0 else 1.0
        if abs(_wrapped(raw_rate - (x3 + gain * (predicted - x2)))) > SPIKE_RETURN * tolerance:
            return True
        self.rejected_by_reason[RATE_SPIKE] += 1
        self._rates[-1] = predicted
        self._guessed |= 1
        self._gain_uv, self._gain_vv, self._mean_square, self._trusted = gain_uv, gain_vv, mean_square, trusted
        return False

    def release(self) -> None:
        """With ``look_ahead``: the frame held is delivered without its next one (none came in time, or a close)."""
        self._held = None

    def _predict(self) -> float:
        """The next rate from the last three: x[n-3] + g (x[n-1] - x[n-2]), g fitted and held to -1..3."""
        x3, x2, x1 = self._rates
        gain = min(max(self._gain_uv / self._gain_vv, -1.0), 3.0) if self._gain_vv > 0 else 1.0
        return x3 + gain * (x1 - x2)

    def _push(self, rate: float, guess: bool = False) -> None:
        rates = self._rates
        del rates[0]
        rates.append(rate)
        self._guessed = (self._guessed << 1 | guess) & 0b111

    def _corrupt(self, error: float, tolerance: float, margin: float) -> bool:
        """Whether ``error`` is, to within ``tolerance``, a corruption's step larger than ``margin`` tolerances."""
        size = abs(_wrapped(error))
        if size <= tolerance:
            return False
        steps = self._steps
        i = max(bisect.bisect_left(steps, size - tolerance), bisect.bisect_right(steps, margin * tolerance))
        return i < len(steps) and steps[i] <= size + tolerance
