"""The loop finds each simulated effect by its signal, untold, and finds nothing when nothing is there.

Runs are 6 h at 2 Hz (43,200 rows): long enough for several 15-minute held-out blocks per
fold over a few chamber cycles. The no-effect case runs seeds 100-102, which were not used
while the thresholds were chosen (development used seeds 0 and 1).
"""

import dataclasses

import numpy as np
import pytest

from art_gyro_calibration.calibration import load_packaged_calibration
from art_gyro_calibration.analysis.loop import NODE_SIGNALS, LoopOptions, close_loop
from art_gyro_calibration.analysis.simulate import EFFECTS, SimulationSettings, simulate_run
from art_gyro_calibration.analysis.metrics import steady_segments
from art_gyro_calibration.analysis.trace import Binned, mirrored_spectrum, phase_surrogates
from art_gyro_calibration.signals import compute_signals

HOURS, RATE_HZ = 6.0, 2.0


def run_loop(serial, effects=(), seed=7):
    cal = load_packaged_calibration(serial)
    sim = simulate_run(cal, SimulationSettings(hours=HOURS, rate_hz=RATE_HZ, seed=seed, effects=effects))
    return sim.truth, close_loop(sim.log(cal), cal.polynomial.rows, cal.polynomial.columns,
                                 LoopOptions(serial_number=serial))


@pytest.mark.parametrize('seed', [100, 101, 102])
def test_nothing_found_when_nothing_is_there(seed):
    """Nothing that matters is claimed on a run without an effect.

    Each round tests at the 1 % level, so one null run in a hundred may claim something by
    chance (research/doc/loop-validation.md counts them over 100 runs); such a claim must stay under
    1 deg/h, which no robot tells from its gyro's wander, and the model must be adequate.
    """
    _, result = run_loop('NAVC3545', seed=seed)
    assert all(e.score.effect_dph < 1.0 for e in result.effects), [e.term.describe() for e in result.effects]
    assert result.adequacy.model_adequate
    # The ART model alone is at the noise floor, held out.
    assert result.held_out_rms_art_dps < 1.05 * result.noise_floor_dps


@pytest.mark.parametrize('serial', ['NAVC3545', 'NAVC4058'])
@pytest.mark.parametrize('effect', sorted(EFFECTS))
def test_each_effect_is_found_by_its_signal(serial, effect):
    truth, result = run_loop(serial, (effect,))
    want = truth['effects'][effect]
    found = _found(result)   # a supply-voltage effect is found, and reported, not written (the node has no supply_v)
    assert [e.signal for e in found] == [want['signal']]
    term = found[0].term
    assert term.form == want['form']
    assert term.coefficients[0] == pytest.approx(want['coefficients'][0], rel=0.1)
    if term.form == 'exp_decay':
        assert term.time_constant_s == pytest.approx(want['time_constant_s'], rel=0.2)
    # Extended held-out error within 20 % of the noise floor; the effect mattered.
    assert result.held_out_rms_extended_dps < 1.2 * result.noise_floor_dps
    assert found[0].held_out_rms_without_dps > found[0].held_out_rms_with_dps
    assert result.extended.terms == ((term,) if term.signal in NODE_SIGNALS else ())


def _found(result):
    """Every effect the loop found: those written and those reported only (a supply voltage, a heading)."""
    return [*result.effects, *result.findings]


def test_all_effects_together():
    """Shupe, warm-up and supply voltage at once, over 12 h: each named, and the model at the noise floor, held out.

    Twelve hours are six chamber cycles. In 6 h the chance level, the residual's own spectrum with
    the other effects still in it, can hide the supply term behind the warm-up (research/doc/simulated-run.md).
    """
    cal = load_packaged_calibration('NAVC3545')
    sim = simulate_run(cal, SimulationSettings(hours=12.0, rate_hz=RATE_HZ, seed=8,
                                               effects=('shupe', 'warmup', 'supply_voltage')))
    result = close_loop(sim.log(cal), 3, 4, LoopOptions(serial_number='NAVC3545'))
    truth = sim.truth['effects']
    assert sorted(e.signal for e in _found(result)) == sorted(v['signal'] for v in truth.values())
    for e in _found(result):
        want = next(v for v in truth.values() if v['signal'] == e.signal)
        assert e.term.coefficients[0] == pytest.approx(want['coefficients'][0], rel=0.1)
    assert result.held_out_rms_extended_dps < 1.05 * result.noise_floor_dps
    np.testing.assert_array_less(result.held_out_rms_extended_dps, result.held_out_rms_art_dps)
    # The written model lacks the supply term (a finding: the node has no supply_v), and the form-free check
    # sees what it leaves against supply_v, and only that.
    assert [x.signal for x in result.adequacy.signals if x.found] == ['supply_v']
    assert not result.adequacy.model_adequate


