"""The measured-data study: its parts on small synthetic records offline, on the real records when they can be had."""

from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from art_gyro_calibration.analysis.loop import RATE_SIGNALS
from art_gyro_calibration.analysis.metrics import Segments
from art_gyro_calibration.analysis.report import STAGES
from art_gyro_calibration.log import GyroLog, read_log
from art_gyro_calibration.model import ArtPolynomial, ErrorModel
from art_gyro_calibration.signals import SignalFilters, compute_signals
from art_gyro_calibration.terms import Term
from importers import StaticRecord, static_log, write_static_log
import measured_data as measured
import measured_folds as folds
import measured_injection as injection
import measured_phone as phone
import measured_record as record_

HOUR = 3600.0
DATA_DIR = Path(__file__).resolve().parents[2] / 'data'  # gitignored download cache


# --- offline, on records built here --------------------------------------------------------

def _synthetic_cats(seed=0, hours=8.0, gap_h=0.3):
    """Three 'days' at 1 Hz, one orientation each, each starting with a handling transient of the temperature.

    Each gyro's bias follows a temperature polynomial, plus white noise of 0.1 deg/s and a
    small random-walk wander; nothing else.
    """
    rng = np.random.default_rng(seed)
    ts, temps, downs = [], [], []
    start = 0.0
    for k, down in enumerate((2, 0, 1)):  # acc_z, acc_x, acc_y down
        s = np.arange(0.0, hours * HOUR)
        ts.append(start + s)
        # Falls 8 degC, then swings slowly by +-3 degC (a phase of its own each day).
        temps.append(9.0 + 8.0 * np.exp(-s / 600.0) + 3.0 * np.sin(2 * np.pi * s / (5 * HOUR) + 2.0 * k))
        downs.append(np.full(s.size, down))
        start = ts[-1][-1] + gap_h * HOUR
    t, temp, down = np.concatenate(ts), np.concatenate(temps), np.concatenate(downs)
    n = t.size
    channels = {}
    for i, a in enumerate('xyz'):
        acc = rng.normal(0.0, 0.01, n)
        acc[down == i] -= 9.81
        channels[f'acc_{a}'] = acc
        channels[f'mag_{a}'] = 20.0 * (down == (i + 1) % 3) + rng.normal(0.0, 0.2, n)
        wander = np.cumsum(rng.normal(0.0, 2e-5, n))
        channels[f'gyro_{a}'] = (0.5 * (i - 1) + 0.01 * (i + 1) * (temp - 15.0) + 4e-4 * (temp - 15.0) ** 2
                                 + wander + rng.normal(0.0, 0.1, n))
    return StaticRecord(t, temp, channels, 'synthetic')


@pytest.fixture(scope='module')
def synthetic():
    """The synthetic record as gyro y's log, its day labels, and the fold with day 3 held out."""
    log = static_log(_synthetic_cats(), 'gyro_y')
    labels, names = record_.orientation_labels(log)
    return log, labels, names, folds.run_fold(log, labels, 2, f'day 3 ({names[2]})', 'y')


def _still_log(hours, down):
    """A still log at 1 Hz, one orientation per part (axis index that points down), parts 10 min apart."""
    parts = []
    for k, axis in enumerate(down):
        t = k * (hours + 1 / 6) * HOUR + np.arange(0.0, hours * HOUR)
        g = np.zeros((len(t), 3))
        g[:, axis] = -9.81
        parts.append((t, g))
    t = np.concatenate([p[0] for p in parts])
    g = np.concatenate([p[1] for p in parts])
    return GyroLog(t, np.zeros(len(t)), np.full(len(t), 20.0), np.zeros(len(t)),
                   {'acc_x': g[:, 0], 'acc_y': g[:, 1], 'acc_z': g[:, 2]})


def test_orientation_labels_count_orientations_in_order():
    labels, names = record_.orientation_labels(_still_log(1.0, (2, 0, 0, 1)))
    assert names == ('acc_z down', 'acc_x down', 'acc_y down')
    assert list(np.unique(labels, return_index=True)[0]) == [0, 1, 2]
    assert np.count_nonzero(labels == 1) == 2 * 3600


