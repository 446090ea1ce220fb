"""The field-check study's own simulator agrees with the package's compensation (through the CLI)."""

import subprocess
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / 'studies'))

import field_check as fc  # noqa: E402


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
    code = 'import sys; sys.path.insert(0, "studies"); import field_check; ' \
           'print(any(m.startswith("art_gyro_calibration") for m in sys.modules))'
    done = subprocess.run([sys.executable, '-c', code], cwd=fc.REPO, capture_output=True, text=True, check=True)
    assert done.stdout.strip() == 'False'
