"""The parked bias logic: when a collection starts, when it is aborted, and the mean check against the bias in force."""

from __future__ import annotations

import math

import numpy as np
import pytest

from art_gyro_calibration.parked import (EARTH_RATE_DPS, ParkedBias, ParkedRefusal, ParkedSettings, check_parked,
                                         gyro_stillness_threshold, odometry_parked)
from art_gyro_calibration.static_bias import NO_BIAS, MotionError, StaticBias, static_bias

TOPIC = ParkedSettings(use_topic=True, gyro_stillness=False, max_age_s=1.0, settle_s=1.0, min_interval_s=600.0)
GYRO = ParkedSettings(use_topic=False, gyro_stillness=True, max_age_s=1.0, settle_s=1.0, min_interval_s=600.0)
# An RD2100 at 10 Hz: a day's bias of 0.02 deg/s, noise of a few counts (0.00305 deg/s each).
BIAS_DPS = 0.02
NOISE_DPS = 0.008
COUNT_DPS = 0.00305
SAMPLES = 100


def window(rate_dps: float, seed: int) -> StaticBias:
    """A bias over SAMPLES frames of a gyro turning at ``rate_dps`` (its day's bias on top), quantised to counts."""
    rng = np.random.default_rng(seed)
    rate = np.round((BIAS_DPS + rate_dps + rng.normal(0.0, NOISE_DPS, SAMPLES)) / COUNT_DPS) * COUNT_DPS
    return static_bias(rate, np.zeros(SAMPLES), max_mean_dps=math.inf)


def feed(parked: ParkedBias, word: bool, start: float, end: float, period: float = 0.1) -> None:
    for t in np.arange(start, end, period):
        parked.put(word, float(t))


def test_odometry_is_parked_below_both_thresholds_only() -> None:
    assert odometry_parked((0.0, 0.0, 0.0), (0.0, 0.0, 0.0), 0.01, 0.02)
    assert odometry_parked((0.005, 0.005, 0.0), (0.0, 0.0, math.radians(0.019)), 0.01, 0.02)
    assert not odometry_parked((0.02, 0.0, 0.0), (0.0, 0.0, 0.0), 0.01, 0.02)
    for creep_dps in (0.05, 0.1, 0.5):   # the odometry reports the creep: refused by max_angular_dps
        assert not odometry_parked((0.0, 0.0, 0.0), (0.0, 0.0, math.radians(creep_dps)), 0.01, 0.02)
    assert not odometry_parked((math.nan, 0.0, 0.0), (0.0, 0.0, 0.0), 0.01, 0.02)


def test_the_mean_check_is_relative_to_the_bias_in_force() -> None:
    reference = StaticBias(0.3, 0.1, 100, 0.01)   # a compensated mean of 0.2 deg/s in force
    check_parked(StaticBias(0.35, 0.1, 100, 0.01), reference, 0.1, gyro_stillness=False)
    with pytest.raises(ParkedRefusal, match='mean compensated rate') as refused:
        check_parked(StaticBias(0.45, 0.1, 100, 0.01), reference, 0.1, gyro_stillness=False)
    assert refused.value.reason == 'mean' and isinstance(refused.value, MotionError)
    # No bias in force: the service's check on the mean itself.
    check_parked(StaticBias(0.05, 0.0, 100, 0.01), NO_BIAS, 0.1, gyro_stillness=False)
    with pytest.raises(ParkedRefusal):
        check_parked(StaticBias(0.15, 0.0, 100, 0.01), NO_BIAS, 0.1, gyro_stillness=False)


def test_gyro_stillness_needs_a_bias_in_force() -> None:
    with pytest.raises(ParkedRefusal, match='no bias in force') as refused:
        check_parked(StaticBias(0.0, 0.0, 100, 0.01), NO_BIAS, 0.1, gyro_stillness=True)
    assert refused.value.reason == 'no_reference'


def test_gyro_stillness_takes_a_still_gyro_and_refuses_the_slowest_creep() -> None:
    """A creep of 0.05, 0.1 or 0.5 deg/s is refused; still windows pass; the bound is a few mdeg/s."""
    reference = window(0.0, seed=1)
    bounds = []
    for seed in range(2, 22):
        still = window(0.0, seed)
        check_parked(still, reference, 0.1, gyro_stillness=True)
        bounds.append(gyro_stillness_threshold(still, reference, 0.1))
    assert EARTH_RATE_DPS < min(bounds) and max(bounds) < 0.01, bounds
    for creep_dps in (0.05, 0.1, 0.5):
        creeping = window(creep_dps, seed=30)
        with pytest.raises(ParkedRefusal, match='the robot is turning'):
            check_parked(creeping, reference, 0.1, gyro_stillness=True)
    # The smallest creep it refuses is about the bound: twice it always, a tenth never.
    assert all(_refused(window(2 * max(bounds), seed), reference) for seed in range(40, 60))
    assert not any(_refused(window(0.1 * min(bounds), seed), reference) for seed in range(40, 60))


