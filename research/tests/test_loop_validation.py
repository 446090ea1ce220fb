"""The pure helpers of research/studies/loop_validation.py's whole-fit sections: summaries, shapes, targets."""

import sys
from collections.abc import Callable
from types import ModuleType
from typing import Any

import numpy as np
import pytest

from art_gyro_calibration.calibration import load_packaged_calibration
from art_gyro_calibration.log import GyroLog


@pytest.fixture(scope='module')
def lv(load_study: Callable[[str], ModuleType]) -> ModuleType:
    """The study as a module."""
    return load_study('loop_validation')


def _field(**dph: float) -> dict[str, dict[str, float]]:
    return {name: {'systematic_rms_dph': value} for name, value in dph.items()}


def _cold(effects: str, written: float, oracle: float, baseline: float, seed: int = 0) -> dict[str, Any]:
    return {'kind': 'cold', 'heating_c': 4.0, 'heating_tau_min': 10.0, 'effects': effects, 'seed': seed,
            'written_terms': ['temperature_rate'],
            'field': _field(written=written, baseline=baseline, oracle=oracle, oracle_node=oracle)}


def test_cold_summary_takes_the_median_of_each_runs_ratio(lv: ModuleType) -> None:
    """Ratios 1, 3, 1.5: the median ratio is 1.5 (not the ratio of the medians), and the cell holds at 2x."""
    runs = [_cold('shupe', 2.0, 2.0, 9.0), _cold('shupe', 9.0, 3.0, 9.0), _cold('shupe', 3.0, 2.0, 9.0)]
    s = lv.cold_summary(runs)
    (cell,) = s['cells']
    assert cell['ratio_median'] == pytest.approx(1.5)
    assert cell['runs'] == 3 and cell['met'] and s['met']


def test_cold_summary_marks_an_effect_cell_above_the_ratio_unmet(lv: ModuleType) -> None:
    """One profile's warm-up at a median ratio of 2.5 fails the section whatever the others do."""
    runs = [_cold('warmup', 5.0, 2.0, 9.0), _cold('shupe', 2.0, 2.0, 9.0)]
    s = lv.cold_summary(runs)
    assert s['targets'] == {'shupe': True, 'warmup': False}
    assert not s['met']


def test_cold_summary_judges_none_against_the_baseline_run_by_run(lv: ModuleType) -> None:
    """Without an effect the oracle ratio is not the target: one run 1.2 deg/h worse than the baseline fails it."""
    good = lv.cold_summary([_cold('none', 3.0, 1.0, 2.5), _cold('none', 2.0, 1.0, 2.0)])
    assert good['met'] and good['cells'][0]['worse_than_baseline_max_dph'] == pytest.approx(0.5)
    bad = lv.cold_summary([_cold('none', 3.2, 3.2, 2.0), _cold('none', 2.0, 2.0, 2.0)])
    assert not bad['met']


def test_a_warm_up_cell_is_judged_on_the_lab_protocols_fit(lv: ModuleType) -> None:
    """Issue 35 item 5: with a several-run fit (two cold starts, a warm restart) in every run, its ratio decides."""
    runs = [_cold('warmup', 5.0, 2.0, 9.0), _cold('warmup', 6.0, 2.0, 9.0)]
    for r, lab in zip(runs, (2.4, 3.0)):
        r['field']['written_runs'] = {'systematic_rms_dph': lab}
    s = lv.cold_summary(runs)
    (cell,) = s['cells']
    assert cell['ratio_median'] == pytest.approx(2.75) and cell['ratio_runs_median'] == pytest.approx(1.35)
    assert cell['written_runs_dph'] == pytest.approx(2.7) and cell['met']
    assert lv.cold_summary([_cold('warmup', 5.0, 2.0, 9.0)])['cells'][0]['ratio_runs_median'] is None


def _null(hours: float, written: dict[str, float], baseline: dict[str, float], adequate: bool = True,
          seed: int = 0) -> dict[str, Any]:
    return {'kind': 'null', 'hours': hours, 'seed': seed, 'verdict': 'baseline', 'written_terms': [],
            'materiality_dph': 0.5 * hours, 'model_adequate': adequate, 'shapes_found': [] if adequate else ['time'],
            'field': {s: _field(written=written[s], baseline=baseline[s]) for s in ('cold', 'warm')}}