def _loop_with_columns(effects, columns, seed=7, hours=HOURS, effect_sizes=None, **loop_options):
    """The loop on a simulated run with extra log columns made from it (``columns``: name -> f(log))."""
    cal = load_packaged_calibration('NAVC3545')
    sim = simulate_run(cal, SimulationSettings(hours=hours, rate_hz=RATE_HZ, seed=seed, effects=effects,
                                               effect_sizes=effect_sizes or {}))
    log = sim.log(cal)
    log = dataclasses.replace(log, extras={**log.extras, **{name: f(log) for name, f in columns.items()}})
    return sim.truth, close_loop(log, 3, 4, LoopOptions(serial_number='NAVC3545', **loop_options))


def test_a_column_carrying_the_temperature_does_not_mask_the_shupe_effect():
    """A chamber set-point beside the gyro temperature: the Shupe effect is still found, on temperature_rate."""
    _, result = _loop_with_columns(('shupe',), {'chamber_setpoint': lambda log: np.round(log.temp_c)})
    assert [e.signal for e in result.effects] == ['temperature_rate']


def test_two_voltmeters_on_one_rail_do_not_explain_each_other_away():
    """Two columns with the same supply voltage: the supply effect is found on one of them, once."""
    rng = np.random.default_rng(3)
    _, result = _loop_with_columns(('supply_voltage',),
                                   {'supply_v2': lambda log: log.extras['supply_v'] + rng.normal(0, 0.002, len(log))})
    assert [e.signal for e in _found(result)] in (['supply_v'], ['supply_v2'])


@pytest.mark.parametrize('seed', [7, 8])
def test_a_small_warm_up_is_not_diluted_by_a_long_log(seed):
    """A 5e-3 deg/s warm-up (18 deg/h, a quarter of the simulated one) is found in a 6 h log.

    Materiality is in deg/h, not a share of the log (the per-sample materiality missed a
    3e-3 warm-up in 6 h logs). At 2 Hz such a warm-up is at the edge of chance (p = 0.01
    and 0.025 with these seeds; a 3e-3 one is found in 4 of 10 seeds): tested at the 5 %
    level, as the materiality is what this test is about; research/doc/loop-validation.md measures
    the power at the default level.
    """
    _, result = _loop_with_columns(('warmup',), {}, seed=seed, effect_sizes={'warmup': 0.005}, alpha=0.05)
    assert [e.term.form for e in result.effects] == ['exp_decay']
    assert result.effects[0].term.coefficients[0] == pytest.approx(0.005, rel=0.3)


def test_phase_surrogates_keep_the_spectrum_and_lose_the_alignment():
    """Each surrogate has the amplitude spectrum of the mirrored series; together they are uncorrelated with it."""
    rng = np.random.default_rng(0)
    x = np.cumsum(rng.normal(size=512))
    s = phase_surrogates(mirrored_spectrum(x), 200, rng)
    mirrored = np.abs(np.fft.rfft(np.concatenate([x, x[::-1]]) - x.mean()))
    for k in range(3):
        full = np.concatenate([s[:, k], s[::-1, k]])
        assert np.abs(np.fft.rfft(full)).sum() > 0.3 * mirrored.sum()
    corr = [np.corrcoef(x, s[:, k])[0, 1] for k in range(200)]
    assert abs(np.mean(corr)) < 0.1


def test_round_threshold_is_a_maximum_over_candidates():
    """A round's threshold is a quantile of the best standardised chance score of any candidate.

    Each candidate's chance tail is scaled to one (its mean excess over its 90th percentile):
    the best of a dozen candidates beats its own 90th percentile in most draws, so the
    round's 99th percentile lies well above it; a candidate counts only past that, which is,
    in what it explains, its own ``threshold_dps2``.
    """
    _, result = run_loop('NAVC3545', seed=101)
    first = result.rounds[0]
    assert first.draws == 200 and first.threshold_score > 1.0
    for c in first.candidates:
        assert (c.explained_dps2 > c.threshold_dps2) == (c.score > first.threshold_score), c
        assert not c.significant or c.score > first.threshold_score
    assert first.threshold_dps2 == min(c.threshold_dps2 for c in first.candidates)


