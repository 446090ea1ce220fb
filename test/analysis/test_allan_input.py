"""``calibrate allan``'s input: a record at rest in seconds, or one clear refusal; a snippet the node accepts."""

from pathlib import Path

import numpy as np
import pytest
import yaml
from rosbags.rosbag2 import StoragePlugin, Writer

from art_gyro_calibration.analysis.cli import main
from art_gyro_calibration.analysis.noise import BIAS_SAMPLES_RANGE, YAW_RATE_STDDEV_RANGE
from art_gyro_calibration.analysis.simulate import SimulationSettings, simulate_run, write_run
from art_gyro_calibration.calibration import load_packaged_calibration
from art_gyro_calibration.ros.parameters import PARAMETERS, check_settings

from test_bags import TS, imu_message

HOURS = 0.25


def _run(tmp_path: Path, name: str, still: bool, ref_rate: bool = True) -> Path:
    """A simulated NAVC4058 run at 10 Hz: at rest throughout, or the rate table's steps (after its 60 s rest)."""
    settings = SimulationSettings(hours=HOURS, seed=4, **({'initial_rest_s': HOURS * 3600 + 10} if still else {}))
    run = simulate_run(load_packaged_calibration('NAVC4058'), settings)
    if not ref_rate:
        del run.columns['ref_rate']
    write_run(tmp_path / name, run)
    return tmp_path / name


def _allan(tmp_path: Path, log: Path, *extra: str) -> int:
    return main(['allan', str(log), '--out', str(tmp_path / 'a.json'), '--serial', 'NAVC4058', '--force', *extra])


def _one_error_line(err: str) -> str:
    lines = err.strip().splitlines()
    assert len(lines) == 1 and 'Traceback' not in err, err
    return lines[0]


def _node_accepts(snippet: str) -> None:
    """The snippet's values through the node's own checks, the other parameters at their defaults."""
    values = {name: entry[0] for name, entry in PARAMETERS.items()}
    given = yaml.safe_load(snippet)['/**']['ros__parameters']
    assert set(given) == {'yaw_rate_stddev', 'bias_samples'}
    values.update(given)
    check_settings(values)


def test_the_ranges_are_the_nodes() -> None:
    assert tuple(PARAMETERS['yaw_rate_stddev'][2]) == YAW_RATE_STDDEV_RANGE
    assert tuple(PARAMETERS['bias_samples'][2]) == BIAS_SAMPLES_RANGE


@pytest.mark.parametrize('node_rate', [None, '10', '1000', '0.05'])
def test_a_still_record_gives_a_snippet_the_node_accepts(tmp_path: Path, capsys: pytest.CaptureFixture[str],
                                                         node_rate: str | None) -> None:
    log = _run(tmp_path, 'still.csv', still=True)
    assert _allan(tmp_path, log, *(['--node-rate-hz', node_rate] if node_rate else [])) == 0
    out = capsys.readouterr().out
    arw = float(out.split('ARW ')[1].split()[0])
    assert arw == pytest.approx(0.1, rel=0.1)   # the simulation's 0.1 deg/sqrt(h)
    _node_accepts(out[out.index('/**:'):])