def test_block_segments_stay_within_runs():
    log = _still_log(1.0, (2, 2))
    values = np.where(log.t < 1.1 * HOUR, 1.0, 3.0)
    segments = record_.block_segments(log.t, block_s=600.0)
    assert len(segments) == 12  # six 10-minute blocks per hour-long run, none across the gap
    assert np.all(segments.counts == 600) and np.all(segments.rate == 0.0)
    tm, vm = record_.block_means(log.t, values)
    assert np.all(vm[:6] == 1.0) and np.all(vm[6:] == 3.0)
    assert tm[0] == pytest.approx(299.5)
    # A block less than half full is left out.
    short = log.slice(slice(0, 850))
    assert len(record_.block_segments(short.t)) == 1


def test_settled_start_is_where_the_temperature_stops_changing():
    t = np.arange(0.0, 3 * HOUR)
    temp = 5.0 + 8.0 * np.exp(-t / 600.0) + 0.5 * t / HOUR
    i = record_.settled_start(t, temp, 600, 1.0)
    assert abs(temp[i + 600] - temp[i]) <= 1.0 / 6 < abs(temp[i + 599] - temp[i - 1])
    assert 0.5 * HOUR < t[i] < 1.5 * HOUR
    # A window across a gap does not count; a temperature that never settles is refused.
    gap = np.concatenate([np.arange(0.0, 300.0), 5000.0 + np.arange(0.0, 300.0)])
    with pytest.raises(ValueError, match='never settles'):
        record_.settled_start(gap, np.full(600, 20.0), 400, 1.0)
    with pytest.raises(ValueError, match='never settles'):
        record_.settled_start(t, 5.0 + 2.0 * t / HOUR, 600, 1.0)


def test_newey_west_covers_the_slope_where_ordinary_least_squares_does_not():
    rng = np.random.default_rng(7)
    x = np.linspace(0.0, 1.0, 144)
    covered_nw = covered_ols = 0
    trials = 300
    for _ in range(trials):
        u = np.zeros(x.size)
        e = rng.normal(0.0, 1.0, x.size)
        for k in range(1, x.size):  # a bias wander: strongly autocorrelated
            u[k] = 0.95 * u[k - 1] + e[k]
        slope, se = folds.newey_west_slope(x, 2.0 + 3.0 * x + u)
        design = np.column_stack([np.ones_like(x), x])
        resid = 2.0 + 3.0 * x + u - design @ np.linalg.lstsq(design, 2.0 + 3.0 * x + u, rcond=None)[0]
        se_ols = np.sqrt(resid @ resid / (x.size - 2) * np.linalg.inv(design.T @ design)[1, 1])
        covered_nw += abs(slope - 3.0) < 2 * se
        covered_ols += abs(slope - 3.0) < 2 * se_ols
    assert covered_ols / trials < 0.6  # ordinary standard errors are far too small on a wander
    assert covered_nw / trials > covered_ols / trials + 0.2


def _loop_double(t, error, terms, days):
    """What time_term_agreement reads of a LoopResult: the extended model, the error and the signals."""
    signals = compute_signals(t, np.zeros(t.size), np.full(t.size, 20.0), {}, SignalFilters())
    model = ErrorModel(ArtPolynomial([[0.0]]), tuple(terms))
    return SimpleNamespace(extended=SimpleNamespace(model=model), error=error, signals=signals,
                           segments=Segments(np.array([0]), np.array([t.size]), np.array([0.0])))


