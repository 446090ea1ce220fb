"""The scaled least-squares fit recovers the report's polynomial (up to its constant)."""

import numpy as np
import pytest

from art_gyro_calibration.calibration import load_packaged_calibration
from art_gyro_calibration.analysis.fit import Scaling, TermSpec, fit_model, polynomial_basis, polynomial_from_scaled
from art_gyro_calibration.analysis.metrics import steady_segments
from art_gyro_calibration.model import ArtPolynomial
from art_gyro_calibration.signals import compute_signals
from art_gyro_calibration.analysis.simulate import SimulationSettings, simulate_run


def simulated(serial, hours=3.0, rate_hz=2.0, seed=11, effects=()):
    cal = load_packaged_calibration(serial)
    run = simulate_run(cal, SimulationSettings(hours=hours, rate_hz=rate_hz, seed=seed, effects=effects))
    return cal, run.log(cal)


def test_scaled_basis_maps_back_exactly():
    rng = np.random.default_rng(2)
    coef = rng.standard_normal((3, 4)) * np.array([[1e-9, 1e-7, 1e-5, 1e-3]]).T[:3] * 10
    poly = ArtPolynomial(coef)
    temp = rng.uniform(10, 50, 500)
    rate = rng.uniform(-100, 100, 500)
    scaling = Scaling.of(temp, rate)
    basis = polynomial_basis(rate, temp, 3, 4, scaling)
    beta = np.linalg.lstsq(basis, poly.error(rate, temp), rcond=None)[0]
    back = polynomial_from_scaled(beta, 3, 4, scaling)
    np.testing.assert_allclose(back.coefficients, coef, rtol=1e-6, atol=1e-18)


@pytest.mark.parametrize('serial', ['NAVC3545', 'NAVC4058'])
def test_fit_recovers_the_report_polynomial_up_to_the_constant(serial):
    cal, log = simulated(serial)
    signals = compute_signals(log.t, log.rate_dps, log.temp_c)
    seg = steady_segments(log.t, log.ref_rate)
    fit = fit_model(signals, log.rate_dps - log.ref_rate, cal.polynomial.rows, cal.polynomial.columns,
                    index=seg.rows())
    got, want = fit.model.polynomial.coefficients, cal.polynomial.coefficients
    # Every coefficient but the constant (T^0 r^0, last row and column): that one absorbs the
    # run's turn-on bias and the Earth's rate, which the static bias removes in use.
    mask = np.ones_like(want, dtype=bool)
    mask[-1, -1] = False
    scale = np.abs(want[mask]).max(axis=None)
    # Compare the surfaces over the calibrated range, up to a constant.
    temp, rate = np.meshgrid(np.linspace(10, 50, 9), np.linspace(-100, 100, 21))
    diff = fit.model.polynomial.error(rate, temp) - cal.polynomial.error(rate, temp)
    assert np.ptp(diff) < 2e-3, f'recovered surface differs by {np.ptp(diff)} deg/s'
    # Coefficients with a material effect over the range are recovered to a few per cent.
    for j in range(want.shape[0]):
        for i in range(want.shape[1]):
            if not mask[j, i]:
                continue
            reach = abs(want[j, i]) * 50.0 ** (want.shape[0] - 1 - j) * 100.0 ** (want.shape[1] - 1 - i)
            if reach > 0.02:
                assert got[j, i] == pytest.approx(want[j, i], rel=0.05), (j, i)
    assert scale > 0


def test_too_few_samples_is_an_error():
    cal, log = simulated('NAVC4058', hours=0.01, rate_hz=1.0)
    signals = compute_signals(log.t, log.rate_dps, log.temp_c)
    with pytest.raises(ValueError, match='cannot determine'):
        fit_model(signals, log.rate_dps - log.ref_rate, 3, 2, [TermSpec('time', 'exp_decay', (), 10.0)],
                  index=np.arange(5))


