"""``calibrate fit`` in bounded memory: chunk by chunk it finds what one chunk finds, and holds no matrix per row."""

import dataclasses
import tracemalloc

import numpy as np
import pytest

from art_gyro_calibration.analysis import chunks, metrics
from art_gyro_calibration.analysis import report as report_module
from art_gyro_calibration.analysis import fit as fit_module
from art_gyro_calibration.analysis.loop import LoopOptions, close_loop
from art_gyro_calibration.analysis.report import build_report
from art_gyro_calibration.analysis.simulate import SimulationSettings, simulate_run
from art_gyro_calibration.calibration import load_packaged_calibration
from art_gyro_calibration import signals as signals_module
from art_gyro_calibration.signals import compute_signals
from art_gyro_calibration.static_bias import refined_temperature_rate, refinement_span_s

SERIAL = 'NAVC3545'


def simulated(hours, rate_hz, effects=(), seed=3):
    cal = load_packaged_calibration(SERIAL)
    return simulate_run(cal, SimulationSettings(hours=hours, rate_hz=rate_hz, seed=seed, effects=effects)).log(cal)


def fit(log):
    result = close_loop(log, 3, 4, LoopOptions(serial_number=SERIAL))
    return result, build_report(log, result, 100)


def assert_close(a, b, path=''):
    """Every number of two reports equal to 1e-8 relative; everything else equal.

    (1e-9 held until the warm-up's every time constant was judged apart: the adequacy's bias
    instability, an Allan floor of the held-out residual, then differed by 1.3e-9.)
    """
    if isinstance(a, dict):
        assert a.keys() == b.keys(), path
        for key in a:
            assert_close(a[key], b[key], f'{path}.{key}')
    elif isinstance(a, list):
        assert len(a) == len(b), path
        for i, (x, y) in enumerate(zip(a, b)):
            assert_close(x, y, f'{path}[{i}]')
    elif isinstance(a, float):
        assert a == pytest.approx(b, rel=1e-8, abs=1e-300), path
    else:
        assert a == b, path


