"""``calibrate replay`` and ``apply`` say when a warm-up term is not applied, why, and which flag applies it."""

from pathlib import Path

import pytest

from art_gyro_calibration.analysis.cli import main
from art_gyro_calibration.analysis.simulate import SimulationSettings, simulate_run, write_run
from art_gyro_calibration.calibration import Calibration, load_packaged_calibration, write_calibration
from art_gyro_calibration.terms import Term

NOT_APPLIED = ('calibrate: warning: the warm-up term (72.0 deg/h at power-on) is not applied: the log is not known to '
               'start at the gyro\'s power-on, so the term counts as decayed, as the node does by default; '
               '--powered-on-at-start applies it from the first row')


def _files(tmp_path: Path, warm_up: bool = True) -> tuple[Path, Path]:
    """A cold simulated run of NAVC4058 with a 0.02 deg/s warm-up, and its calibration (with the term or without)."""
    base = load_packaged_calibration('NAVC4058')
    terms = (Term('time_since_power_on', 'exp_decay', (0.02,), (), 1200.0),) if warm_up else ()
    cal = Calibration(base.serial_number, base.rate_scale_factor, base.polynomial, base.temperature_range_c,
                      terms=terms)
    write_calibration(tmp_path / 'cal.yaml', cal, header='a test')
    write_run(tmp_path / 'cold.csv', simulate_run(base, SimulationSettings(hours=0.2, effects=('warmup',), seed=5)))
    return tmp_path / 'cold.csv', tmp_path / 'cal.yaml'


@pytest.mark.parametrize('command', ['replay', 'apply'])
def test_an_unapplied_warm_up_is_said_with_the_flag_that_applies_it(
        tmp_path: Path, command: str, capsys: pytest.CaptureFixture[str]) -> None:
    log, cal = _files(tmp_path)
    out = ['--out', str(tmp_path / 'out.csv'), '--force'] if command == 'apply' else []
    assert main([command, str(log), '--calibration', str(cal), *out]) == 0
    assert capsys.readouterr().err.strip().splitlines() == [NOT_APPLIED]
    assert main([command, str(log), '--calibration', str(cal), *out, '--powered-on-at-start']) == 0
    assert 'warm-up' not in capsys.readouterr().err


def test_nothing_is_said_without_a_warm_up(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    log, cal = _files(tmp_path, warm_up=False)
    assert main(['replay', str(log), '--calibration', str(cal)]) == 0
    assert 'warm-up' not in capsys.readouterr().err