def test_a_drift_is_kept_only_if_every_training_day_agrees():
    rng = np.random.default_rng(3)
    t = np.concatenate([np.arange(0.0, 20 * HOUR), 24 * HOUR + np.arange(0.0, 20 * HOUR)])
    days = (t > 22 * HOUR).astype(int)
    noise = rng.normal(0.0, 0.05, t.size)
    drift = Term('time', 'power', (0.02 / 86400.0,), (1,))  # 0.02 deg/s per day
    same = _loop_double(t, drift.evaluate(t) + 0.3 * days + noise, [drift], days)
    kept = folds.time_term_agreement(same, drift, days, 0.001)
    assert kept.kept and all(d.judged and abs(d.gain - 1.0) < 0.3 for d in kept.days)
    assert 'deg/s per day' in kept.describe()
    # Each day drifts the other way round: the joint fit sees a drift, each day alone denies it.
    within = np.where(days == 0, 0.03, -0.03) * (t - np.where(days == 0, 0.0, 24 * HOUR)) / 86400.0
    flip = folds.time_term_agreement(_loop_double(t, within + 0.05 * days + noise, [drift], days), drift, days,
                                     0.001)
    assert not flip.kept
    # A warm-up that has died out by day 2 is judged on day 1 alone.
    warmup = Term('time_since_power_on', 'exp_decay', (0.05,), (), 2 * HOUR)
    alone = folds.time_term_agreement(_loop_double(t, warmup.evaluate(t) + noise, [warmup], days), warmup, days,
                                      0.001)
    assert alone.kept and alone.days[0].judged and not alone.days[1].judged


def test_kept_model_refits_without_a_dropped_term():
    t = np.arange(0.0, 10 * HOUR)
    drift = Term('time', 'power', (1e-6,), (1,))
    loop = _loop_double(t, np.full(t.size, 0.2), [drift], np.zeros(t.size, dtype=int))
    agreement = folds.Agreement(drift, (), kept=False)
    model = folds.kept_model(loop, (agreement,), rows=1)
    assert model.terms == () and model.polynomial.coefficients[0, 0] == pytest.approx(0.2)
    assert folds.kept_model(loop, (folds.Agreement(drift, (), kept=True),), rows=1) is loop.extended.model


def test_signals_since_count_time_from_the_training_origin():
    t = np.arange(100.0, 200.0)
    temp = np.linspace(10.0, 20.0, t.size)
    since = folds.SignalsSince(t, np.zeros(t.size), temp, origin_s=150.0)
    assert since.time[0] == -50.0 and since.time[-1] == 49.0
    assert np.array_equal(since.temperature_rate, compute_signals(t, np.zeros(t.size), temp).temperature_rate)


def test_effects_are_scaled_to_their_rms():
    log = _still_log(2.0, (2, 0, 1))
    days, _ = record_.orientation_labels(log)
    for effect in injection.EFFECTS:
        shape = injection.effect_shape(effect, GyroLog(log.t, log.rate_dps, 20.0 + log.t / HOUR, log.ref_rate,
                                                       log.extras), days)
        if effect == 'shupe':
            continue  # a steady warming: dT/dt is constant, nothing to scale
        values, scale = injection.scaled(shape, 0.01)
        assert np.std(values) == pytest.approx(0.01)
        assert np.allclose(values, scale * shape)
    step = injection.effect_shape('step', log, days)
    assert np.all(step[days == 0] == 0.0) and np.all(step[days > 0] == 1.0)
    drift = injection.effect_shape('drift', log, days)
    assert drift[-1] == pytest.approx((log.t[-1] - log.t[0]) / 86400.0)
    with pytest.raises(ValueError, match='unknown effect'):
        injection.effect_shape('tide', log, days)