def test_without_gyro_stillness_a_bool_topic_is_believed_below_the_service_mean() -> None:
    """A Bool that says parked while the robot creeps at 0.05 deg/s is believed: the mean check is the service's."""
    reference = window(0.0, seed=1)
    check_parked(window(0.05, seed=3), reference, 0.1, gyro_stillness=False)
    for creep_dps in (0.5,):
        with pytest.raises(ParkedRefusal):
            check_parked(window(creep_dps, seed=3), reference, 0.1, gyro_stillness=False)


def _refused(bias: StaticBias, reference: StaticBias) -> bool:
    try:
        check_parked(bias, reference, 0.1, gyro_stillness=True)
    except ParkedRefusal:
        return True
    return False


def test_a_collection_starts_once_parked_and_settled_and_not_on_a_stale_word() -> None:
    parked = ParkedBias(TOPIC, now=0.0)
    assert not parked.due(0.0)
    feed(parked, False, 0.0, 5.0)
    assert not parked.due(5.0)
    feed(parked, True, 5.0, 5.95)
    assert not parked.due(5.9)   # not settled
    feed(parked, True, 5.95, 6.2)
    assert parked.due(6.15)
    assert not parked.due(7.5)   # the last word is 1.35 s old: stale, not parked
    feed(parked, True, 7.6, 8.55)
    assert not parked.due(8.5)   # a silence may have hidden a move: parked again since 7.6, to settle
    feed(parked, True, 8.55, 8.7)
    assert parked.due(8.65)
    parked.start(8.65)
    assert not parked.due(8.65)  # one runs


def test_a_collection_is_aborted_when_the_robot_moves_or_the_topic_falls_silent() -> None:
    parked = ParkedBias(TOPIC, now=0.0)
    feed(parked, True, 0.0, 2.0)
    parked.start(2.0)
    assert parked.broken(2.05) is None
    parked.put(False, 2.1)
    moved = parked.broken(2.1)
    assert moved is not None and moved.reason == 'moved'
    parked.put(True, 2.2)   # parked again: still broken (it moved during the collection)
    moved = parked.broken(2.2)
    assert moved is not None and moved.reason == 'moved'
    parked.ended(2.2, moved)
    assert parked.refused['moved'] == 1 and parked.last_refusal.startswith('moved: ')

    parked.put(True, 3.5)
    parked.start(3.5)
    stale = parked.broken(4.6)
    assert stale is not None and stale.reason == 'stale'
    parked.ended(4.6, stale)
    assert parked.refused['stale'] == 1


def test_after_an_update_the_next_waits_for_a_move_or_the_interval() -> None:
    parked = ParkedBias(TOPIC, now=0.0)
    feed(parked, True, 0.0, 1.5)
    parked.start(1.5)
    parked.ended(11.5, None)
    assert parked.updates == 1 and parked.last_update == 11.5
    feed(parked, True, 11.5, 600.0, period=0.5)
    assert not parked.due(599.9)            # parked for an hour: not re-biased every window
    feed(parked, True, 600.0, 612.0, period=0.5)
    assert parked.due(611.6)                # the interval
    parked.start(611.6)
    parked.ended(621.6, None)
    feed(parked, False, 621.6, 630.0)       # moved
    feed(parked, True, 630.0, 630.5)
    assert not parked.due(630.4)            # not settled
    feed(parked, True, 630.5, 631.2)
    assert parked.due(631.1)                # moved and parked again


def test_a_bias_from_the_service_counts_as_an_update() -> None:
    parked = ParkedBias(TOPIC, now=0.0)
    feed(parked, True, 0.0, 12.0)
    parked.bias_taken(11.0)
    assert not parked.due(11.9)


def test_the_gyro_alone_retries_after_motion_and_waits_after_a_bias() -> None:
    parked = ParkedBias(GYRO, now=0.0)
    assert not parked.due(0.5) and parked.due(1.0)
    parked.start(1.0)
    assert parked.broken(100.0) is None     # no topic to fall silent
    parked.ended(11.0, ParkedRefusal('mean', 'turning'))
    assert parked.due(11.0)                 # it moved: the next still window is taken at once
    parked.start(11.0)
    parked.ended(21.0, MotionError('rate spread 0.1 deg/s over 100 samples exceeds 0.02 deg/s'))
    assert parked.refused == {**parked.refused, 'mean': 1, 'spread': 1}
    assert parked.due(21.0)
    parked.start(21.0)
    parked.ended(31.0, None)
    assert not parked.due(600.0) and parked.due(631.0)
