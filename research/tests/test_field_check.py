"""The field-check study's own simulator agrees with the package's compensation (through the CLI)."""

import stat
import subprocess
import sys
from pathlib import Path
from typing import Any

import field_check as fc
import numpy as np
import pytest

from art_gyro_calibration.signals import SignalFilters


def test_polynomial_is_the_report_form() -> None:
    """The correction is sum_ij c[i][j] T^(rows-1-i) rate^(cols-1-j), rows of temperature powers highest first."""
    gyro = fc.Gyro.packaged('NAVC3545')
    rate, temp = np.array([-37.0, 0.0, 81.5]), np.array([12.0, 30.0, 47.0])
    c = np.array(gyro.coefficients)
    rows, cols = c.shape
    naive = sum(c[i, j] * temp ** (rows - 1 - i) * rate ** (cols - 1 - j) for i in range(rows) for j in range(cols))
    assert np.allclose(gyro.comp(rate, temp), naive, rtol=1e-12, atol=1e-15)


def test_packaged_calibration_removes_the_simulated_polynomial(tmp_path: Path) -> None:
    """With no effect, no wander and no self-heating, `calibrate apply` of the packaged file leaves only noise."""
    gyro = fc.Gyro.packaged('NAVC3545')
    phys = fc.Physics(self_heat_c=0.0, wander_dph=1e-9, rrw_dph_rthr=0.0)
    run = fc.simulate(gyro, phys, 0.25, 7, 0.0, 0.0)
    log = tmp_path / 'run.csv'
    fc.write_log(run, log)
    cmd_log = tmp_path / 'commands.log'
    err = fc.applied_error(log, fc.REPO / 'config' / 'NAVC3545.yaml', run, True, tmp_path / 'out.csv', cmd_log)
    got, best = fc.score(err), fc.score(fc.true_signals_error(run))
    # The same static bias and noise: the packaged calibration is the truth here, up to the quantised temperature.
    assert abs(got['mean_dph'] - best['mean_dph']) < 0.5
    assert got['sys_rms_dph'] < best['sys_rms_dph'] + 0.5


def test_the_study_never_imports_the_package() -> None:
    """It drives the package through its command line only."""
    code = 'import sys; sys.path.insert(0, "research/studies"); import field_check; ' \
           'print(any(m.startswith("art_gyro_calibration") for m in sys.modules))'
    done = subprocess.run([sys.executable, '-c', code], cwd=fc.REPO, capture_output=True, text=True, check=True)
    assert done.stdout.strip() == 'False'


def test_a_2h_fit_is_not_worse_than_the_packaged_file_on_a_warm_second_run(tmp_path: Path) -> None:
    """The study's shupe_k2.4_slow, run 2: a 2 h fit and a warm second run of the same gyro (its seeds).

    The loop explained the 2 h log's Shupe effect with a rate-sign term; on the baseline polynomial it
    was 0.63 deg/h better on the log (materiality 1.19) and was written: 12.34 against 9.90 deg/h on the
    warm second run. Terms on top of the baseline are now written only if better by the materiality.
    """
    case = next(c for c in fc.CASES if c.name == 'shupe_k2.4_slow')
    gyro, seed = fc.Gyro.packaged(fc.SERIAL), case.seed + 2000
    fit = tmp_path / 'fit.csv'
    fc.write_log(fc.simulate(gyro, case.physics, 2.0, seed * 100 + 11, 0.0, 0.0), fit)
    cal, report, cmd_log = tmp_path / 'cal.yaml', tmp_path / 'REPORT.json', tmp_path / 'commands.log'
    fc.calibrate('fit', str(fit), '--rows', '3', '--columns', '4', '--serial', fc.SERIAL, '--out', str(cal),
                 '--report', str(report), log=cmd_log)
    warm = fc.simulate(gyro, case.physics, fc.WARM_SECOND_HOURS, seed * 100 + 2, fc.WARM_START_S, fc.WARM_HEADING_DEG)
    second = tmp_path / 'warm.csv'
    fc.write_log(warm, second)
    baseline = fc.REPO / 'config' / f'{fc.SERIAL}.yaml'
    written, packaged = (fc.score(fc.applied_error(second, c, warm, False, tmp_path / 'out.csv', cmd_log))
                         for c in (cal, baseline))
    assert written['sys_rms_dph'] <= packaged['sys_rms_dph'] + 1.0