def test_a_rate_table_run_is_refused_by_its_ref_rate(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert _allan(tmp_path, _run(tmp_path, 'table.csv', still=False)) == 1
    line = _one_error_line(capsys.readouterr().err)
    assert 'table.csv: not at rest: ref_rate is' in line and 'at row 601 (t = 60 s)' in line
    assert not (tmp_path / 'a.json').exists()


def test_a_turning_record_without_a_reference_is_refused_by_its_steps(tmp_path: Path,
                                                                      capsys: pytest.CaptureFixture[str]) -> None:
    assert _allan(tmp_path, _run(tmp_path, 'table.csv', still=False, ref_rate=False)) == 1
    line = _one_error_line(capsys.readouterr().err)
    assert 'table.csv: not at rest: the mean rate steps by' in line and 'blocks from 50 s and 60 s' in line


def test_a_small_bump_in_a_still_record_is_refused(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    rng = np.random.default_rng(2)
    t = np.arange(20_000) * 0.01
    rate = rng.normal(0.0, 0.05, t.size)
    rate[12_000:12_500] += 0.05   # 5 s at 0.05 deg/s: the noise's size a sample, far beyond it over 10 s
    _csv(tmp_path / 'bump.csv', t, rate)
    assert main(['allan', str(tmp_path / 'bump.csv'), '--out', str(tmp_path / 'a.json')]) == 1
    assert 'not at rest' in _one_error_line(capsys.readouterr().err)
    rate[12_000:12_500] -= 0.05
    _csv(tmp_path / 'bump.csv', t, rate)
    assert main(['allan', str(tmp_path / 'bump.csv'), '--out', str(tmp_path / 'a.json'), '--force']) == 0


def _csv(path: Path, t: np.ndarray, rate: np.ndarray) -> Path:
    with open(path, 'w') as f:
        f.write('t,rate_dps,temp_c\n')
        for a, b in zip(t, rate):
            f.write(f'{float(a)!r},{float(b)!r},25.0\n')
    return path


@pytest.mark.parametrize('factor, unit', [(1e3, '10 Hz if they are ms'), (1e9, '10 Hz if they are ns'),
                                          (1e6, '10 Hz if they are us')])
def test_a_time_column_in_another_unit_is_named(tmp_path: Path, capsys: pytest.CaptureFixture[str],
                                                factor: float, unit: str) -> None:
    t = np.arange(3000) * 0.1 * factor
    _csv(tmp_path / 'x.csv', t, np.random.default_rng(1).normal(0.0, 0.01, t.size))
    assert main(['allan', str(tmp_path / 'x.csv'), '--out', str(tmp_path / 'a.json')]) == 1
    line = _one_error_line(capsys.readouterr().err)
    assert 'the time column must be in seconds' in line and unit in line


def test_repeated_times_are_refused(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    t = np.repeat(np.arange(1500) * 0.1, 2)
    _csv(tmp_path / 'x.csv', t, np.random.default_rng(1).normal(0.0, 0.01, t.size))
    assert main(['allan', str(tmp_path / 'x.csv'), '--out', str(tmp_path / 'a.json')]) == 1
    assert 'times repeat the one before' in _one_error_line(capsys.readouterr().err)


def test_a_bag_whose_stamps_go_back_is_refused(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    n = 2000
    recorded = 1_700_000_000_000_000_000 + np.arange(n, dtype=np.int64) * 100_000_000
    stamps = recorded.copy()
    stamps[1200:] -= 50_000_000_000   # the unit's clock stepped back 50 s; the bag recorded in order
    rate = np.random.default_rng(3).normal(0.0, 1e-4, n)
    with Writer(tmp_path / 'bag', version=9, storage_plugin=StoragePlugin.MCAP) as w:
        imu = w.add_connection('/imu/uncalibrated', 'sensor_msgs/msg/Imu', typestore=TS)
        for k in range(n):
            w.write(imu, int(recorded[k]), TS.serialize_cdr(imu_message(int(stamps[k]), float(rate[k])),
                                                            'sensor_msgs/msg/Imu'))
    assert main(['allan', str(tmp_path / 'bag'), '--out', str(tmp_path / 'a.json')]) == 1
    line = _one_error_line(capsys.readouterr().err)
    assert 'time goes back at sample 1201: 1.70000007e+09 s after 1.70000012e+09 s' in line


@pytest.mark.parametrize('rate', ['1e-300', '1e300', '1e-3', '1e6'])
def test_an_extreme_node_rate_is_one_line(tmp_path: Path, capsys: pytest.CaptureFixture[str], rate: str) -> None:
    log = _csv(tmp_path / 'x.csv', np.arange(3000) * 0.1, np.random.default_rng(1).normal(0.0, 0.01, 3000))
    assert main(['allan', str(log), '--out', str(tmp_path / 'a.json'), '--node-rate-hz', rate]) == 1
    assert '--node-rate-hz must be in 0.01..100000 Hz' in _one_error_line(capsys.readouterr().err)


def test_a_constant_record_is_one_line(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    log = _csv(tmp_path / 'x.csv', np.arange(3000) * 0.1, np.full(3000, 0.25))
    assert main(['allan', str(log), '--out', str(tmp_path / 'a.json')]) == 1
    line = _one_error_line(capsys.readouterr().err)
    assert 'every one of its 3000 samples reads 0.25 deg/s: a constant record' in line


def test_noise_the_node_cannot_take_is_refused(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    # A per-sample noise of 1e-6 deg/s (2e-8 rad/s): below the node's yaw_rate_stddev range.
    log = _csv(tmp_path / 'x.csv', np.arange(3000) * 0.1, np.random.default_rng(1).normal(0.0, 1e-6, 3000))
    assert main(['allan', str(log), '--out', str(tmp_path / 'a.json')]) == 1
    line = _one_error_line(capsys.readouterr().err)
    assert "outside what the node takes as yaw_rate_stddev (1e-07..1 rad/s)" in line
