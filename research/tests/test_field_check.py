"""The field-check study's own simulator agrees with the package's compensation (through the CLI)."""

import subprocess
import sys
from pathlib import Path

import field_check as fc
import numpy as np


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
    got, best = fc.score(err), fc.score(fc.best_error(run))
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
    warm = fc.simulate(gyro, case.physics, fc.SECOND_RUN_HOURS, seed * 100 + 2, fc.WARM_START_S, fc.WARM_HEADING_DEG)
    second = tmp_path / 'warm.csv'
    fc.write_log(warm, second)
    baseline = fc.REPO / 'config' / f'{fc.SERIAL}.yaml'
    written, packaged = (fc.score(fc.applied_error(second, c, warm, False, tmp_path / 'out.csv', cmd_log))
                         for c in (cal, baseline))
    assert written['sys_rms_dph'] <= packaged['sys_rms_dph'] + 1.0
