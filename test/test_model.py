"""The model against straight transcriptions of the report's C program (Python and gcc)."""

import math
from pathlib import Path

import numpy as np
import pytest
from c_reference import compile_reference, run_reference

from art_gyro_calibration.calibration import load_packaged_calibration
from art_gyro_calibration.compensation import Compensator, apply_calibration
from art_gyro_calibration.gyro_physics import measured_from_true
from art_gyro_calibration.log import GyroLog
from art_gyro_calibration.model import ArtPolynomial, Continuation, ErrorModel
from art_gyro_calibration.signals import SignalTracker, compute_signals

RATES = np.linspace(-100.0, 100.0, 41)     # the RD2100's full scale, deg/s
TEMPS = np.linspace(-10.0, 60.0, 15)       # beyond the calibrated range on both sides, degC


def comp_function_transcribed(coef: list[list[float]], gyro_rate: float, gyro_temp: float) -> float:
    """CompFunction() of the report, line by line, in single precision like the C floats."""
    f = np.float32
    rows, columns = len(coef), len(coef[0])
    sum_t = [f(0)] * columns
    comp = f(0)
    for i in range(columns):
        sum_t[i] = f(0)
        for j in range(rows):
            aux = f(math.pow(f(gyro_temp), rows - j - 1)) if rows - j - 1 else f(1)
            sum_t[i] = f(sum_t[i] + f(aux * f(coef[j][i])))
    for i in range(columns):
        aux = f(math.pow(f(gyro_rate), columns - i - 1)) if columns - i - 1 else f(1)
        comp = f(comp + f(aux * sum_t[i]))
    return float(comp)


def test_comp_matches_the_transcription_over_the_whole_range(serial: str) -> None:
    poly = load_packaged_calibration(serial).polynomial
    coef = poly.coefficients.tolist()
    rate, temp = np.meshgrid(RATES, TEMPS)
    expected = np.vectorize(lambda r, t: comp_function_transcribed(coef, r, t))(rate, temp)
    scale = np.abs(expected).max()
    assert scale > 1e-3  # the error surface is not trivially zero
    np.testing.assert_allclose(poly.error(rate, temp), expected, rtol=0, atol=2e-6 * max(scale, 1.0))
    one = np.vectorize(poly.error_one)(rate, temp)
    np.testing.assert_allclose(one, poly.error(rate, temp), rtol=1e-12, atol=1e-15)


def test_rows_are_temperature_powers_and_columns_rate_powers() -> None:
    # Only coef[0][1] set: the term temp**(rows-1) * rate**(columns-2).
    c = np.zeros((3, 4))
    c[0, 1] = 1.0
    assert ArtPolynomial(c).error_one(2.0, 3.0) == pytest.approx(3.0 ** 2 * 2.0 ** 2)
    assert ArtPolynomial([[1.0]]).error(np.array([5.0, -7.0]), 30.0).tolist() == [1.0, 1.0]


@pytest.mark.parametrize('bad', [[[]], [[1.0, float('nan')]], [[float('inf')]]])
def test_bad_coefficients_are_refused(bad: list[list[float]]) -> None:
    with pytest.raises(ValueError):
        ArtPolynomial(bad)


def test_measured_from_true_inverts_the_model(serial: str) -> None:
    poly = load_packaged_calibration(serial).polynomial
    rate, temp = np.meshgrid(RATES, TEMPS)
    measured = measured_from_true(poly, rate, temp)
    np.testing.assert_allclose(measured - poly.error(measured, temp), rate, atol=1e-9)


def _raw_run(serial: str, n: int = 3000, bias_samples: int = 100) -> tuple[np.ndarray, np.ndarray]:
    """Raw counts: still for the bias samples, then rates over the whole range and temperatures over -40..85 degC.

    A robot meets that (winter outdoors, a hot enclosure); the report prints no temperature range, so its
    program applies the polynomial at every temperature and the packaged files must too.
    """
    cal = load_packaged_calibration(serial)
    rng = np.random.default_rng(7)
    true = np.concatenate([np.zeros(bias_samples), rng.uniform(-100, 100, n - bias_samples)])
    temp = np.concatenate([np.full(bias_samples, 22.0), rng.uniform(-40, 85, n - bias_samples)])
    measured = measured_from_true(cal.polynomial, true, temp) + rng.normal(0, 0.005, n)
    raw_rate = np.round(measured / cal.rate_scale_factor).astype(np.int32)
    raw_temp = np.round(temp / cal.temp_scale_factor).astype(np.int32)
    return raw_rate, raw_temp


