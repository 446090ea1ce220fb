"""The local quadratic temperature rate: its twins agree, it follows a ramp and a bend, and old files keep theirs."""

import dataclasses
from pathlib import Path

import numpy as np
import pytest

from art_gyro_calibration.calibration import dump_calibration, load_calibration, load_packaged_calibration
from art_gyro_calibration.compensation import RunStart, apply_calibration
from art_gyro_calibration.gyro_physics import measured_from_true
from art_gyro_calibration.log import GyroLog
from art_gyro_calibration.signals import FIRST_ORDER_TAU_S, SignalFilters, compute_signals, first_order_smooth
from art_gyro_calibration.temperature_rate import FIRST_ORDER, LOCAL_QUADRATIC, LocalQuadraticRate
from art_gyro_calibration.terms import Term

TAU_S = SignalFilters().temperature_rate_tau_s


def _per_sample(t: np.ndarray, x: np.ndarray, tau_s: float) -> np.ndarray:
    estimate = LocalQuadraticRate(tau_s)
    out = np.empty(len(t))
    for k in range(len(t)):
        estimate.update(t[k] - t[k - 1] if k else 0.0, float(x[k]))
        out[k] = estimate.value
    return out


@pytest.mark.parametrize('rate_hz, counts', [(10.0, True), (1000.0, False)])
def test_batch_equals_per_sample(rate_hz: float, counts: bool) -> None:
    """Over counts at 10 Hz and floats at 1 kHz, with jitter, repeated stamps and a gap, to 1e-12 degC/s."""
    rng = np.random.default_rng(1)
    n = 40000
    dt = rng.uniform(0.5, 1.5, n) / rate_hz
    dt[rng.integers(0, n, 30)] = 0.0
    dt[n // 2] = 900.0
    t = 1.7e9 + np.cumsum(dt)
    x = 20.0 + 5.0 * np.sin((t - t[0]) / 900.0) + rng.normal(0.0, 0.01, n)
    if counts:
        x = np.round(x / 0.05) * 0.05
    batch = compute_signals(t, np.zeros(n), x).temperature_rate
    np.testing.assert_allclose(batch, _per_sample(t, x, TAU_S), rtol=0, atol=1e-12)
    assert np.max(np.abs(batch)) > 1e-3   # the comparison is not of zeros


def test_ramp_and_bend_without_lag() -> None:
    """A ramp's slope exactly, and a parabola's (a bend) without the first-order filter's lag."""
    t = np.arange(0.0, 3600.0, 0.1)
    ramp = compute_signals(t, np.zeros(len(t)), 15.0 + t / 60.0).temperature_rate
    np.testing.assert_allclose(ramp[t > 30 * TAU_S], 1 / 60.0, rtol=1e-9)   # once the start has decayed
    curvature = 1e-6   # degC/s^2: 0.06 degC/min more every minute
    bend = 15.0 + curvature * t ** 2
    quadratic = compute_signals(t, np.zeros(len(t)), bend).temperature_rate
    first = compute_signals(t, np.zeros(len(t)), bend,
                            filters=SignalFilters(FIRST_ORDER_TAU_S, 0.5, FIRST_ORDER)).temperature_rate
    late = t > 30 * TAU_S
    true = 2 * curvature * t[late]
    # Sampled, it reads the slope half a step back (0.05 s), where the first-order filter reads it 120 s back.
    assert np.max(np.abs(quadratic[late] - true)) < 1.001 * 2 * curvature * 0.05
    assert np.min(np.abs(first[late] - true)) > 0.9 * 2 * curvature * FIRST_ORDER_TAU_S   # lags by tau


def test_slope_change_followed_within_seven_time_constants() -> None:
    """A hold then 1 degC/min in 0.05 degC counts: within 5 % of the slope 7 tau (140 s) after it starts.

    Today's first-order filter (120 s) is 5 % off for 6.5 min: the lag the Shupe correction paid at every ramp.
    """
    t = np.arange(0.0, 3600.0, 0.1)
    x = np.round((15.0 + np.maximum(t - 600.0, 0.0) / 60.0) / 0.05) * 0.05
    since = t - 600.0
    for filters, within_s in ((SignalFilters(), 7 * TAU_S),
                              (SignalFilters(FIRST_ORDER_TAU_S, 0.5, FIRST_ORDER), 3.5 * FIRST_ORDER_TAU_S)):
        error = np.abs(compute_signals(t, np.zeros(len(t)), x, filters=filters).temperature_rate * 60.0 - 1.0)
        assert np.max(error[since > within_s]) < 0.05, filters
        assert np.max(error[(since > within_s - 30.0) & (since < within_s)]) > 0.05, filters   # not much sooner


def test_bounded_by_five_spans_over_tau() -> None:
    """The bound the calibration's envelope check takes (signals._temperature_rate_range) holds on full-span steps."""
    rng = np.random.default_rng(2)
    t = np.cumsum(rng.choice([0.0, 0.001, 0.1, 50.0], 20000))
    x = rng.choice([10.0, 50.0], 20000)
    rate = compute_signals(t, np.zeros(len(t)), x, filters=SignalFilters(5.0)).temperature_rate
    assert np.max(np.abs(rate)) <= 5.0 * 40.0 / 5.0


def test_an_old_file_keeps_its_first_order_filter(tmp_path: Path) -> None:
    """A file that names no form is read as today's first-order filter, and gives today's numbers exactly."""
    packaged = load_packaged_calibration('NAVC3545')
    assert packaged.filters == SignalFilters(FIRST_ORDER_TAU_S, 0.5, FIRST_ORDER)
    t = np.arange(0.0, 1200.0, 0.1)
    x = np.round((20.0 + 3.0 * (1.0 - np.exp(-t / 300.0))) / 0.05) * 0.05
    rate = compute_signals(t, np.zeros(len(t)), x, filters=packaged.filters).temperature_rate
    level = np.concatenate((x[:1], first_order_smooth(x, -np.diff(t) / FIRST_ORDER_TAU_S)))
    np.testing.assert_array_equal(rate, (x - level) / FIRST_ORDER_TAU_S)
    path = tmp_path / 'old.yaml'
    text = dump_calibration(packaged)
    assert 'temperature_rate_form: first_order' in text   # written back as what it is
    path.write_text(text.replace('temperature_rate_form: first_order', ''), encoding='utf-8')
    assert load_calibration(path).filters == packaged.filters


def test_a_new_fit_writes_the_local_quadratic_fit(tmp_path: Path) -> None:
    """What a fit writes (SignalFilters()) reads back as itself; a misspelt form is refused naming the key."""
    calibration = load_packaged_calibration('NAVC3545')
    path = tmp_path / 'new.yaml'
    path.write_text(dump_calibration(dataclasses.replace(calibration, filters=SignalFilters())), encoding='utf-8')
    assert load_calibration(path).filters == SignalFilters() and SignalFilters().temperature_rate_form == \
        LOCAL_QUADRATIC
    path.write_text(path.read_text(encoding='utf-8').replace(LOCAL_QUADRATIC, 'local_quartic'), encoding='utf-8')
    with pytest.raises(ValueError, match="filters.temperature_rate_form must be one of first_order, "
                                         "local_quadratic, got 'local_quartic'"):
        load_calibration(path)


def test_the_node_corrects_a_shupe_gyro_near_the_true_rate() -> None:
    """A Shupe gyro (2.4 deg/s per degC/s) in a chamber swinging 5 degC over an hour, as the node applies its file.

    With the true coefficient, the first-order filter's 120 s lag left 11 deg/h rms; the local quadratic fit
    leaves about 1 (the 0.05 degC counts' noise), where the same correction on the true rate leaves 0.1.
    """
    t = np.arange(0.0, 7200.0, 0.1)
    w = 2 * np.pi / 3600.0
    true, true_rate = 20.0 + 5.0 * np.sin(w * t), 5.0 * w * np.cos(w * t)
    packaged = load_packaged_calibration('NAVC3545')
    log = GyroLog(t, measured_from_true(packaged.polynomial, 2.4 * true_rate, true), np.round(true / 0.05) * 0.05)
    rms = {}
    for filters in (SignalFilters(FIRST_ORDER_TAU_S, 0.5, FIRST_ORDER), SignalFilters()):
        calibration = dataclasses.replace(packaged, terms=(Term('temperature_rate', 'power', (2.4,), (1,)),),
                                          filters=filters)
        corrected = apply_calibration(log, calibration, 100, start=RunStart(powered_on_at_start=True)).corrected_dps
        rms[filters.temperature_rate_form] = float(np.sqrt(np.mean(corrected[100:] ** 2))) * 3600.0
    assert rms[FIRST_ORDER] > 8.0
    assert rms[LOCAL_QUADRATIC] < 2.0