def test_the_true_form_through_the_node_is_the_truth_where_the_node_signal_is_true(tmp_path: Path) -> None:
    """A warm-up and an aged slope, written as the true form's file, leave what the true signals leave.

    The node's time since power-on and temperature are the true ones (up to 0.05 degC counts), so through
    `calibrate apply` the file must match the true form on the true signals; the packaged file misses both.
    """
    gyro = fc.Gyro.packaged(fc.SERIAL)
    phys = fc.Physics(self_heat_c=0.0, wander_dph=1e-9, rrw_dph_rthr=0.0, warmup_dph=40.0, warmup_tau_s=600.0,
                      aged_dph_per_c=0.5)
    run = fc.simulate(gyro, phys, 0.25, 11, 0.0, 0.0, chamber_start_c=45.0)
    log, cal, cmd_log = tmp_path / 'run.csv', tmp_path / 'true.yaml', tmp_path / 'commands.log'
    fc.write_log(run, log)
    assert fc.true_form_file(phys, cal)
    node, packaged = (fc.score(fc.applied_error(log, c, run, True, tmp_path / 'out.csv', cmd_log))
                      for c in (cal, fc.REPO / 'config' / f'{fc.SERIAL}.yaml'))
    truth = fc.score(fc.true_signals_error(run))
    assert abs(node['mean_dph'] - truth['mean_dph']) < 0.3
    assert abs(node['sys_rms_dph'] - truth['sys_rms_dph']) < 0.3
    assert abs(packaged['mean_dph'] - truth['mean_dph']) > 5.0


def test_no_true_form_file_for_a_shape_no_form_has(tmp_path: Path) -> None:
    """A heading effect or a temperature step has no calibration file the node takes."""
    for phys in (fc.Physics(heading_saw_dph=6.0), fc.Physics(heading_bump_dph=6.0), fc.Physics(temp_step_dph=6.0)):
        assert not fc.true_form_file(phys, tmp_path / 'true.yaml')
    assert not (tmp_path / 'true.yaml').exists()
    assert fc.true_form_file(fc.Physics(shupe_k=0.6), tmp_path / 'true.yaml')


def test_every_case_keeps_the_gyro_in_its_calibrated_range() -> None:
    """Chamber phases, cold soaks and self-heating shapes of every case, and the protocol's chamber starts."""
    gyro = fc.Gyro.packaged(fc.SERIAL)
    for case in fc.CASES:
        for start in (None, *[c for _, _, c in fc.PROTOCOL if c is not None]):
            temp = fc.simulate(gyro, case.physics, 3.0, case.seed, 0.0, 0.0, start)['temp']
            assert 10.0 <= temp.min() and temp.max() <= 50.0, (case.name, start, temp.min(), temp.max())


def _results(loop: float, node: float, signals: float, case: str = 'shupe') -> list[dict[str, Any]]:
    def s(v: float) -> dict[str, float]:
        return {'sys_rms_dph': v, 'mean_dph': 0.0}
    run = {'baseline': s(5.0), 'loop_6h': s(loop), 'true_signals': s(signals), 'true_node': s(node)}
    return [{'case': case, 'scores': {'cold': run, 'warm': run}}]


def test_targets_fail_where_the_issue_says() -> None:
    """Written over 1.5x the true form through the node, the node over 1.5x the true signals, a null run hurt."""
    ok = fc.targets(_results(loop=2.9, node=2.0, signals=1.4))
    assert [r['passed'] for r in ok] == [True, True]
    bad = fc.targets(_results(loop=3.4, node=2.2, signals=1.4))
    assert [r['passed'] for r in bad] == [False, False]
    null = fc.targets(_results(loop=6.1, node=5.0, signals=5.0, case='null_x'))
    expected = [(False, True), (False, True), (True, False)]
    assert [(r['target'].startswith('no null'), r['passed']) for r in null] == expected


@pytest.mark.parametrize('help_text, refused', [
    ('usage: calibrate fit LOG [--validate OTHER_LOG]', True),
    ('usage: calibrate fit LOG [LOG ...] [--warm-start LOG]', False)])
def test_the_several_run_fit_is_skipped_only_when_calibrate_fit_takes_one_log(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch, help_text: str, refused: bool) -> None:
    """The study asks `calibrate fit --help` whether it takes --warm-start."""
    fake = tmp_path / 'python'
    fake.write_text(f'#!/bin/sh\necho "{help_text}"\n')
    fake.chmod(fake.stat().st_mode | stat.S_IXUSR)
    monkeypatch.setattr(fc, 'PYTHON', str(fake))
    assert bool(fc.several_runs_refusal()) == refused


def test_the_true_form_file_names_the_filters_a_fit_writes() -> None:
    """A file naming no filters keeps the old first-order one: the true form must use what a new fit writes."""
    defaults = SignalFilters()
    assert fc.FIT_FILTERS == {'temperature_rate_tau_s': defaults.temperature_rate_tau_s,
                              'rate_change_tau_s': defaults.rate_change_tau_s,
                              'temperature_rate_form': defaults.temperature_rate_form}