def _transcribed_program(serial: str, raw_rate: np.ndarray, raw_temp: np.ndarray,
                         bias_samples: int) -> tuple[np.ndarray, np.ndarray]:
    """StaticBias() then main() of the report, in Python single precision."""
    cal = load_packaged_calibration(serial)
    f = np.float32
    coef = cal.polynomial.coefficients.tolist()
    scale, tscale = f(cal.rate_scale_factor), f(cal.temp_scale_factor)
    sum_b = sum_c = f(0)
    for k in range(bias_samples):
        sum_b = f(sum_b + f(raw_rate[k]))
        sum_c = f(sum_c + f(comp_function_transcribed(coef, f(scale * f(raw_rate[k])), f(tscale * f(raw_temp[k])))))
    static_bias_drift = f(f(sum_b * scale) / f(bias_samples))
    calc_static_bias_drift = f(sum_c / f(bias_samples))
    comps, rates = [], []
    for k in range(len(raw_rate)):
        gyro_rate = f(scale * f(raw_rate[k]))
        comp = f(comp_function_transcribed(coef, gyro_rate, f(tscale * f(raw_temp[k]))))
        comps.append(comp)
        rates.append(f(f(f(gyro_rate - static_bias_drift) - comp) + calc_static_bias_drift))
    return np.array(comps, dtype=float), np.array(rates, dtype=float)


def test_comp_rate_matches_the_transcribed_program(serial: str) -> None:
    cal = load_packaged_calibration(serial)   # as shipped: the report's program has no clamp, nor may ours
    raw_rate, raw_temp = _raw_run(serial, n=600)
    comp_ref, rate_ref = _transcribed_program(serial, raw_rate, raw_temp, 100)
    log = GyroLog(np.arange(len(raw_rate)) * 0.1, raw_rate * cal.rate_scale_factor, raw_temp * 0.05)
    applied = apply_calibration(log, cal, bias_samples=100)
    np.testing.assert_allclose(applied.comp_dps, comp_ref, atol=2e-5)
    np.testing.assert_allclose(applied.corrected_dps, rate_ref, atol=5e-5)
    # The correction matters: it is far larger than the tolerance.
    assert np.abs(applied.corrected_dps - (log.rate_dps - applied.bias.static_bias_drift_dps)).max() > 0.01


@pytest.fixture(scope='module')
def c_reference(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The report's C program, compiled with gcc -O2."""
    return compile_reference(tmp_path_factory.mktemp('c'))


def test_comp_rate_matches_the_compiled_c_program(serial: str, c_reference: Path, tmp_path: Path) -> None:
    cal = load_packaged_calibration(serial)   # as shipped: the report's program has no clamp, nor may ours
    bias_samples = 100
    raw_rate, raw_temp = _raw_run(serial)
    out, _ = run_reference(c_reference, cal, raw_rate, raw_temp, bias_samples, tmp_path)

    log = GyroLog(np.arange(len(raw_rate)) * 0.1, raw_rate * cal.rate_scale_factor, raw_temp * 0.05)
    applied = apply_calibration(log, cal, bias_samples=bias_samples)
    np.testing.assert_allclose(applied.comp_dps[bias_samples:], out[:, 0], atol=2e-5)
    np.testing.assert_allclose(applied.corrected_dps[bias_samples:], out[:, 1], atol=5e-5)

    # The node's per-sample path gives the same numbers.
    comp = Compensator(cal)
    errors = []
    for k in range(len(raw_rate)):
        rate, temp = comp.scale(int(raw_rate[k]), int(raw_temp[k]))
        errors.append(comp.error(log.t[k], rate, temp))
    comp.bias = applied.bias
    per_sample = [comp.correct(r, e) for r, e in zip(log.rate_dps, errors)]
    np.testing.assert_allclose(per_sample, applied.corrected_dps, rtol=0, atol=1e-9)


def test_beyond_its_range_the_polynomial_is_continued_by_another_s_temperature_dependence() -> None:
    """A refit over 20..32 degC, held at its edges and carried on beyond them as the report's polynomial moves."""
    refit = ArtPolynomial([[1e-6, 2e-4], [3e-3, -0.01]])
    report = load_packaged_calibration('NAVC3545').polynomial
    model = ErrorModel(refit, (), (20.0, 32.0), Continuation(report))
    temp = np.linspace(0.0, 60.0, 121)
    rate = np.linspace(-100.0, 100.0, 121)
    edge = np.clip(temp, 20.0, 32.0)
    expected = refit.error(rate, edge) + report.error(rate, temp) - report.error(rate, edge)
    np.testing.assert_allclose(model.polynomial_error(rate, temp), expected, rtol=0, atol=1e-12)
    inside = (temp >= 20.0) & (temp <= 32.0)
    np.testing.assert_array_equal(model.polynomial_error(rate, temp)[inside], refit.error(rate, temp)[inside])
    # Its own calibrated range holds the continuing polynomial at that range's edge in turn.
    bounded = ErrorModel(refit, (), (20.0, 32.0), Continuation(report, (10.0, 40.0)))
    assert bounded.polynomial_error(50.0, 55.0) == pytest.approx(
        refit.error_one(50.0, 32.0) + report.error_one(50.0, 40.0) - report.error_one(50.0, 32.0), abs=1e-12)
    # The node's per-sample path gives the same.
    t = np.arange(temp.size) * 0.1
    signals = compute_signals(t, rate, temp)
    for model_ in (model, bounded):
        tracker = SignalTracker(powered_on_at_start=True)
        one = []
        for k in range(t.size):
            tracker.update(t[k], rate[k], temp[k])
            one.append(model_.error_one(tracker))
        np.testing.assert_allclose(one, model_.error(signals), rtol=0, atol=1e-12)
