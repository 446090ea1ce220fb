"""Causal signals: per sample and over a log they agree, and they measure what they claim."""

import dataclasses

import numpy as np
import pytest

from art_gyro_calibration.model import ArtPolynomial, ErrorModel
from art_gyro_calibration.signals import (DERIVED_SIGNALS, FIRST_ORDER_TAU_S, LAGGED_SIGNAL, SIGNALS, Envelope,
                                          SignalFilters, Signals, SignalTracker, compute_signals, smoothed_both_ways)
from art_gyro_calibration.temperature_rate import FIRST_ORDER, FORMS, LocalQuadraticRate
from art_gyro_calibration.terms import Term


def _run(t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(3)
    rate = 40 * np.sign(np.sin(t / 30)) + rng.normal(0, 0.01, len(t))
    temp = 20 + 8 * np.sin(t / 2000) + np.round(rng.normal(0, 1, len(t))) * 0.05
    return rate, temp


@pytest.mark.parametrize('form', FORMS)
@pytest.mark.parametrize('jitter', [0.0, 0.01])
def test_tracker_agrees_with_batch(jitter: float, form: str) -> None:
    rng = np.random.default_rng(4)
    t = np.arange(20000) * 0.1 + rng.uniform(0, jitter, 20000)
    rate, temp = _run(t)
    filters = SignalFilters(60.0, 0.3, form)
    signals = compute_signals(t, rate, temp, filters=filters)
    lag = Term('temperature_lag', 'power', (1.0,), (1,), 300.0)
    tracker = SignalTracker(filters, lags=(300.0,), powered_on_at_start=True)
    tracked = [name for name in DERIVED_SIGNALS if name not in ('angle', 'temperature_lag')]   # not per sample
    got: dict[str, list[float]] = {name: [] for name in tracked + ['temperature_lag']}
    for k in range(len(t)):
        tracker.update(t[k], rate[k], temp[k])
        for name in tracked:
            got[name].append(tracker.value(name))
        got['temperature_lag'].append(tracker.for_term(lag))
    for name in tracked:
        np.testing.assert_allclose(got[name], signals.get(name), rtol=1e-9, atol=1e-9, err_msg=name)
    np.testing.assert_allclose(got['temperature_lag'], signals.for_term(lag), rtol=1e-9, atol=1e-9)


def test_a_warm_gyro_has_no_time_since_power_on() -> None:
    """Unless the run started at power-on, the warm-up's clock is infinite: the warm-up has decayed."""
    t = np.arange(100) * 0.1
    tracker = SignalTracker()
    tracker.update(0.0, 0.0, 20.0)
    assert tracker.value('time_since_power_on') == np.inf
    assert np.all(np.isinf(compute_signals(t, t, t, powered_on_at_start=False).time_since_power_on))
    np.testing.assert_array_equal(compute_signals(t, t, t).time_since_power_on, t)


# Each form at its default time constant, and after how many of them it reads a ramp's slope within 2 %.
@pytest.mark.parametrize('filters, settled_taus', [(SignalFilters(), 9.0),
                                                   (SignalFilters(FIRST_ORDER_TAU_S, 0.5, FIRST_ORDER), 5.0)])
def test_temperature_rate_of_a_ramp(filters: SignalFilters, settled_taus: float) -> None:
    t = np.arange(0, 3600, 0.1)
    temp = 15 + t / 60.0  # 1 degC per minute
    signals = compute_signals(t, np.zeros_like(t), np.round(temp / 0.05) * 0.05, filters=filters)
    settled = t > settled_taus * filters.temperature_rate_tau_s
    np.testing.assert_allclose(signals.temperature_rate[settled], 1 / 60.0, rtol=0.02)
    assert signals.temperature_rate[0] == 0.0  # nothing is known of the past at the first sample


def test_angle_and_time() -> None:
    t = np.arange(0, 36.01, 0.01) + 100.0
    signals = compute_signals(t, np.full_like(t, 10.0), np.full_like(t, 20.0))
    assert signals.angle[-1] == pytest.approx(360.0)
    assert signals.time[-1] == pytest.approx(36.0)
    assert set(signals.rate_sign) == {1.0}


def test_extra_columns_and_unknown_names() -> None:
    t = np.arange(5.0)
    signals = compute_signals(t, t, t, extras={'supply_v': t * 2})
    assert signals.names()[-1] == 'supply_v'
    np.testing.assert_array_equal(signals.get('supply_v'), t * 2)
    with pytest.raises(KeyError, match="signal 'humidity' is neither derived"):
        signals.get('humidity')
    with pytest.raises(KeyError, match='not available per sample'):
        SignalTracker().value('supply_v')


def test_every_registered_signal_is_computed_by_its_readers() -> None:
    """A signal added to the registry is an attribute of Signals, and of SignalTracker when the node tracks it.

    The lagged temperature is the exception: its time constant comes with the term (``for_term``).
    """
    for name, signal in SIGNALS.items():
        assert signal.description, name
        if name == LAGGED_SIGNAL:
            continue
        assert name in Signals.__dict__ or name in Signals.__dataclass_fields__, name
        if signal.per_sample:
            assert hasattr(SignalTracker, name), name


def test_error_model_per_sample_equals_batch() -> None:
    t = np.arange(3000) * 0.1
    rate, temp = _run(t)
    model = ErrorModel(ArtPolynomial([[1e-6, 2e-4], [3e-3, -0.01]]),
                       (Term('temperature_rate', 'power', (4.0, 0.01), (1,), rate_powers=(0, 1)),
                        Term('time_since_power_on', 'exp_decay', (0.03,), (), 120.0),
                        Term('temperature_lag', 'power', (1e-3, 2e-5, 1e-6, 3e-8), (1, 2), 300.0, (0, 1)),
                        Term('time', 'power', (1e-5,), (1,)), Term('rate_sign', 'power', (0.001,), (1,))),
                       temperature_range_c=(12.0, 20.5))
    batch = model.error(compute_signals(t, rate, temp))
    tracker = SignalTracker(lags=model.lags, powered_on_at_start=True)
    one = []
    for k in range(len(t)):
        tracker.update(t[k], rate[k], temp[k])
        one.append(model.error_one(tracker))
    np.testing.assert_allclose(one, batch, rtol=1e-10, atol=1e-12)
    assert np.ptp(batch - model.polynomial.error(rate, temp)) > 0.01  # the terms do contribute


def _irregular_log(n: int, seed: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Epoch-second times with jitter, repeated stamps and a 10-minute gap; rate, temperature, a supply."""
    rng = np.random.default_rng(seed)
    dt = rng.choice([0.001, 0.01, 0.1], n) * rng.uniform(0.5, 1.5, n)
    dt[rng.integers(0, n, 20)] = 0.0          # two frames with one stamp
    dt[n // 3] = 600.0                        # the logger stopped for ten minutes
    t = 1.7e9 + np.cumsum(dt)
    rate, temp = _run(t - t[0])
    return t, rate, temp, 12.0 + rng.normal(0, 0.01, n)


@pytest.mark.parametrize('form', FORMS)
@pytest.mark.parametrize('seed', [0, 1, 2])
def test_chunked_equals_whole_log(seed: int, form: str) -> None:
    """Signals computed chunk by chunk, each from the previous chunk's end state, equal the whole log's."""
    n = 30000
    t, rate, temp, supply = _irregular_log(n, seed)
    filters = SignalFilters(60.0, 0.3, form)
    whole = compute_signals(t, rate, temp, {'supply_v': supply}, filters)
    rng = np.random.default_rng(10 + seed)
    # Random boundaries, chunks of one sample, and a boundary on each side of the gap's first sample.
    cuts = np.unique(np.concatenate(([0, 1, 2, n // 3, n // 3 + 1, n], rng.integers(0, n, 40))))
    state = None
    parts = {name: [] for name in DERIVED_SIGNALS + ('supply_v',)}
    lag = Term('temperature_lag', 'power', (1.0,), (1,), 200.0)

    def value(signals: Signals, name: str) -> np.ndarray:
        return signals.for_term(lag) if name == lag.signal else signals.get(name)

    for start, stop in zip(cuts[:-1], cuts[1:]):
        chunk = compute_signals(t[start:stop], rate[start:stop], temp[start:stop],
                                {'supply_v': supply[start:stop]}, filters, state)
        for name in parts:
            parts[name].append(value(chunk, name))
        state = chunk.end_state()
    chunk = compute_signals(t[n:], rate[n:], temp[n:], {'supply_v': supply[n:]}, filters, state)
    assert len(chunk) == 0 and chunk.end_state() == state   # an empty chunk carries the state through
    for name in parts:
        # The filters' closed form rounds to a few ulps of (x - level) * tau / dt wherever it restarts
        # (2e-11 deg/s^2 of a rate change reaching 130 deg/s^2 here); the rest is the same arithmetic.
        scale = max(1.0, np.max(np.abs(value(whole, name))))
        np.testing.assert_allclose(np.concatenate(parts[name]), value(whole, name), rtol=0, atol=1e-12 * scale,
                                   err_msg=name)
    end = whole.end_state()
    assert (end.t0, end.t, end.rate, end.temperature, end.angle) == \
        (state.t0, state.t, state.rate, state.temperature, state.angle)
    assert (end.temperature_level, end.rate_level) == pytest.approx((state.temperature_level, state.rate_level),
                                                                    rel=1e-14)
    if form == FIRST_ORDER:
        assert end.temperature_levels is None and state.temperature_levels is None
    else:
        assert end.temperature_levels == pytest.approx(state.temperature_levels, rel=1e-14)
    assert state.t0 == t[0] and state.t == t[-1]


def test_end_state_continues_the_tracker() -> None:
    """The end state holds what the per-sample tracker holds after the same samples."""
    t, rate, temp, _ = _irregular_log(2000, 5)
    state = compute_signals(t, rate, temp).end_state()
    tracker = SignalTracker()
    for k in range(len(t)):
        tracker.update(t[k], rate[k], temp[k])
    assert (state.t0, state.t, state.rate, state.temperature) == \
        (tracker.t0, tracker.t, tracker.rate, tracker.temperature)
    quadratic = tracker._temperature_rate
    assert isinstance(quadratic, LocalQuadraticRate)   # the default: what a new fit writes
    assert (state.temperature_level, *(state.temperature_levels or ())) == \
        pytest.approx((quadratic.level, quadratic.level2, quadratic.level3), rel=1e-12)
    with pytest.raises(ValueError, match='continues only from a state with its levels'):
        _ = compute_signals(t, rate, temp, state=dataclasses.replace(state, temperature_levels=None)).temperature_rate
    assert state.rate_level == pytest.approx(tracker._rate_change.smooth, rel=1e-12)
    with pytest.raises(ValueError, match='no samples'):
        compute_signals([], [], []).end_state()


def test_each_run_of_several_starts_its_signals_afresh() -> None:
    """A several-run fit: time, time since power-on and every filter restart at each run's first row."""
    t = np.concatenate([np.arange(0.0, 600.0, 1.0), np.arange(0.0, 300.0, 1.0) + 5000.0,
                        np.arange(0.0, 300.0, 1.0) + 9000.0])
    temp = np.concatenate([20.0 + 0.01 * np.arange(600), 35.0 + 0.02 * np.arange(300), 30.0 - 0.01 * np.arange(300)])
    rate = np.sin(t / 50.0)
    starts = ((0, True), (600, True), (900, False))
    s = compute_signals(t, rate, temp, run_starts=starts)
    for (first, cold), stop in zip(starts, (600, 900, 1200)):
        alone = compute_signals(t[first:stop], rate[first:stop], temp[first:stop], powered_on_at_start=cold)
        for name in ('time', 'time_since_power_on', 'temperature_rate', 'rate_change', 'angle'):
            np.testing.assert_array_equal(s.get(name)[first:stop], alone.get(name))
        np.testing.assert_array_equal(s.lagged_temperature(60.0)[first:stop], alone.lagged_temperature(60.0))
    # At a run's first row: no time since its start, no rate of change yet (the jump from the run before is
    # no rate), the lag at the run's own temperature; a warm run's time since power-on is infinite.
    assert s.time[600] == 0.0 and s.time_since_power_on[600] == 0.0 and np.isposinf(s.time_since_power_on[900])
    assert s.temperature_rate[600] == 0.0 and s.lagged_temperature(60.0)[600] == 35.0
    with pytest.raises(ValueError, match='row 0'):
        compute_signals(t, rate, temp, run_starts=((5, True),))


def test_the_temperature_rate_filters_time_scales_and_bounds() -> None:
    """A static bias refinement keeps an old file's scale (its tau) and at least 2 min with the local quadratic fit.

    The envelope bounds each form's estimate: the span over tau, five times that for the local quadratic fit.
    """
    old = SignalFilters(60.0, 0.5, FIRST_ORDER)
    assert old.refinement_scale_s == 60.0
    assert SignalFilters().refinement_scale_s == FIRST_ORDER_TAU_S
    assert SignalFilters(50.0).refinement_scale_s == 150.0
    envelope = Envelope((10.0, 50.0), 100.0, old, 3600.0)
    assert SIGNALS['temperature_rate'].range(envelope) == (-40.0 / 60.0, 40.0 / 60.0)
    assert SIGNALS['temperature_rate'].range(dataclasses.replace(envelope, filters=SignalFilters(60.0))) == \
        (-200.0 / 60.0, 200.0 / 60.0)
    with pytest.raises(ValueError, match="filters.temperature_rate_form must be one of first_order, local_quadratic"):
        SignalFilters(temperature_rate_form='second_order')


def _chamber_counts() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """6 h at 10 Hz of chamber ramps of 0.1 degC/min between holds: time, true temperature, its 0.05 degC counts."""
    t = np.arange(0.0, 6 * 3600.0, 0.1)
    knots_s = np.cumsum([0.0, 1200.0, 6000.0, 1800.0, 6000.0, 1800.0])
    true_c = np.interp(t, knots_s, [20.0, 20.0, 30.0, 30.0, 20.0, 20.0])
    return t, true_c, np.round(true_c / 0.05) * 0.05


def test_the_fit_s_temperature_rate_is_not_diluted_by_the_counts_noise() -> None:
    # A temperature-rate coefficient fitted on the node's rate from 0.05 degC counts came out at 0.94 of the true
    # one (the noise in a regressor shrinks its coefficient); the node's static-bias refinement, which takes the
    # term's value into the mission's bias, has no such noise. The fit reads the temperature smoothed both ways.
    t, true_c, counts = _chamber_counts()
    true_rate = np.gradient(true_c, t)
    node = compute_signals(t, np.zeros(len(t)), counts).temperature_rate
    fit = compute_signals(t, np.zeros(len(t)), counts, refined_start=True).temperature_rate
    late = t > 600.0   # past the refinement's minutes
    assert float(node[late] @ true_rate[late] / (node[late] @ node[late])) < 0.95
    assert float(fit[late] @ true_rate[late] / (fit[late] @ fit[late])) == pytest.approx(1.0, abs=0.01)
    # The node's own signals, and the first-order filter's (a file that names no form), are as they were.
    first_order = SignalFilters(FIRST_ORDER_TAU_S, 0.5, FIRST_ORDER)
    np.testing.assert_array_equal(compute_signals(t, np.zeros(len(t)), counts, filters=first_order,
                                                  refined_start=True).temperature, counts)


def test_a_two_way_smoothing_keeps_a_slope_to_the_ends_and_each_run_apart() -> None:
    t = np.arange(0.0, 600.0, 0.1)
    line = 20.0 + 0.01 * t
    np.testing.assert_allclose(smoothed_both_ways(t, line, 20.0), line, atol=1e-5)
    # Two runs of one fit, the second 10 degC warmer: neither is smoothed into the other.
    temp = np.where(t < 300.0, 20.0, 30.0)
    start = int(np.searchsorted(t, 300.0))
    signals = compute_signals(t, np.zeros(len(t)), temp, run_starts=((0, True), (start, False)), refined_start=True)
    np.testing.assert_allclose(signals.temperature, temp, atol=1e-9)
    with pytest.raises(ValueError, match='whole log'):
        compute_signals(t, np.zeros(len(t)), temp, state=signals.end_state(), refined_start=True)
