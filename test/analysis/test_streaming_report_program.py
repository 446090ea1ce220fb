"""``calibrate apply`` with the packaged calibrations as shipped gives the report program's numbers, any temperature.

The report prints no temperature range and its program clamps nothing: from -40 to 85 degC (a winter outdoors, a hot
enclosure) the command's output is the compiled program's (test/c/art_reference.c).
"""

from pathlib import Path

import numpy as np
import pytest
from c_reference import compile_reference, run_reference

from art_gyro_calibration.analysis.cli import main
from art_gyro_calibration.calibration import find_calibration_file, load_packaged_calibration
from art_gyro_calibration.gyro_physics import measured_from_true

BIAS_SAMPLES = 100


@pytest.mark.parametrize('serial', ['NAVC3545', 'NAVC4058'])
def test_calibrate_apply_matches_the_c_program_from_minus_40_to_85_degc(serial: str, tmp_path: Path, capsys) -> None:
    cal = load_packaged_calibration(serial)
    rng = np.random.default_rng(11)
    n = 2000
    true = np.concatenate([np.zeros(BIAS_SAMPLES), rng.uniform(-100, 100, n - BIAS_SAMPLES)])
    temp = np.concatenate([np.full(BIAS_SAMPLES, 22.0), rng.uniform(-40, 85, n - BIAS_SAMPLES)])
    raw_rate = np.round(measured_from_true(cal.polynomial, true, temp) / cal.rate_scale_factor).astype(np.int32)
    raw_temp = np.round(temp / cal.temp_scale_factor).astype(np.int32)
    log = tmp_path / 'log.csv'
    with open(log, 'w') as f:
        f.write('t,raw_rate,raw_temp\n')
        f.writelines(f'{k * 0.1:.1f},{r},{c}\n' for k, (r, c) in enumerate(zip(raw_rate, raw_temp)))
    out = tmp_path / 'out.csv'
    assert main(['apply', str(log), '--calibration', str(find_calibration_file(serial)), '--out', str(out),
                 '--bias-samples', str(BIAS_SAMPLES)]) == 0
    printed = capsys.readouterr().out
    data = np.loadtxt(out, delimiter=',', skiprows=1)
    reference, _ = run_reference(compile_reference(tmp_path), cal, raw_rate, raw_temp, BIAS_SAMPLES, tmp_path)
    np.testing.assert_allclose(data[BIAS_SAMPLES:, 3], reference[:, 0], atol=2e-5)   # comp
    np.testing.assert_allclose(data[BIAS_SAMPLES:, 4], reference[:, 1], atol=5e-5)   # CompRate
    outside = int(np.sum((raw_temp * 0.05 < 10.0) | (raw_temp * 0.05 > 50.0)))
    assert f'{outside} outside the calibrated range 10..50 degC (temperature_warn_range_c, assumed' in printed, printed
    assert 'not clamped' in printed