def test_a_fold_measures_every_model_four_ways(synthetic):
    log, labels, names, fold = synthetic
    assert names == ('acc_z down', 'acc_x down', 'acc_y down')
    assert np.array_equal(fold.held, labels == 2)
    start, settled = fold.bias_windows['bias_start'], fold.bias_windows['bias_settled']
    assert np.all(fold.held[start]) and start[0] == np.flatnonzero(fold.held)[0]
    # The settled window comes after the handling transient; the errors are measured after it.
    assert abs(log.temp_c[settled[-1]] - log.temp_c[settled[0]]) <= folds.SETTLED_C_PER_H / 6
    assert log.temp_c[start[0]] - log.temp_c[start[-1]] > 3.0
    assert fold.span[0] == settled[-1] + 1 and fold.span[-1] == np.flatnonzero(fold.held)[-1]
    for stage in STAGES:
        assert np.mean(fold.errors[stage, 'mean_removed']) == pytest.approx(0.0, abs=1e-12)
        for way in folds.WAYS:
            assert fold.errors[stage, way].shape == fold.span.shape
    # The turn-on bias (0 on y) and the temperature polynomial: ART predicts the day's bias, the raw gyro does not.
    raw, art = (fold.field[s, 'predicted'].systematic_rms_dps for s in ('uncalibrated', 'art'))
    assert art < 0.3 * raw
    # Right after it, a raw gyro's static bias taken in the transient is worse than one taken after it.
    assert (abs(fold.field['uncalibrated', 'bias_settled'].heading_10min_deg)
            < 0.2 * abs(fold.field['uncalibrated', 'bias_start'].heading_10min_deg))
    assert not {c.signal for r in fold.loop.rounds for c in r.candidates} & set(RATE_SIGNALS)


def test_an_injected_drift_is_found_blind_and_named(synthetic):
    log, labels, _, base = synthetic
    floor = folds.record_allan(log)[1].adev.min()
    trial = injection.run_trial(base, labels, 'drift', 10.0, floor, max_effects=4)
    assert trial.detected and 'time' in trial.named
    assert 0.7 < trial.recovered < 1.3
    assert trial.rms_dps == pytest.approx(10.0 * floor)
    after = trial.fold.field['extended', 'predicted'].systematic_rms_dps
    assert after < 0.7 * trial.fold.field['art', 'predicted'].systematic_rms_dps
    cell, = injection.cells([trial])
    assert cell.detected == 1 and 'time (1)' in cell.named() and cell.held_out('art', 'predicted').shape == (1,)


def _synthetic_phone(seed=1, hours=1.5):
    """A still phone at 10 Hz: two nearly equal gyro streams, no temperature."""
    rng = np.random.default_rng(seed)
    t = np.arange(0.0, hours * HOUR, 0.1)
    channels = {}
    for i, a in enumerate('xyz'):
        rate = -0.5 * (i + 1) + rng.normal(0.0, 0.02, t.size)
        channels[f'gyro_{a}'] = rate
        channels[f'gyro_measured_{a}'] = rate + rng.normal(0.0, 0.001, t.size)
        channels[f'acc_{a}'] = rng.normal(9.81 if a == 'z' else 0.0, 0.01, t.size)
        channels[f'mag_{a}'] = rng.normal(10.0 * i, 0.2, t.size)
    return StaticRecord(t, np.full(t.size, np.nan), channels, 'phone')


def test_the_document_of_a_study(synthetic, tmp_path):
    log, labels, names, fold = synthetic
    floor = folds.record_allan(log)[1].adev.min()
    trial = injection.run_trial(fold, labels, 'step', 3.0, floor, max_effects=2)
    raw, art = folds.record_allan(log)
    rec = _synthetic_phone()
    axis = phone.run_phone_axis(rec, np.ones(rec.t.size, dtype=bool), 'z', 2)
    assert not {c.signal for r in axis.fold.loop.rounds for c in r.candidates} & set(phone.TWINS)
    cats_allan = {a: {'raw': raw, 'art': art} for a in 'xyz'}
    cats_record = _synthetic_cats()
    study = measured.Study(cats_record, np.ones(cats_record.t.size, dtype=bool), names, {3: [fold, fold, fold]},
                           {a: floor for a in 'xyz'}, cats_allan, injection.cells([trial]), [axis],
                           measured.QUICK, 12.0)
    doc = tmp_path / 'doc' / 'measured.md'
    figs = measured.write_figures(study, tmp_path / 'figures', doc)
    text = measured.markdown(study, figs)
    assert '## What these records can and cannot test' in text and 'rate-table record of an RD2100' in text
    assert f'{fold.field["art", "bias_settled"].systematic_rms_dps:.4f}' in text
    assert '| step at the first orientation change | ' in text
    assert '../figures/measured-injection.png' in text and '../figures/measured-phone-allan.png' in text
    for name in ('record', 'temperature', 'y-day3', 'allan-day3', 'injection', 'phone-allan'):
        assert (tmp_path / 'figures' / f'measured-{name}.png').stat().st_size > 10_000


