"""Start-up safety of the extended terms, as the node and ``calibrate apply`` apply them."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest

from art_gyro_calibration.calibration import Calibration, load_packaged_calibration
from art_gyro_calibration.calibration import load_calibration
from art_gyro_calibration.compensation import (BEYOND_RANGE, CLIPPED, IMPLAUSIBLE_TEMPERATURE, Compensator,
                                               FrameCorrector, RunStart, apply_calibration, usable_rates)
from art_gyro_calibration.gyro_physics import measured_from_true
from art_gyro_calibration.log import GyroLog
from art_gyro_calibration.signals import SignalFilters, compute_signals
from art_gyro_calibration.static_bias import StaticBiasCollector
from art_gyro_calibration.temperature_rate import FIRST_ORDER
from art_gyro_calibration.terms import Term

RATE_HZ = 10.0
BIAS_SAMPLES = 100
DPH = 3600.0


def _calibration(*terms: Term, tau_s: float = 120.0) -> Calibration:
    base = load_packaged_calibration('NAVC3545')
    return dataclasses.replace(base, terms=terms, filters=SignalFilters(tau_s, temperature_rate_form=FIRST_ORDER))


def _still_run(hours: float, temp: np.ndarray | None = None, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    t = np.arange(int(hours * 3600 * RATE_HZ)) / RATE_HZ
    return t, np.full(len(t), 25.0) if temp is None else temp


def _per_sample(calibration: Calibration, log: GyroLog, start: RunStart) -> np.ndarray:
    """What the node publishes once its startup static bias is taken (from frame BIAS_SAMPLES - 1 on)."""
    from art_gyro_calibration.static_bias import StaticBiasCollector
    comp = Compensator(calibration, start)
    collector = StaticBiasCollector(BIAS_SAMPLES, keep_window=comp.refinable)
    out = []
    for t, rate, temp in zip(log.t, log.rate_dps, log.temp_c):
        error = comp.error(t, rate, temp)
        if collector is not None and collector.add(rate, error, t, temp, comp.causal_dps()):
            comp.bias, collector = collector.result(), None
        out.append(comp.correct(rate, error))
    return np.array(out[BIAS_SAMPLES - 1:])


def test_a_warm_restart_with_a_warm_up_term_is_no_worse_than_the_report_calibration() -> None:
    """A node restarted on a warm gyro must not replay the warm-up into its static bias.

    The gyro's true error is the polynomial plus a warm-up that decayed hours ago; the run starts
    3 h after power-on. With the warm-up counted from the node's start (the old behaviour) the
    static bias absorbed its full 0.02 deg/s amplitude: 72 deg/h for the whole mission.
    """
    warm_up = Term('time_since_power_on', 'exp_decay', (0.02,), (), 1200.0)
    t, temp = _still_run(1.0)
    true_rate = np.zeros(len(t))
    art = _calibration()
    measured = measured_from_true(art.polynomial, true_rate, temp)   # the warm-up is long gone
    log = GyroLog(t, measured, temp)
    for start in (RunStart(), RunStart(powered_on_at_start=False)):
        report_only = apply_calibration(log, art, BIAS_SAMPLES, start=start).corrected_dps
        extended = apply_calibration(log, _calibration(warm_up), BIAS_SAMPLES, start=start).corrected_dps
        assert abs(extended.mean()) * DPH <= abs(report_only.mean()) * DPH + 0.01
    # Anchoring the warm-up at the run's start is what a node restart did: now only on a declared cold start.
    anchored = apply_calibration(log, _calibration(warm_up), BIAS_SAMPLES,
                                 start=RunStart(powered_on_at_start=True)).corrected_dps
    assert abs(anchored[-100:].mean()) * DPH > 50.0


def test_a_cold_start_with_a_warm_up_term_removes_it() -> None:
    """Told the gyro was powered on with the run, the warm-up is corrected from the first sample."""
    warm_up = Term('time_since_power_on', 'exp_decay', (0.02,), (), 1200.0)
    t, temp = _still_run(1.0)
    art = _calibration()
    measured = measured_from_true(art.polynomial, 0.02 * np.exp(-t / 1200.0), temp)
    log = GyroLog(t, measured, temp)
    cold = RunStart(powered_on_at_start=True)
    extended = apply_calibration(log, _calibration(warm_up), BIAS_SAMPLES, start=cold).corrected_dps
    report_only = apply_calibration(log, art, BIAS_SAMPLES, start=cold).corrected_dps
    assert np.abs(extended).max() * DPH < 0.1
    assert np.abs(report_only[-100:]).mean() * DPH > 60.0   # the static bias kept the warm-up's start
    np.testing.assert_allclose(_per_sample(_calibration(warm_up), log, cold), extended[BIAS_SAMPLES - 1:],
                               rtol=0, atol=1e-12)


def _self_heating(hours: float = 1.0, heating_c: float = 6.0, tau_s: float = 600.0,
                  shupe: float = 0.5) -> tuple[GyroLog, float, np.ndarray]:
    """A freshly powered gyro warming by ``heating_c`` with time constant ``tau_s``, a Shupe effect of ``shupe``.

    By default 6 degC in 10 minutes: dT/dt starts at 0.01 degC/s, and 0.5 deg/s per degC/s makes 0.005 deg/s
    (18 deg/h) at power-on. The temperature in 0.05 degC counts.
    """
    t = np.arange(int(hours * 3600 * RATE_HZ)) / RATE_HZ
    temp = 20.0 + heating_c * (1.0 - np.exp(-t / tau_s))
    true_rate_of_temp = heating_c / tau_s * np.exp(-t / tau_s)
    art = _calibration()
    measured = measured_from_true(art.polynomial, shupe * true_rate_of_temp, temp)
    return GyroLog(t, measured, np.round(temp / 0.05) * 0.05), shupe, true_rate_of_temp


def test_the_static_bias_is_refined_once_the_temperature_rate_is_known() -> None:
    """The Shupe error of the bias window is not absorbed for the whole mission (20+ deg/h).

    Over the first 10 s the causal filter reads about 0 degC/s while the gyro self-heats; the
    static bias takes the window's Shupe error with it. Refined after 3 filter time constants,
    the error is what the model leaves, as on a gyro whose filter had run for ever.
    """
    log, shupe, _ = _self_heating()
    cal = _calibration(Term('temperature_rate', 'power', (shupe,), (1,)))
    applied = apply_calibration(log, cal, BIAS_SAMPLES)
    after = log.t > 3600 * 0.5
    assert applied.bias.refined_dps == pytest.approx(0.005, rel=0.15)
    # Without the refinement the whole mission carried the window's -0.005 deg/s (18 deg/h).
    unrefined = dataclasses.replace(applied.bias, refined_dps=0.0,
                                    calc_static_bias_drift_dps=applied.bias.calc_static_bias_drift_dps
                                    - applied.bias.refined_dps)
    before = unrefined.correct(log.rate_dps, applied.comp_dps)
    assert abs(before[after].mean()) * DPH > 15.0
    assert abs(applied.corrected_dps[after].mean()) * DPH < 3.0
    # The node refines the same way, sample by sample, and so do chunks of the log.
    np.testing.assert_allclose(_per_sample(cal, log, RunStart()), applied.corrected_dps[BIAS_SAMPLES - 1:],
                               rtol=0, atol=1e-9)
    chunks = None
    parts = []
    for a, b in ((0, 150), (150, 2000), (2000, 3700), (3700, len(log))):
        chunks = apply_calibration(log.slice(slice(a, b)), cal, BIAS_SAMPLES, after=chunks)
        parts.append(chunks.corrected_dps)
    np.testing.assert_allclose(np.concatenate(parts), applied.corrected_dps, rtol=0, atol=1e-9)


def test_a_fast_self_heating_is_refined_without_a_lasting_bias() -> None:
    """6 degC with a 5-minute time constant (the loop study's fastest profile).

    A quadratic over the refinement's 6 minutes read the window's temperature rate 9 % low: the
    node carried -3.7 deg/h of the 0.6 deg/s per degC/s Shupe effect for the whole mission.
    """
    log, shupe, _ = _self_heating(tau_s=300.0, shupe=0.6)
    cal = _calibration(Term('temperature_rate', 'power', (shupe,), (1,)))
    applied = apply_calibration(log, cal, BIAS_SAMPLES, start=RunStart(powered_on_at_start=True))
    assert abs(applied.corrected_dps[log.t > 1800.0].mean()) * DPH < 1.0   # -0.45 deg/h
    np.testing.assert_allclose(_per_sample(cal, log, RunStart(powered_on_at_start=True)),
                               applied.corrected_dps[BIAS_SAMPLES - 1:], rtol=0, atol=1e-9)


def test_until_the_refinement_the_temperature_rate_terms_follow_its_provisional_fit() -> None:
    """The minutes between the bias window and its refinement carry no Shupe error twice.

    The static bias took the window's true Shupe error (the causal filter read about 0 there);
    as the filter rose over its first minutes the model subtracted that error again: up to
    -0.0045 deg/s (-16 deg/h) for six minutes after each cold start. Held at their window mean
    until the refinement, the terms left how far the true error moved since: -5.7 deg/h on average
    from the second minute to the sixth, up to -8. After a minute they follow the slope of the
    refinement's provisional fit, and leave under 1.5 deg/h.
    """
    log, shupe, true_rate = _self_heating()
    cal = _calibration(Term('temperature_rate', 'power', (shupe,), (1,)))
    applied = apply_calibration(log, cal, BIAS_SAMPLES, start=RunStart(powered_on_at_start=True))
    t = log.t
    first = (t >= BIAS_SAMPLES / RATE_HZ) & (t < 60.0)   # held: the provisional fit needs a minute
    moved = shupe * (true_rate[first] - true_rate[:BIAS_SAMPLES].mean())
    np.testing.assert_allclose(applied.corrected_dps[first], moved, rtol=0, atol=0.0006)
    minutes = (t >= 60.0) & (t < 360.0)
    assert np.max(np.abs(applied.corrected_dps[minutes])) * DPH < 1.5
    # The node does the same, frame by frame.
    np.testing.assert_allclose(_per_sample(cal, log, RunStart(powered_on_at_start=True)),
                               applied.corrected_dps[BIAS_SAMPLES - 1:], rtol=0, atol=1e-9)


def test_a_slow_warm_up_in_temperature_counts_does_not_swing_the_provisional_fit() -> None:
    """2 degC over 25 minutes crosses a 0.05 degC count every half minute or so.

    Fitted from the window on, a cubic through the first of those steps swung the Shupe term by
    34 deg/h (measured); from a minute on, the swing stays under 4 deg/h.
    """
    log, shupe, _ = _self_heating(hours=0.5, heating_c=2.0, tau_s=1500.0, shupe=0.6)
    cal = _calibration(Term('temperature_rate', 'power', (shupe,), (1,)))
    applied = apply_calibration(log, cal, BIAS_SAMPLES, start=RunStart(powered_on_at_start=True))
    assert np.max(np.abs(applied.corrected_dps[BIAS_SAMPLES:])) * DPH < 4.0


def test_temperatures_outside_the_calibrated_range_are_clamped_and_counted() -> None:
    """Outside a fitted file's temperature_range_c the model is evaluated at the range's edge; samples counted."""
    cal = dataclasses.replace(_calibration(Term('temperature_lag', 'power', (1e-3,), (1,), 60.0)),
                              temperature_range_c=(10.0, 50.0), temperature_warn_range_c=None)
    high = 50.0
    t = np.arange(200) / RATE_HZ
    temp = np.where(t < 10, 30.0, high + 15.0)
    rate = np.full(len(t), 5.0)
    comp = Compensator(cal)
    errors = [comp.error(a, b, c) for a, b, c in zip(t, rate, temp)]
    assert comp.outside_range == int(np.sum(temp > high))
    edge = cal.polynomial.error(np.array([5.0]), np.array([high]))[0]
    lag_edge = 1e-3 * min(compute_signals(t, rate, temp).lagged_temperature(60.0)[-1], high)
    assert errors[-1] == pytest.approx(edge + lag_edge, abs=1e-12)
    applied = apply_calibration(GyroLog(t, rate, temp), cal, 50, max_mean_dps=10.0)   # turning at 5 deg/s
    assert applied.outside_range == comp.outside_range
    np.testing.assert_allclose(applied.comp_dps, errors, rtol=0, atol=1e-12)


def test_a_report_calibration_is_counted_outside_its_warn_range_but_never_clamped() -> None:
    """The report prints no range: its polynomial applies at every temperature; the warn range only counts."""
    cal = load_packaged_calibration('NAVC4058')
    assert cal.temperature_range_c is None and cal.temperature_warn_range_c == (10.0, 50.0)
    t = np.arange(300) / RATE_HZ
    temp = np.linspace(-40.0, 85.0, len(t))
    rate = np.full(len(t), 20.0)
    comp = Compensator(cal)
    errors = [comp.error(a, b, c) for a, b, c in zip(t, rate, temp)]
    np.testing.assert_allclose(errors, cal.polynomial.error(rate, temp), rtol=0, atol=1e-12)
    assert comp.outside_range == int(np.sum((temp < 10.0) | (temp > 50.0))) > 0
    applied = apply_calibration(GyroLog(t, rate, temp), cal, 50, max_mean_dps=100.0)
    np.testing.assert_allclose(applied.comp_dps, errors, rtol=0, atol=1e-12)
    assert applied.outside_range == comp.outside_range


def test_the_frame_corrector_publishes_what_apply_gives_and_drops_what_it_drops() -> None:
    """The node's per-frame step (raw counts in) against ``calibrate apply`` on the same frames, ROS aside.

    Warming and turning, every signal the node tracks, a refinement within the run, and two frames whose
    temperature no gyro survives and three clipped rates: dropped by both, counted by the corrector.
    """
    cal = dataclasses.replace(load_packaged_calibration('NAVC3545'), terms=(
        Term('temperature_rate', 'power', (0.02,), (1,)), Term('time', 'power', (1e-4,), (1,)),
        Term('time_since_power_on', 'exp_decay', (0.03,), (), 5.0),
        Term('temperature_lag', 'power', (1e-4, 2e-5), (1,), 3.0, (0, 1)),
        Term('rate_change', 'power', (0.002,), (1,))), filters=SignalFilters(0.2, temperature_rate_form=FIRST_ORDER))
    n, rate_hz = 20, 50.0
    t = np.arange(1500) / rate_hz
    raw_rate = np.where(t < 2.0, np.arange(t.size) % 3 - 1, np.round(30.0 * np.sin(t) / cal.rate_scale_factor))
    raw_rate = raw_rate.astype(int)   # still: +-1 count of noise (a rate without any is refused as no gyro's)
    raw_temp = np.round((20.0 + 0.5 * t) / cal.temp_scale_factor).astype(int)
    raw_temp[[700, 900]] = 4000, -1400   # 200, -70 degC
    raw_rate[[1000, 1100, 1200]] = 32767, -32768, -32767   # clipped: the turn is beyond the range
    start = RunStart(powered_on_at_start=True)

    def collected(collector: StaticBiasCollector) -> None:
        corrector.compensator.bias, corrector.collector = collector.result(), None

    corrector = FrameCorrector(cal, start)
    corrector.collect(StaticBiasCollector(n, keep_window=corrector.compensator.refinable), collected)
    published, reasons = [], []
    for ti, r, temp in zip(t.tolist(), raw_rate.tolist(), raw_temp.tolist()):
        reason = corrector.step(r, temp, ti)
        reasons.append(reason)
        if not reason:
            published.append(corrector.rate_dps)
    assert [i for i, r in enumerate(reasons) if r] == [700, 900, 1000, 1100, 1200]
    assert reasons[700] == IMPLAUSIBLE_TEMPERATURE and reasons[1000] == CLIPPED
    assert corrector.dropped == {IMPLAUSIBLE_TEMPERATURE: 2, CLIPPED: 3, BEYOND_RANGE: 0, 'not_finite': 0}
    # apply keeps clipped rows (calibrate fit excludes them first, as usable_rates says): here they are left out.
    rows = usable_rates(raw_rate * cal.rate_scale_factor, cal.rate_scale_factor)
    t, raw_rate, raw_temp = t[rows], raw_rate[rows], raw_temp[rows]
    applied = apply_calibration(GyroLog(t, raw_rate * cal.rate_scale_factor, raw_temp * cal.temp_scale_factor),
                                cal, n, max_mean_dps=1.0, start=start)
    assert applied.bias.refined_dps and corrector.compensator.bias.refined_dps
    rate = raw_rate[applied.kept] * cal.rate_scale_factor
    # The corrector had no static bias for its first n - 1 frames.
    expected = np.concatenate((rate[:n - 1] - applied.comp_dps[:n - 1], applied.corrected_dps[n - 1:]))
    np.testing.assert_allclose(published, expected, rtol=0, atol=2e-9)
    assert corrector.compensator.outside_range == applied.outside_range


def test_rates_beyond_a_kvh_units_range_are_dropped() -> None:
    """kvh_fog values with good CRCs published as 1000 deg/s .. 1.7e42 deg/s (a DSP-1760 reads +-490)."""
    cal = load_calibration(Path(__file__).resolve().parent.parent / 'config' / 'KVH_DSP1760_EXAMPLE.yaml')
    corrector = FrameCorrector(cal)
    rates = [10.0, 489.9, -490.0, 490.5, 1000.0, -5.7e7, 1.7e42, 30.0]
    reasons = [corrector.step(r, 25.0, 0.001 * i) for i, r in enumerate(rates)]
    assert reasons == ['', '', '', BEYOND_RANGE, BEYOND_RANGE, BEYOND_RANGE, BEYOND_RANGE, '']
    assert corrector.dropped[BEYOND_RANGE] == 4 and corrector.rate_dps == 30.0
    np.testing.assert_array_equal(usable_rates(np.array(rates), cal.rate_scale_factor), [r == '' for r in reasons])
    # An RD2100 log: the clipped counts are not usable; a simulated table beyond the counts' range is kept.
    scale = 0.00305
    counts = np.array([0, 32766, 32767, -32767, -32768, 32787, -33204])
    np.testing.assert_array_equal(usable_rates(counts * scale, scale), [True, True, False, False, False, True, True])