def test_null_summary_fails_on_one_second_run_worse_than_the_baseline(lv: ModuleType) -> None:
    """A null whose written file is 1.5 deg/h worse on its warm second run only: the target is not met."""
    ok = _null(2.0, {'cold': 2.0, 'warm': 2.0}, {'cold': 2.0, 'warm': 1.5}, seed=1)
    worse = _null(2.0, {'cold': 2.0, 'warm': 3.5}, {'cold': 2.0, 'warm': 2.0}, seed=2)
    assert lv.null6_summary([ok])['met']
    s = lv.null6_summary([ok, worse])
    assert not s['met']
    warm = next(r for r in s['rows'] if r['scenario'] == 'warm')
    assert warm['worse_count'] == 1 and warm['worse_max_dph'] == pytest.approx(1.5)
    assert s['worse'][0][:3] == (2, 2.0, 'warm')


def test_median_materiality_per_length(lv: ModuleType) -> None:
    """The median of each length's null runs."""
    runs = [_null(2.0, {'cold': 1, 'warm': 1}, {'cold': 1, 'warm': 1}) for _ in range(3)]
    runs[0]['materiality_dph'] = 0.1
    runs.append(_null(6.0, {'cold': 1, 'warm': 1}, {'cold': 1, 'warm': 1}))
    assert lv.median_materiality(runs) == {2.0: pytest.approx(1.0), 6.0: pytest.approx(3.0)}


def _shape(shape: str, adequate: bool, found: list[str], hours: float = 6.0) -> dict[str, Any]:
    return {'kind': 'shape', 'shape': shape, 'hours': hours, 'seed': 0, 'size_dph': 1.5, 'raw_size_dph': 1.5,
            'size_rms_dph': 0.5, 'raw_rms_dph': 0.7, 'model_adequate': adequate, 'shapes_found': found,
            'found_terms': []}


def test_a_shape_counts_only_when_the_alarm_fires_and_names_its_signal(lv: ModuleType) -> None:
    """Fired on the wrong signal, or named without the alarm (impossible, but judged so): not detected."""
    assert lv.shape_detected(_shape('heading_bump', False, ['angle', 'time']))
    assert not lv.shape_detected(_shape('heading_bump', False, ['temperature']))
    assert not lv.shape_detected(_shape('heading_bump', True, ['angle']))


def test_shape_summary_targets(lv: ModuleType) -> None:
    """9 of 10 shape runs detected meets 90 %; 1 alarm in 10 null runs misses 5 %."""
    shapes = [_shape('rate_bump', False, ['rate'])] * 9 + [_shape('rate_bump', False, ['temperature'])]
    nulls = [_null(2.0, {'cold': 1, 'warm': 1}, {'cold': 1, 'warm': 1}, adequate=k > 0) for k in range(10)]
    s = lv.shape_summary(shapes + nulls, {2.0: 0.5})
    assert s['detected'] == pytest.approx(0.9) and s['targets']['shapes']
    assert s['null_fired'] == 1 and not s['targets']['nulls'] and not s['met']
    assert s['rows'][0]['fired'] == 1.0 and s['rows'][0]['detected'] == pytest.approx(0.9)
    quiet = lv.shape_summary(shapes + nulls[1:], {2.0: 0.5})
    assert quiet['met']
    # The study's own null runs count too: 1 of 10 there fails the null target.
    study = [{'effect': None, 'model_adequate': k > 0} for k in range(10)]
    assert not lv.shape_summary(shapes + nulls[1:], {2.0: 0.5}, study_nulls=study)['targets']['nulls']


def test_the_shape_target_is_on_long_fit_logs(lv: ModuleType) -> None:
    """2 h logs have no power target: shapes missed there are reported, not judged."""
    long = [_shape('rate_bump', False, ['rate'])] * 9 + [_shape('rate_bump', True, [])]
    short = [_shape('rate_bump', True, [], hours=2.0)] * 10
    s = lv.shape_summary(long + short, {2.0: 0.5, 6.0: 0.5})
    assert s['detected'] == pytest.approx(0.45) and s['detected_long'] == pytest.approx(0.9)
    assert s['targets']['shapes'] and s['rows'][0]['detected_by_hours'] == {'2': 0.0, '6': pytest.approx(0.9)}
    assert not lv.shape_summary(long[1:] + short, {2.0: 0.5, 6.0: 0.5})['targets']['shapes']
    assert not lv.shape_summary(short, {2.0: 0.5})['targets']['shapes']