@pytest.mark.parametrize('effects', [('shupe', 'warmup', 'supply_voltage'), ('coil_lag',)])
def test_small_chunks_give_the_one_chunk_calibration(effects, monkeypatch):
    """The same effects, coefficients, p-values, held-out errors and REPORT numbers from 44 chunks as from one.

    Also the per-row temporaries of the metrics taken in pieces of 777 rows instead of one.

    The causal signals (a lagged coil temperature, the warm-up, the angle of the corrected
    rate) continue across the chunks' edges, and the bins cut by them add their parts.
    """
    log = simulated(6.0, 2.0, effects)
    assert len(log) < min(chunks.DESIGN_CHUNK_ROWS, report_module.STAGE_CHUNK_ROWS)
    whole, whole_report = fit(log)
    monkeypatch.setattr(chunks, 'DESIGN_CHUNK_ROWS', 1000)
    monkeypatch.setattr(report_module, 'STAGE_CHUNK_ROWS', 1000)   # the stage errors compensated in chunks too
    monkeypatch.setattr(metrics, 'PIECE_ROWS', 777)   # noise floor, correlation time, segments in pieces
    monkeypatch.setattr(fit_module, 'PIECE_ROWS', 777)
    parts, parts_report = fit(log)

    assert [e.term.signal for e in parts.effects] == [e.term.signal for e in whole.effects]
    assert len(whole.effects) >= 1
    for mine, theirs in zip(parts.effects, whole.effects):
        assert (mine.term.form, mine.term.powers, mine.term.rate_powers) == \
            (theirs.term.form, theirs.term.powers, theirs.term.rate_powers)
        assert mine.term.time_constant_s == pytest.approx(theirs.term.time_constant_s, rel=1e-9)
        np.testing.assert_allclose(mine.term.coefficients, theirs.term.coefficients, rtol=1e-9)
        assert mine.score.p_value == theirs.score.p_value
    for name in ('noise_floor_dps', 'held_out_rms_art_dps', 'held_out_rms_extended_dps', 'materiality_dph'):
        assert getattr(parts, name) == pytest.approx(getattr(whole, name), rel=1e-9), name
    # The polynomials: their corrections over the log agree to 1e-9 of their range (a raw coefficient
    # can be a near-cancellation of the scaled ones, so compared one by one it would say little).
    for which in ('art', 'extended'):
        a = getattr(parts, which).polynomial.error(log.rate_dps, log.temp_c)
        b = getattr(whole, which).polynomial.error(log.rate_dps, log.temp_c)
        np.testing.assert_allclose(a, b, rtol=0, atol=1e-9 * np.ptp(b))
    # Each candidate's screen numbers to 1e-8 (relative, or of the scale the screen judges them on: the noise
    # floor's variance, the materiality). The filtered signals restarted at a chunk's edge differ from the
    # whole log's by 1e-11 relative; a candidate nearly in the base model's span (1e-13 deg/h) or one that
    # extrapolates wildly into a held-out block (a warm-up of 30 s: -0.4 deg^2/s^2, 1.0e-8 apart) amplifies that.
    floor2, materiality = whole.noise_floor_dps ** 2, whole.materiality_dph
    # A standardised score is a difference of chance tails far smaller than the floor's variance: 1e-4 absolute.
    scale = {'held_out_improvement_dps2': floor2, 'chance_max_improvement_dps2': floor2, 'explained_dps2': floor2,
             'chance_threshold_dps2': floor2, 'score': 1e4, 'fraction_of_noise_floor_variance': 1.0,
             'effect_dph': materiality}
    for mine, theirs in zip(parts_report.pop('screens'), whole_report.pop('screens')):
        assert mine['chance_threshold_dps2'] == pytest.approx(theirs['chance_threshold_dps2'], rel=1e-8,
                                                              abs=1e-8 * floor2)
        assert mine['chance_threshold_score'] == pytest.approx(theirs['chance_threshold_score'], abs=1e-4)
        assert [c['signal'] for c in mine['candidates']] == [c['signal'] for c in theirs['candidates']]
        for a, b in zip(mine['candidates'], theirs['candidates']):
            for key, value in b.items():
                if key in scale:
                    assert a[key] == pytest.approx(value, rel=1e-7, abs=1e-8 * scale[key]), (b['signal'], key)
                else:
                    assert a[key] == value, (b['signal'], key)
    for report in (parts_report, whole_report):   # compared above, by what they do
        del report['polynomial']['art_coefficients'], report['polynomial']['extended_coefficients']
    assert_close(parts_report, whole_report)


def test_chunked_signals_equal_the_whole_logs():
    """Chunks continue the causal signals: lags, filters and the angle of a corrected rate."""
    log = simulated(1.0, 2.0)
    whole = compute_signals(log.t, log.rate_dps, log.temp_c, log.extras)
    whole = dataclasses.replace(whole, angle_correction=load_packaged_calibration(SERIAL).model)
    index = np.arange(0, len(log), 3)
    seen = []
    for chunk in chunks.chunks(whole, index, 700):
        rows = chunk.start + chunk.rows
        assert np.array_equal(rows, index[chunk.positions])
        seen.append([chunk.signals.lagged_temperature(600.0)[chunk.rows], chunk.signals.angle[chunk.rows],
                     chunk.signals.temperature_rate[chunk.rows], chunk.signals.rate_change[chunk.rows]])
    for got, want in zip(zip(*seen), [whole.lagged_temperature(600.0), whole.angle, whole.temperature_rate,
                                      whole.rate_change]):
        np.testing.assert_allclose(np.concatenate(got), want[index], rtol=1e-12, atol=1e-12)


def test_no_matrix_with_a_row_per_log_row(monkeypatch):
    """With small chunks the loop's peak is a few of the log's columns, not its design matrices.

    The polynomial alone has 12 columns; before, the every-row held-out error held them
    and the error per row (and each candidate's basis per row), and the fit its design
    matrix: the loop's peak was 75 times one column of the log. The per-bin arrays are
    small on a 100 Hz log (100 rows per 1 s bin).
    """
    log = simulated(1.0, 100.0, seed=5)
    monkeypatch.setattr(chunks, 'DESIGN_CHUNK_ROWS', 2048)
    column = len(log) * 8
    tracemalloc.start()
    try:
        before = tracemalloc.get_traced_memory()[0]
        close_loop(log, 3, 4, LoopOptions(serial_number=SERIAL))
        peak = tracemalloc.get_traced_memory()[1] - before
    finally:
        tracemalloc.stop()
    assert peak < 20 * column, f'peak {peak / column:.1f} columns of the log'