# A gyro with slow noise as the loop study's (research/doc/loop-validation.md): a bias wander of 1.1 deg/h over an
# hour and a rate random walk, logged 2 h at 10 Hz: one chamber cycle.
WANDERING = dict(hours=2.0, rate_hz=10.0, wander_dps=3e-4, wander_tau_s=3600.0, rate_random_walk_dph_rthr=0.5)


@pytest.mark.parametrize('seed', [5000, 5001, 5002])
def test_a_shupe_effect_over_one_chamber_cycle_is_not_its_own_chance(seed):
    """A 14 deg/h Shupe effect in a 2 h log with a wandering bias is found.

    Its chance residuals once had the residual's spectrum, the effect's included: over one
    chamber cycle the effect then looked like wander (found in 2 of 8 such runs).
    """
    cal = load_packaged_calibration('NAVC3545')
    sim = simulate_run(cal, SimulationSettings(seed=seed, effects=('shupe',), **WANDERING))
    result = close_loop(sim.log(cal), cal.polynomial.rows, cal.polynomial.columns, LoopOptions(seed=seed))
    assert 'temperature_rate' in [e.signal for e in result.effects]


@pytest.mark.parametrize('seed', [1010, 1014, 1020])
def test_the_null_without_the_strongest_candidate_stays_honest_under_wander(seed):
    """Without an effect, a 6 h log whose bias wanders and random-walks yields no material claim.

    Taking the strongest candidate out of the chance residuals' spectrum also takes out the
    wander it happens to fit at the slowest frequencies (38 of 100 such runs then claimed a
    drift or a lagged temperature); the random-walk floor there puts it back.
    """
    cal = load_packaged_calibration('NAVC3545')
    sim = simulate_run(cal, SimulationSettings(seed=seed, **{**WANDERING, 'hours': 6.0}))
    result = close_loop(sim.log(cal), cal.polynomial.rows, cal.polynomial.columns, LoopOptions(seed=seed))
    assert result.effects == (), [e.term.describe() for e in result.effects]


def test_surrogates_are_drawn_at_a_fast_length_and_cut_to_the_log():
    """A bin count with a large prime factor is continued to a 5-smooth length; the spectrum still that of the log."""
    from art_gyro_calibration.analysis.trace import _fast_length
    smooth = [m for m in range(1, 5000) if all(p in (2, 3, 5) for p in _prime_factors(m))]
    assert all(_fast_length(n) == min(m for m in smooth if m >= n) for n in range(1, 4000))
    rng = np.random.default_rng(1)
    x = np.cumsum(rng.normal(size=4999))   # 4999 is prime
    spectrum = mirrored_spectrum(x)
    assert len(spectrum) == 5000 + 1   # 2 * 5000 samples: 5000 = 2**3 * 5**4
    assert phase_surrogates(spectrum, 3, rng).shape == (5000, 3)


def _prime_factors(m):
    out, p = [], 2
    while m > 1:
        while m % p == 0:
            out.append(p)
            m //= p
        p += 1
    return out


@pytest.mark.parametrize('seed', [101, 102, 103])
def test_a_warm_up_over_one_chamber_cycle_is_no_drift(seed):
    """A 20-minute warm-up in a 2 h log is named a warm-up, with its time constant, and leaves a warm restart alone.

    A line explains over half of such a decay, and the drift once stood for it; the drift,
    counted from node start, then added 4-8 deg/h to a node restarted on the warm gyro.
    The line must now also do nearly as well held out.
    """
    from art_gyro_calibration.analysis.replay import replay
    from art_gyro_calibration.analysis.simulate import same_gyro, warm_restart
    from art_gyro_calibration.compensation import RunStart
    from art_gyro_calibration.static_bias import DEFAULT_SAMPLES
    cal = load_packaged_calibration('NAVC3545')
    settings = SimulationSettings(seed=seed, effects=('warmup',), **WANDERING)
    result = close_loop(simulate_run(cal, settings).log(cal), cal.polynomial.rows, cal.polynomial.columns,
                        LoopOptions(seed=seed))
    assert [e.signal for e in result.effects] == ['time_since_power_on'], \
        [e.term.describe() for e in result.effects]
    assert result.effects[0].term.time_constant_s == pytest.approx(EFFECTS['warmup'][3], rel=0.2)
    warm = warm_restart(cal, same_gyro(settings, seed + 1), 3 * 3600.0).log(cal)
    field = {name: 3600.0 * replay(warm, calibration, DEFAULT_SAMPLES, start=RunStart()).field.systematic_rms_dps
             for name, calibration in (('art', result.art), ('extended', result.extended))}
    assert field['extended'] < field['art'] + 1.0, field   # deg/h