def test_the_document_marks_unmet_targets(lv: ModuleType) -> None:
    """The section's target table says **not met** where a target fails, met where it holds."""
    saved = {'results': [_cold('shupe', 6.0, 2.0, 9.0), _cold('none', 2.0, 2.0, 2.0),
                         _null(2.0, {'cold': 2.0, 'warm': 2.0}, {'cold': 2.0, 'warm': 2.0}),
                         _shape('temperature_step', False, ['temperature'])],
             'materiality': {'2': 0.5}}
    s = lv.summarise_whole_fit(saved)
    assert not s['cold']['met'] and s['nulls']['met'] and s['shapes']['met']
    text = '\n'.join(lv.whole_fit_lines(s, {'item6_runs': 4, 'item6_cpu_s': 1.0}))
    rows = {line.split('|')[1].strip(): line for line in text.splitlines() if line.startswith('| ')}
    assert '**not met**' in rows['cold start']
    assert rows['nulls against the baseline'].rstrip(' |').endswith('met')
    assert '**not met**' not in rows['nulls against the baseline']
    assert '| 3.00 |' in text   # the shupe cell's ratio


def test_shape_cases_are_sized_from_the_null_materiality(lv: ModuleType) -> None:
    """3x each length's materiality, lengths alternating, every seed distinct."""
    cases = lv.shape_cases(4, {2.0: 0.5, 6.0: 0.4})
    assert len(cases) == 4 * len(lv.SHAPES)
    assert len({c.seed for c in cases}) == len(cases)
    for c in cases:
        assert c.size_dph == pytest.approx(3.0 * {2.0: 0.5, 6.0: 0.4}[c.hours])
    assert [c.hours for c in cases[:4]] == [2.0, 6.0, 2.0, 6.0]
    cold = lv.cold_cases(2)
    assert len(cold) == 2 * len(lv.SELF_HEATING_PROFILES) * len(lv.COLD_EFFECT_SETS)
    assert len({c.seed for c in cold}) == len(cold)


def test_cold_case_settings(lv: ModuleType) -> None:
    """The profile in seconds, k 0.6, 9 deg/h of warm-up, the 0.5 degC/min ramp."""
    s = lv.ColdCase(6.0, 5.0, 'both', 7).settings()
    assert (s.self_heating_c, s.self_heating_tau_s, s.ramp_c_per_min, s.hours) == (6.0, 300.0, 0.5, 6.0)
    assert s.effect_sizes == {'shupe_true_rate': 0.6, 'warmup': pytest.approx(9.0 / 3600.0)}
    assert lv.ColdCase(2.0, 10.0, 'none', 7).settings().effects == ()


def test_table_heading(lv: ModuleType) -> None:
    """10 deg/s for 36 s is one turn."""
    t = np.arange(0.0, 40.0, 0.1)
    rate = np.where(t < 36.0 - 1e-9, 10.0, 0.0)
    assert lv.table_heading_deg(t, rate)[-1] == pytest.approx(360.0)


@pytest.fixture(scope='module')
def short_log(lv: ModuleType) -> GyroLog:
    """Half an hour of a simulated null run (a hold and a ramp of the chamber)."""
    truth = load_packaged_calibration(lv.SERIAL)
    settings = lv.Case(None, 0.0, 0.5, 11).settings()
    return lv.simulate_run(truth, settings).log(truth)


@pytest.mark.parametrize('shape', ['heading_sawtooth', 'heading_bump', 'temperature_bump', 'temperature_step',
                                   'temperature_ripple', 'rate_bump', 'supply_bump'])
