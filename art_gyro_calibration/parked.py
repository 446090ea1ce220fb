"""Parked bias: a static bias taken whenever the robot is parked (an angular zero-rate update).

What says "parked" is a topic the robot already has (:class:`ParkedSignal`: a Bool, or odometry whose twist is
below thresholds), or, only if the user opts in, the gyro's own stillness. :class:`ParkedBias` decides when a
collection starts, when a running one is aborted (the robot moved, or the topic went silent) and checks its
result (:func:`check_parked`) against the bias in force. ROS-free: the node feeds it times and messages.

The smallest turn rate a collection can refuse: with a topic alone, the topic's own (odometry: ``max_angular_dps``;
a Bool: none, the mean check relative to the bias in force, ``static_bias_max_mean_dps``); with the gyro's
stillness, :data:`EARTH_RATE_DPS` plus :data:`UNCERTAINTY_SIGMAS` standard errors of the difference of two
biases' means (a few mdeg/s on an RD2100 over 100 samples).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from art_gyro_calibration.static_bias import MotionError, StaticBias

# The Earth's rotation (deg/s): a still gyro's mean moves by at most its vertical part between two places.
EARTH_RATE_DPS = 15.041 / 3600.0
# How many standard errors of the difference of the two means the gyro-stillness mean check allows beyond it.
UNCERTAINTY_SIGMAS = 3.0
# Why a parked collection ended without a bias (the keys of ParkedBias.refused).
REFUSALS = ('moved', 'stale', 'mean', 'spread', 'no_reference', 'other')


class ParkedRefusal(MotionError):
    """A parked collection refused, with the key (:data:`REFUSALS`) it is counted under."""

    def __init__(self, reason: str, message: str) -> None:
        super().__init__(message)
        self.reason = reason


def odometry_parked(linear_mps: tuple[float, float, float], angular_rps: tuple[float, float, float],
                    max_linear_mps: float, max_angular_dps: float) -> bool:
    """Whether an odometry twist says parked: speed and angular rate (norms) below the thresholds, and finite."""
    speed = math.sqrt(sum(v * v for v in linear_mps))
    rate_dps = math.degrees(math.sqrt(sum(w * w for w in angular_rps)))
    return speed <= max_linear_mps and rate_dps <= max_angular_dps   # a NaN compares false: not parked


def gyro_stillness_threshold(bias: StaticBias, reference: StaticBias, max_mean_dps: float) -> float:
    """The largest mean compensated rate the Earth's rotation and the two biases' noise explain (deg/s).

    At most ``max_mean_dps`` (the service's), for a gyro so noisy the standard error alone would allow more.
    """
    stderr = math.sqrt(bias.rate_std_dps ** 2 / bias.samples + reference.rate_std_dps ** 2 / reference.samples)
    return min(max_mean_dps, EARTH_RATE_DPS + UNCERTAINTY_SIGMAS * stderr)


def check_parked(bias: StaticBias, reference: StaticBias, max_mean_dps: float, gyro_stillness: bool) -> None:
    """Refuse a parked bias whose mean compensated rate, with ``reference`` (the bias in force), shows a turn.

    Relative to the bias in force: a gyro whose bias is large passes, one that turns does not. Without a bias in
    force the check is the service's (the mean of rate - error), and the gyro's stillness cannot judge (refused).
    With ``gyro_stillness`` the bound is :func:`gyro_stillness_threshold`, else ``max_mean_dps``.
    """
    mean = bias.static_bias_drift_dps - bias.calc_static_bias_drift_dps
    if reference.samples:
        mean -= reference.static_bias_drift_dps - reference.calc_static_bias_drift_dps
    elif gyro_stillness:
        raise ParkedRefusal('no_reference', 'no bias in force to compare with: the gyro\'s stillness alone '
                                            'cannot tell a slow turn from a bias')
    bound = gyro_stillness_threshold(bias, reference, max_mean_dps) if gyro_stillness else max_mean_dps
    if not abs(mean) <= bound:
        raise ParkedRefusal('mean', f'mean compensated rate {mean:+.5f} deg/s over {bias.samples} samples (with the '
                                    f'bias in force) exceeds {bound:.5f} deg/s: the robot is turning')


@dataclass(frozen=True)
class ParkedSettings:
    """The ``parked_bias.*`` parameters the logic needs: a topic says parked (``use_topic``), the gyro's stillness."""

    use_topic: bool
    gyro_stillness: bool
    max_age_s: float
    settle_s: float
    min_interval_s: float


class ParkedBias:
    """When a parked collection starts and when it is aborted; refusals counted by reason.

    Times are the caller's monotonic seconds. The topic's messages go to :meth:`put`; :meth:`due` says whether a
    collection should start now; :meth:`broken` whether a running one must be aborted (and why); :meth:`ended`
    notes how one ended. After one ended (a bias, a refusal, or a bias from elsewhere: :meth:`bias_taken`) the
    next waits until the robot has moved and parked again, or for ``min_interval_s``.
    """

    def __init__(self, settings: ParkedSettings, now: float) -> None:
        self.settings = settings
        self._parked = False            # the topic's latest word
        self._received = -math.inf      # when it came
        self._since = math.inf          # when the robot was last seen to park (topic: false -> true)
        self._moved = True              # the robot moved (or nothing ended yet) since the last end
        self._last_end = -math.inf
        self._started = math.inf        # when the running collection started (inf: none runs)
        self.refused = dict.fromkeys(REFUSALS, 0)
        self.last_update = -math.inf    # when the last parked bias was put in force
        self.updates = 0
        self.last_refusal = ''
        if not settings.use_topic:      # the gyro alone: always "parked", its stillness decides
            self._parked, self._received, self._since = True, math.inf, now

    def put(self, parked: bool, now: float) -> None:
        """The topic's word at ``now``."""
        if parked and not self.parked(now):
            self._since = now
        if not parked:
            self._moved = True
        self._parked, self._received = parked, now

    def parked(self, now: float) -> bool:
        """Whether the robot is parked now: the topic's last word is true and not older than ``max_age_s``."""
        return self._parked and now - self._received <= self.settings.max_age_s

    def due(self, now: float) -> bool:
        """Whether a collection should start now (none runs, parked and settled, and not too soon after the last)."""
        return (self._started == math.inf and self.parked(now) and now - self._since >= self.settings.settle_s
                and (self._moved or now - self._last_end >= self.settings.min_interval_s))

    def start(self, now: float) -> None:
        """A collection started."""
        self._started = now
        self._moved = False

    def broken(self, now: float) -> ParkedRefusal | None:
        """Why the running collection must be aborted now (the robot moved or the topic fell silent), else None."""
        if self._started == math.inf or not self.settings.use_topic:
            return None
        if self._since > self._started or not self._parked:
            return ParkedRefusal('moved', 'the robot moved during the collection (the parked topic said false)')
        if not self.parked(now):
            return ParkedRefusal('stale', f'the parked topic was silent for more than {self.settings.max_age_s:g} s')
        return None

    def ended(self, now: float, error: BaseException | None) -> None:
        """The running collection ended at ``now``: with a bias (``error`` None) or refused for ``error``."""
        self._started = math.inf
        self._last_end = now
        if error is None:
            self.last_update = now
            self.updates += 1
            return
        reason = error.reason if isinstance(error, ParkedRefusal) else \
            'spread' if isinstance(error, MotionError) and 'spread' in str(error) else 'other'
        self.refused[reason] += 1
        self.last_refusal = f'{reason}: {error}'
        if not self.settings.use_topic and reason in ('mean', 'spread'):
            self._moved = True   # the gyro alone: it moved, so the next still window may be taken at once

    def bias_taken(self, now: float) -> None:
        """A bias came from elsewhere (the service, the start-up): the next parked one waits as after its own."""
        self._last_end = now
        self._moved = False