def test_fetch_says_why_it_cannot(tmp_path, monkeypatch):
    monkeypatch.setattr(record_.sys, 'executable', str(tmp_path / 'no-python'))
    with pytest.raises(record_.DataUnavailable, match='cannot run'):
        record_.fetch_records(tmp_path / 'cache')


# --- on the real records, when they can be downloaded -----------------------------------

@pytest.fixture(scope='module')
def paths():
    try:
        return record_.fetch_records(DATA_DIR)
    except record_.DataUnavailable as e:
        pytest.skip(f'the measured records cannot be downloaded here: {e}')


@pytest.fixture(scope='module')
def record_slice(paths):
    """Hours 10 to 22 of the CATS record: one orientation, warming from 5 to 16 degC."""
    record, _ = record_.import_cats(paths['cats'])
    return record.slice((record.t >= 10 * HOUR) & (record.t < 22 * HOUR))


def test_import_of_the_real_record(record_slice, tmp_path):
    record = record_slice
    still = record_.still_mask(record.t, [record.channels[c] for c in record_.MOTION_CHANNELS])
    assert still.all()  # nobody touched the tag in these hours
    log = static_log(record, 'gyro_x', still)
    # A MEMS gyro's turn-on bias: about 2 deg/s on x, read as 37 mrad/s in the file.
    assert 1.9 < np.median(log.rate_dps) < 2.2
    assert np.all(log.ref_rate == 0.0)
    assert 4.5 < log.temp_c.min() < log.temp_c.max() < 17.0
    assert {'gyro_y', 'gyro_z', 'acc_z', 'mag_x', 'depth'} <= set(log.extras)
    labels, names = record_.orientation_labels(log)
    assert names == ('acc_z down',) and np.all(labels == 0)
    path = tmp_path / 'gyro_x.csv'
    write_static_log(path, log.slice(slice(0, 2000)))
    assert np.allclose(read_log(path).rate_dps, log.rate_dps[:2000], rtol=1e-8)


def test_the_loop_on_the_real_record(record_slice):
    # The first 3 h (steady at 5 degC) held out, the 9 h of warming after them the training 'day'.
    days = (record_slice.t >= 13 * HOUR).astype(int)
    results = [folds.run_fold(static_log(record_slice, f'gyro_{a}'), days, 0, 'first 3 h', a) for a in 'xyz']
    for r in results:
        assert (r.loop.art.polynomial.rows, r.loop.art.polynomial.columns) == (folds.ROWS, folds.COLUMNS)
        assert 5.0 < r.loop.materiality_dph < 60.0  # the bias instability of a MEMS gyro, in deg/h
        # White noise at 1 s of a MEMS gyro resampled to 1 Hz: about 0.1 deg/s.
        assert 0.05 < r.allan['art'].adev[0] < 0.2
        assert r.span.size > 2 * HOUR
    screened = {c.signal for r in results for found in r.loop.rounds for c in found.candidates}
    assert {'temperature', 'gyro_x', 'acc_z', 'depth'} <= screened


def test_the_phone_record_is_quieter_than_the_tag(paths):
    record, still = record_.import_phone(paths['phone'])
    assert record.t[-1] == pytest.approx(21479.9) and still.mean() > 0.9
    assert np.all(np.isnan(record.temp_c))
    cats, _ = record_.import_cats(paths['cats'])
    for a in 'xyz':
        tag = phone.stream_allan(cats, np.ones(cats.t.size, dtype=bool), f'gyro_{a}').at(1.0)
        assert phone.stream_allan(record, still, f'gyro_{a}').at(1.0) < 0.5 * tag