def test_shapes_have_the_size_asked_beyond_the_polynomial(lv: ModuleType, short_log: GyroLog, shape: str) -> None:
    """Unit peak-to-peak before sizing; sized, the polynomial's residual of the effect has the half range asked."""
    truth = load_packaged_calibration(lv.SERIAL)
    rows, columns = truth.polynomial.rows, truth.polynomial.columns
    unit = lv.shape_unit(shape, short_log)
    assert float(np.ptp(unit)) == pytest.approx(1.0, abs=0.02)
    effect, sizes = lv.sized_shape(shape, short_log, 1.7, rows, columns)
    left = lv.inexpressible(effect, short_log, rows, columns)
    assert lv.half_range(left) * 3600.0 == pytest.approx(1.7, rel=1e-6)
    assert sizes['size_dph'] == pytest.approx(1.7)
    assert sizes['size_rms_dph'] <= sizes['raw_rms_dph'] * 1.05


def test_a_step_in_temperature_is_partly_the_polynomials(lv: ModuleType, short_log: GyroLog) -> None:
    """The polynomial takes much of a step's rms, so the part it cannot express is smaller than the step."""
    truth = load_packaged_calibration(lv.SERIAL)
    _, sizes = lv.sized_shape('temperature_step', short_log, 1.0, truth.polynomial.rows, truth.polynomial.columns)
    assert sizes['size_rms_dph'] < 0.7 * sizes['raw_rms_dph']


def test_unknown_shape(lv: ModuleType, short_log: GyroLog) -> None:
    """A shape not in SHAPES is refused by name."""
    with pytest.raises(ValueError, match='unknown shape'):
        lv.shape_unit('triangle', short_log)


def test_the_detector_told_the_shape_finds_it_and_not_its_absence(lv: ModuleType, short_log: GyroLog) -> None:
    """A heading sawtooth of 2 deg/h beyond the polynomial on half an hour: the projection on it beats chance."""
    truth = load_packaged_calibration(lv.SERIAL)
    rows, columns = truth.polynomial.rows, truth.polynomial.columns
    effect, _ = lv.sized_shape('heading_sawtooth', short_log, 2.0, rows, columns)
    shaped = GyroLog(short_log.t, short_log.rate_dps + effect, short_log.temp_c, short_log.ref_rate,
                     short_log.extras)
    score, chance = lv.oracle_shape_score(shaped, effect, rows, columns, seed=1)
    assert score > 2.0 * chance
    # The same log without the shape: the projection is chance's.
    score, chance = lv.oracle_shape_score(short_log, effect, rows, columns, seed=1)
    assert score < chance


def test_the_power_target_covers_long_fit_logs_from_a_quarter_magnitude(lv: ModuleType) -> None:
    """A cell of a 2 h fit log, or below magnitude 0.25, is reported but not judged."""
    assert lv.targeted_cell({'effect': 'shupe', 'magnitude': 0.25, 'hours': 6.0})
    assert not lv.targeted_cell({'effect': 'shupe', 'magnitude': 1.0, 'hours': 2.0})
    assert not lv.targeted_cell({'effect': 'shupe', 'magnitude': 0.1, 'hours': 6.0})


def test_the_drift_target_is_half_size_on_6_h_logs_and_quarter_size_on_12_h(lv: ModuleType) -> None:
    """Issue 35 item 5: a 6 h log cannot tell a quarter-size drift from a bounded wander; a 12 h log is judged on it."""
    assert not lv.targeted_cell({'effect': 'drift', 'magnitude': 0.25, 'hours': 6.0})
    assert lv.targeted_cell({'effect': 'drift', 'magnitude': 0.5, 'hours': 6.0})
    assert lv.targeted_cell({'effect': 'drift', 'magnitude': 0.25, 'hours': 12.0})
    assert not lv.targeted_cell({'effect': 'drift', 'magnitude': 0.1, 'hours': 12.0})
    assert ('drift', 0.25, 12.0) in lv.power_cells()
    _, power = lv.cases_for(0, 1)
    assert sum(c.effect == 'drift' and c.hours == 12.0 for c in power) == 1


def test_rerunning_the_whole_fit_without_saved_results_is_refused(lv: ModuleType, monkeypatch: pytest.MonkeyPatch,
                                                                  capsys: pytest.CaptureFixture[str]) -> None:
    """--rerun-whole-fit keeps the other sections of a saved run: without one it is an error, not a whole study."""
    monkeypatch.setattr(sys, 'argv', ['loop_validation.py', '--rerun-whole-fit'])
    with pytest.raises(SystemExit) as exit_info:
        lv.main()
    assert exit_info.value.code == 2
    assert '--rerun-whole-fit needs --from-results' in capsys.readouterr().err