@pytest.mark.parametrize('seed', [7, 8])
def test_a_quarter_size_scale_factor_in_t_cubed_is_found(seed):
    """A scale factor in T**3 of 50 ppm at the range's ends (a quarter of the simulated one) is found in a 6 h log.

    Scored held out, with a threshold set by the candidates whose chance scores are largest
    (slow ones, wide ones), it was found in 45 % of such runs (research/doc/loop-validation.md). Each
    candidate is now judged against its own chance, and the next temperature row is tried
    one rate power at a time: a scale factor is one column, not four.
    """
    cal = load_packaged_calibration('NAVC3545')
    settings = SimulationSettings(seed=seed, effects=('rate_t3',), effect_sizes={'rate_t3': 5e-5},
                                  **{**WANDERING, 'hours': 6.0})
    result = close_loop(simulate_run(cal, settings).log(cal), cal.polynomial.rows, cal.polynomial.columns,
                        LoopOptions(seed=seed))
    assert [(e.term.signal, e.term.powers, e.term.rate_powers) for e in result.effects] == [('temperature', (3,), (1,))]


@pytest.mark.parametrize('seed', [37005, 37006])
def test_a_quarter_size_warm_up_in_a_six_hour_log_is_found_and_mends_a_cold_start(seed):
    """A 20-minute warm-up of 5e-3 deg/s (a quarter of the simulated one) in a 6 h log with a wandering bias.

    Judged by its best time constant, it was measured against the chance of the long ones (a
    warm-up of hours fits the wander of hours) and missed in these runs. Each time constant is
    now judged in its own chance tail, and the term takes the best-fitting one of those that
    beat chance: the node's static bias then leaves a cold start unbiased.
    """
    from art_gyro_calibration.analysis.replay import replay
    from art_gyro_calibration.analysis.simulate import same_gyro
    from art_gyro_calibration.compensation import RunStart
    from art_gyro_calibration.static_bias import DEFAULT_SAMPLES
    cal = load_packaged_calibration('NAVC3545')
    settings = SimulationSettings(seed=seed, effects=('warmup',), effect_sizes={'warmup': 0.005},
                                  **{**WANDERING, 'hours': 6.0})
    result = close_loop(simulate_run(cal, settings).log(cal), cal.polynomial.rows, cal.polynomial.columns,
                        LoopOptions(seed=seed))
    assert [e.signal for e in result.effects] == ['time_since_power_on'], \
        [e.term.describe() for e in result.effects]
    assert result.effects[0].term.time_constant_s == pytest.approx(EFFECTS['warmup'][3], rel=0.3)
    cold = simulate_run(cal, dataclasses.replace(same_gyro(settings, seed + 1), hours=2.0)).log(cal)
    field = {name: 3600.0 * replay(cold, calibration, DEFAULT_SAMPLES,
                                   start=RunStart(powered_on_at_start=True)).field.systematic_rms_dps
             for name, calibration in (('art', result.art), ('extended', result.extended))}
    assert field['extended'] < 0.5 * field['art'], field   # deg/h


@pytest.mark.parametrize('seed, size', [(42004, 0.002), (44012, 0.004)])
def test_a_supply_voltage_is_not_taken_by_a_wide_temperature_form(seed, size):
    """A supply-voltage effect in a 2 h log is named supply_v, not a lagged temperature.

    The lagged temperature's eight columns span any slow column over one chamber cycle: the
    supply voltage, judged to stand for it, gave way, and the lag's term then failed its
    held-out check (nothing found). A log column now stands for a derived signal only if
    each spans the other.
    """
    cal = load_packaged_calibration('NAVC3545')
    settings = SimulationSettings(seed=seed, effects=('supply_voltage',), effect_sizes={'supply_voltage': size},
                                  **WANDERING)
    result = close_loop(simulate_run(cal, settings).log(cal), cal.polynomial.rows, cal.polynomial.columns,
                        LoopOptions(seed=seed))
    assert [e.signal for e in _found(result)] == ['supply_v'], [e.term.describe() for e in _found(result)]


