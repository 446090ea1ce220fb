"""A deeply nested YAML file (well under MAX_YAML_BYTES) is refused in one line naming it, not a RecursionError."""

import pytest

from art_gyro_calibration.analysis.cli import main
from art_gyro_calibration.analysis.simulate import SimulationSettings, simulate_run, write_run
from art_gyro_calibration.calibration import (MAX_YAML_BYTES, MAX_YAML_DEPTH, CalibrationError,
                                              load_packaged_calibration, read_yaml)

DEPTH = 10_000


def deep_yaml(path, block=False):
    """A params file whose one value is nested DEPTH levels (flow lists), or MAX_YAML_DEPTH + 1 (block mappings)."""
    if block:
        levels = MAX_YAML_DEPTH + 1
        body = ''.join(f'{"  " * (k + 2)}k{k}:\n' for k in range(levels)) + '  ' * (levels + 2) + 'v: 1\n'
    else:
        body = '    a: ' + '[' * DEPTH + ']' * DEPTH + '\n'
    path.write_text('/**:\n  ros__parameters:\n' + body)
    assert path.stat().st_size < MAX_YAML_BYTES
    return path


@pytest.mark.parametrize('block', [False, True], ids=['flow', 'block'])
def test_read_yaml_refuses_deep_nesting_in_one_line(tmp_path, block):
    path = deep_yaml(tmp_path / 'deep.yaml', block)
    with pytest.raises(CalibrationError) as e:
        read_yaml(path, 'calibration file')
    assert str(e.value).startswith(f'{path}: not a calibration file: nested deeper than {MAX_YAML_DEPTH} levels '
                                   '(line ')
    assert '\n' not in str(e.value)


def test_the_packaged_calibrations_are_well_within_the_depth():
    load_packaged_calibration('NAVC3545')


@pytest.fixture
def log(tmp_path):
    path = tmp_path / 'LOG.csv'
    write_run(path, simulate_run(load_packaged_calibration('NAVC3545'), SimulationSettings(hours=0.05)))
    return path


@pytest.mark.parametrize('command', [
    lambda log, deep, out: ['replay', str(log), '--calibration', str(deep)],
    lambda log, deep, out: ['apply', str(log), '--calibration', str(deep), '--out', str(out / 'OUT.csv')],
    lambda log, deep, out: ['fit', str(log), '--rows', '1', '--columns', '2', '--serial', 'NAVC3545', '--baseline',
                            str(deep), '--out', str(out / 'CAL.yaml'), '--report', str(out / 'REPORT.json')],
], ids=['replay', 'apply', 'fit_baseline'])
def test_calibrate_refuses_a_deep_calibration_in_one_line(tmp_path, log, capsys, command):
    deep = deep_yaml(tmp_path / 'deep.yaml')
    assert main(command(log, deep, tmp_path)) == 1
    err = capsys.readouterr().err
    assert f'{deep}: not a calibration file: nested deeper than {MAX_YAML_DEPTH} levels' in err, err
    assert 'Traceback' not in err and 'RecursionError' not in err and len(err.splitlines()) == 1, err