def test_no_chunk_crosses_a_run_and_each_run_starts_afresh():
    """Several runs: the chunks split at each run's first row, and their signals equal the whole's."""
    log = simulated(0.3, 2.0)
    starts = ((0, True), (500, False), (1400, True))
    whole = compute_signals(log.t, log.rate_dps, log.temp_c, log.extras, run_starts=starts)
    index = np.arange(1, len(log), 2)
    got = {name: [] for name in ('time_since_power_on', 'temperature_rate', 'angle')}
    for chunk in chunks.chunks(whole, index, 700):
        first = max(f for f, _ in starts if f <= chunk.start)
        assert chunk.start + len(chunk.signals) <= min([f for f, _ in starts if f > chunk.start] + [len(log)])
        assert (chunk.signals.previous is None) == (chunk.start == first)
        for name, values in got.items():
            values.append(chunk.signals.get(name)[chunk.rows])
    for name, values in got.items():
        np.testing.assert_allclose(np.concatenate(values), whole.get(name)[index], rtol=1e-12, atol=1e-12)


def test_the_fit_s_refined_start_is_whole_in_every_run_s_first_chunk():
    """The fit's temperature rate over a run's first minutes (the refinement's slope) is fitted on all of them."""
    cal = load_packaged_calibration(SERIAL)
    log = simulate_run(cal, SimulationSettings(hours=1.0, rate_hz=2.0, seed=3, self_heating_c=4.0)).log(cal)
    starts = ((0, True), (3000, False))
    whole = compute_signals(log.t, log.rate_dps, log.temp_c, log.extras, run_starts=starts, refined_start=True)
    # On the fit's temperature (smoothed both ways, signals.FIT_SMOOTHING_S), as the node's filter would read it.
    temp_c = whole.temperature
    filtered = compute_signals(log.t, log.rate_dps, temp_c, log.extras, run_starts=starts).temperature_rate
    span = int(refinement_span_s(whole.filters.refinement_scale_s) * 2.0)   # rows at 2 Hz
    for first, _ in starts:
        rows = slice(first, first + span)
        np.testing.assert_array_equal(whole.temperature_rate[rows],
                                      refined_temperature_rate(log.t[first:], temp_c[first:],
                                                               whole.filters.refinement_scale_s))
        assert not np.allclose(whole.temperature_rate[rows], filtered[rows])
        after = slice(first + span, first + 2 * span)
        np.testing.assert_array_equal(whole.temperature_rate[after], filtered[after])
    index = np.arange(len(log))
    got = [chunk.signals.temperature_rate for chunk in chunks.chunks(whole, index, 300)]
    np.testing.assert_allclose(np.concatenate(got), whole.temperature_rate, rtol=1e-12, atol=1e-12)


def test_every_pass_after_the_first_takes_each_chunk_s_temperature_rate_as_made(monkeypatch):
    """The temperature rate is filtered once per chunk: a fit after the loop's many filtered the log again each."""
    log = simulated(0.3, 2.0)
    starts = ((0, True), (1000, False))
    whole = compute_signals(log.t, log.rate_dps, log.temp_c, log.extras, run_starts=starts)
    index = np.arange(0, len(log), 2)
    made = []
    filtered = signals_module.Signals._filtered_temperature_rate
    monkeypatch.setattr(signals_module.Signals, '_filtered_temperature_rate',
                        lambda self: made.append(len(self)) or filtered(self))
    passes = [[chunk.signals.temperature_rate.copy() for chunk in chunks.chunks(whole, index, 400)]
              for _ in range(3)]
    assert sum(made) == len(log)   # each row filtered once, on the first pass
    for later in passes[1:]:
        for got, want in zip(later, passes[0]):
            np.testing.assert_array_equal(got, want)