def test_a_lag_is_tried_and_retuned_only_within_a_quarter_of_the_log():
    """On a 2 h log no lag beyond 30 minutes is tried, nor reached by retuning.

    A 4 h lag retuned from the grid's 2 h on a 2 h log moved little over it; its polynomial,
    extrapolated on a warm restart, read 650 deg/h.
    """
    from art_gyro_calibration.analysis.fit import TermSpec
    from art_gyro_calibration.analysis.loop import retuned
    from art_gyro_calibration.analysis.metrics import DEFAULT_SETTLE_S, steady_segments
    from art_gyro_calibration.analysis.trace import Binned, candidate_specs
    from art_gyro_calibration.signals import LAGGED_SIGNAL, compute_signals
    cal = load_packaged_calibration('NAVC3545')
    log = simulate_run(cal, SimulationSettings(seed=3, **WANDERING)).log(cal)
    signals = compute_signals(log.t, log.rate_dps, log.temp_c, log.extras)
    quarter = 0.25 * float(log.t[-1] - log.t[0])
    lags = [spec.time_constant_s for spec in candidate_specs(signals, 3, 4)['temperature_lag']]
    assert max(lags) == pytest.approx(quarter) and min(lags) == 60.0
    binned = Binned(signals, log.rate_dps - log.ref_rate, steady_segments(log.t, log.ref_rate, DEFAULT_SETTLE_S), 3, 4)
    for lag in (max(lags), 2 * max(lags)):
        spec = TermSpec(LAGGED_SIGNAL, 'power', (1, 2), lag, (0, 1, 2, 3))
        assert retuned(binned, [spec])[0].time_constant_s <= quarter * (1 + 1e-9)


@pytest.mark.parametrize('seed, size', [(54010, 5e-5), (56018, 1e-4)])
def test_a_scale_factor_in_t_cubed_far_beyond_chance_survives_the_final_held_out_check(seed, size):
    """A rate x T**3 term that beat its round's chance by far (2.1 and 13 times the threshold) in a 2 h log stays.

    Over one chamber cycle its held-out error is how the polynomial extrapolates into a held-out
    block's temperatures: the final check dropped it, and nothing was found.
    """
    cal = load_packaged_calibration('NAVC3545')
    settings = SimulationSettings(seed=seed, effects=('rate_t3',), effect_sizes={'rate_t3': size}, **WANDERING)
    result = close_loop(simulate_run(cal, settings).log(cal), cal.polynomial.rows, cal.polynomial.columns,
                        LoopOptions(seed=seed))
    assert [(e.term.signal, e.term.powers, 1 in e.term.rate_powers) for e in result.effects] == \
        [('temperature', (3,), True)], [e.term.describe() for e in result.effects]


def test_no_held_out_block_spans_two_runs():
    """Several runs: each run's blocks of time count from its own first bin, so none holds rows of two runs."""
    t = np.arange(3000.0)   # two runs back to back: a block of the log's clock would straddle row 1500
    starts = ((0, True), (1500, True))
    signals = compute_signals(t, np.zeros(3000), 20.0 + 0.001 * t, run_starts=starts)
    segments = steady_segments(t, np.zeros(3000), 0.0, breaks=[0, 1500])
    binned = Binned(signals, np.zeros(3000), segments, 1, 1, folds=3, bin_s=10.0, block_s=400.0)
    fold = np.empty(len(binned.starts), dtype=np.int64)
    for k, bins in enumerate(binned.folds):
        fold[bins] = k
    bin_t = binned.bin_times()
    # Run 1's last block (1200..1500 s) and run 2's first (1500..1900 s) are dealt to different folds.
    assert not set(fold[(bin_t >= 1200.0) & (bin_t < 1500.0)]) & set(fold[(bin_t >= 1500.0) & (bin_t < 1900.0)])
    # A fit of the runs has a column per run beyond the first (its turn-on bias) beside the polynomial.
    assert binned.base.shape[1] == 1 + 1 + 1