def test_a_term_on_a_signal_far_from_zero_is_recovered():
    """A pressure-like extra column (1e5 +- 50) fits as well as the same column near zero: centring keeps it posed."""
    cal, log = simulated('NAVC3545', hours=2.0)
    wiggle = 50 * np.sin(log.t / 100.0) + np.random.default_rng(3).normal(0, 1, len(log))
    error = log.rate_dps - log.ref_rate + 2e-5 * wiggle
    seg = steady_segments(log.t, log.ref_rate)
    found = []
    for offset in (0.0, 1e5):
        signals = compute_signals(log.t, log.rate_dps, log.temp_c, {'pressure': offset + wiggle})
        fit = fit_model(signals, error, 3, 4, [TermSpec('pressure', 'power', (1,))], seg.rows())
        found.append(fit.model.terms[0].coefficients[0])
        # The model predicts the error itself (constant included), not just its shape.
        np.testing.assert_allclose(fit.model.error(signals)[fit.index] + fit.residual, error[fit.index], atol=1e-9)
    assert found[1] == pytest.approx(found[0], rel=1e-6)
    assert found[1] == pytest.approx(2e-5, rel=0.1)


def test_each_run_has_its_own_turn_on_bias_and_the_polynomial_is_shared():
    """Two runs, each with its own constant: the shared polynomial and each run's offset, none written."""
    rng = np.random.default_rng(3)
    t = np.arange(4000.0)
    temp = np.concatenate([15.0 + 0.005 * t[:2000], 25.0 + 0.005 * t[:2000]])   # the runs overlap in 20..25 degC
    rate = rng.choice([-50.0, -10.0, 0.0, 10.0, 50.0], 4000)
    polynomial = ArtPolynomial(np.array([[1e-5, 2e-4], [-3e-4, 0.002]]))   # [[T r, T], [r, 1]]
    turn_on = np.where(np.arange(4000) < 2000, 0.0, 0.004)
    error = polynomial.error(rate, temp) + turn_on
    runs = compute_signals(t, rate, temp, run_starts=((0, True), (2000, True)))
    fit = fit_model(runs, error, 2, 2)
    np.testing.assert_allclose(fit.model.polynomial.coefficients, polynomial.coefficients, rtol=1e-6, atol=1e-12)
    assert fit.run_offsets_dps == pytest.approx((0.0, 0.004), abs=1e-9)
    # As one run, the second run's bias is read as a temperature slope.
    one = fit_model(compute_signals(t, rate, temp), error, 2, 2)
    assert one.run_offsets_dps == ()
    assert abs(one.model.polynomial.coefficients[0, 1] - 2e-4) > 1e-4


def test_a_shupe_coefficient_on_the_node_s_noisy_temperature_rate_is_not_biased_toward_zero():
    """The causal temperature rate from 0.05 degC counts is noisy: least squares on every row read 2.4 as 2.26.

    Its columns are instrumented by their 60 s means (the module's docstring): the coefficient is the true one.
    """
    rng = np.random.default_rng(7)
    t = np.arange(0.0, 6 * 3600.0, 0.1)
    # Chamber ramps of 0.1 degC/min between holds, the gyro's temperature logged in 0.05 degC counts.
    knots_t = np.cumsum([0.0, 1200.0, 6000.0, 1800.0, 6000.0, 1800.0, 6000.0])
    knots_c = [20.0, 20.0, 30.0, 30.0, 20.0, 20.0, 30.0]
    true_c = np.interp(t, knots_t, knots_c)
    true_rate = np.gradient(true_c, t)
    temp = np.round(true_c / 0.05) * 0.05
    error = 2.4 * true_rate + 0.005 * rng.standard_normal(len(t))
    signals = compute_signals(t, np.zeros(len(t)), temp)
    spec = TermSpec('temperature_rate', 'power', (1,))
    [term] = fit_model(signals, error, 1, 1, [spec]).model.terms
    assert term.coefficients[0] == pytest.approx(2.4, rel=0.02)
