"""``calibrate allan``: IEEE Std 952 noise terms of records whose terms are known, and the node's parameters."""

import io
import json
import math

import numpy as np
import pytest
from rosbags.rosbag2 import StoragePlugin

from art_gyro_calibration.analysis.allan import allan_deviation
from art_gyro_calibration.analysis.cli import main
from art_gyro_calibration.analysis.noise import (BIAS_WINDOW_TOLERANCE, allan_of_record, fit_noise_terms,
                                                 node_parameters)
from art_gyro_calibration.log import read_log

from test_bags import write_bag


def flicker(n, fs, b, rng):
    """Bias instability B (deg/s): flicker rate noise of one-sided PSD B^2 / (pi f), Allan floor 0.664 B."""
    f = np.fft.rfftfreq(n, 1.0 / fs)
    amp = np.zeros_like(f)
    amp[1:] = np.sqrt(b * b / (np.pi * f[1:]) * fs * n / 2.0)
    return np.fft.irfft(amp * (rng.normal(size=f.size) + 1j * rng.normal(size=f.size)) / np.sqrt(2.0), n)


@pytest.mark.parametrize('seed', [0, 1, 2])
def test_white_noise_and_bias_instability_are_recovered(seed):
    """ARW within 2 %, bias instability within 10 % (5.8 h at 100 Hz); no rate random walk or ramp made up."""
    rng = np.random.default_rng(seed)
    fs, n, arw, bias = 100.0, 1 << 21, 1e-3, 3e-4   # 0.06 deg/sqrt(h), 1.08 deg/h
    x = 0.004 + rng.normal(0.0, arw * math.sqrt(fs), n) + flicker(n, fs, bias, rng)
    terms = fit_noise_terms(allan_deviation(x, fs), fs)
    assert terms.arw_dps_sqrt_s == pytest.approx(arw, rel=0.02)
    assert terms.bias_instability_dps == pytest.approx(bias, rel=0.10)
    named = terms.to_dict()
    assert named['arw_deg_per_sqrt_h'] == pytest.approx(0.06, rel=0.02)
    assert named['bias_instability_deg_per_h'] == pytest.approx(1.08, rel=0.10)
    assert named['rate_random_walk_deg_per_h_per_sqrt_h'] < 0.1 * 1.08
    assert named['quantisation_deg'] is None and named['rate_ramp_deg_per_h_per_h'] is None


def test_rate_random_walk_and_the_bias_window():
    """White noise within 10 %, a rate random walk within 25 % (seen at long taus, in few clusters); the window."""
    rng = np.random.default_rng(3)
    fs, n, arw, rrw = 50.0, 1 << 21, 2e-3, 2e-5
    x = rng.normal(0.0, arw * math.sqrt(fs), n) + np.cumsum(rng.normal(0.0, rrw / math.sqrt(fs), n))
    allan = allan_deviation(x, fs)
    terms = fit_noise_terms(allan, fs)
    assert terms.arw_dps_sqrt_s == pytest.approx(arw, rel=0.10)
    assert terms.rate_random_walk_dps_per_sqrt_s == pytest.approx(rrw, rel=0.25)
    assert terms.quantisation_deg is None
    node = node_parameters(terms, allan, 10.0)
    # sigma^2(T) = N^2/T + K^2 T/3 is least at T = sqrt(3) N / K; the window is the shortest within 10 % of it.
    best_t = math.sqrt(3.0) * terms.arw_dps_sqrt_s / terms.rate_random_walk_dps_per_sqrt_s
    least = float(terms.adev(best_t)[0])
    assert node.bias_window_s < best_t and node.bias_samples == round(node.bias_window_s * 10.0)
    assert node.bias_error_dps <= BIAS_WINDOW_TOLERANCE * least * 1.001
    assert float(terms.adev(0.9 * node.bias_window_s)[0]) > BIAS_WINDOW_TOLERANCE * least
    assert node.yaw_rate_stddev == pytest.approx(math.radians(terms.arw_dps_sqrt_s * math.sqrt(10.0)))
    assert not node.limited_by


def test_white_noise_alone_asks_for_the_longest_window_and_says_why():
    fs = 10.0
    x = np.random.default_rng(4).normal(0.0, 0.01, 100_000)
    allan = allan_deviation(x, fs)
    node = node_parameters(fit_noise_terms(allan, fs), allan, fs)
    assert node.yaw_rate_stddev == pytest.approx(math.radians(0.01), rel=0.02)
    # Within 10 % of the deviation at the longest tau, which falls as T^-1/2: 1/1.1^2 of it.
    assert node.bias_window_s == pytest.approx(allan.tau_s[-1] / BIAS_WINDOW_TOLERANCE ** 2, rel=0.03)
    assert 'longer record' in node.limited_by


def _csv(path, t, rate, raw=False):
    with open(path, 'w') as f:
        f.write('t,raw_rate,raw_temp\n' if raw else 't,rate_dps,temp_c\n')
        for a, b in zip(t, rate):
            f.write(f'{float(a)!r},{float(b)!r},{500 if raw else 25.0}\n')
    return path


def test_calibrate_allan_on_a_csv_and_on_a_bag_of_the_same_record(tmp_path, capsys):
    rng = np.random.default_rng(8)
    fs, n = 20.0, 40_000
    ns = 1_700_000_000_000_000_000 + np.arange(n, dtype=np.int64) * 50_000_000
    rate = 0.003 + rng.normal(0.0, 0.02, n)
    csv = _csv(tmp_path / 'still.csv', ns * 1e-9, rate)
    assert main(['allan', str(csv), '--out', str(tmp_path / 'a.json'), '--plots', str(tmp_path / 'plots'),
                 '--node-rate-hz', '10']) == 0
    out = capsys.readouterr()
    assert '/**:\n  ros__parameters:\n    yaw_rate_stddev: ' in out.out
    assert 'calibrate allan' not in out.err   # no progress bar: stderr is no terminal
    report = json.loads((tmp_path / 'a.json').read_text())
    for key in ('arw_deg_per_sqrt_h', 'bias_instability_deg_per_h', 'rate_random_walk_deg_per_h_per_sqrt_h'):
        assert isinstance(report[key], float)
    assert report['arw_deg_per_sqrt_h'] == pytest.approx(0.02 / math.sqrt(fs) * 60.0, rel=0.03)
    assert report['record']['samples'] == n and report['record']['sample_rate_hz'] == pytest.approx(fs)
    assert report['record']['gaps'] == 0
    deviation = report['allan_deviation']
    assert len(deviation['tau_s']) == len(deviation['adev_dps']) == len(deviation['low_dps']) \
        == len(deviation['high_dps']) >= 12
    assert np.all(np.array(deviation['low_dps']) < deviation['adev_dps'])
    params = report['node_parameters']
    assert params['rate_hz'] == 10.0
    assert params['yaw_rate_stddev'] == pytest.approx(math.radians(0.02 / math.sqrt(2.0)), rel=0.03)
    assert (tmp_path / 'plots' / 'allan.png').read_bytes()[:4] == b'\x89PNG'
    log = read_log(csv)
    bag = write_bag(tmp_path / 'bag', log, ns, StoragePlugin.SQLITE3)
    assert main(['allan', str(bag), '--out', str(tmp_path / 'b.json'), '--node-rate-hz', '10']) == 0
    from_bag = json.loads((tmp_path / 'b.json').read_text())
    assert np.allclose(from_bag['allan_deviation']['adev_dps'], deviation['adev_dps'], rtol=1e-9)
    assert from_bag['node_parameters']['bias_samples'] == params['bias_samples']


def test_a_raw_log_needs_its_scale_factor_and_gaps_are_reported(tmp_path, capsys):
    t = np.arange(2000) * 0.1
    t[1000:] += 5.0   # the gyro was silent 5 s
    raw = _csv(tmp_path / 'raw.csv', t, np.random.default_rng(9).integers(-20, 20, 2000), raw=True)
    assert main(['allan', str(raw), '--out', str(tmp_path / 'a.json')]) == 1
    assert 'raw counts need a calibration for their scale factors: give --serial or --rate-scale-factor' \
        in capsys.readouterr().err
    assert main(['allan', str(raw), '--out', str(tmp_path / 'a.json'), '--serial', 'NAVC4058']) == 0
    err = capsys.readouterr().err
    assert '1 gaps in the record (the longest 5.1 s)' in err
    assert json.loads((tmp_path / 'a.json').read_text())['record']['gaps'] == 1


class _Terminal(io.StringIO):
    def isatty(self):
        return True


def test_progress_is_shown_on_a_terminal_only():
    chunks = [(np.arange(k, k + 1000) * 0.01, np.random.default_rng(k).normal(size=1000)) for k in range(0, 5000, 1000)]
    terminal, pipe = _Terminal(), io.StringIO()
    import art_gyro_calibration.analysis.progress as progress
    ticks = iter(np.arange(0.0, 100.0, 1.0))
    real = progress.time.monotonic
    try:
        progress.time.monotonic = lambda: float(next(ticks))
        allan_of_record(iter(chunks), 'still.csv', progress_total=5000, progress_stream=terminal)
    finally:
        progress.time.monotonic = real
    allan_of_record(iter(chunks), 'still.csv', progress_total=5000, progress_stream=pipe)
    assert '100.0 %' in terminal.getvalue() and '[####' in terminal.getvalue()
    assert pipe.getvalue() == ''


def test_fit_takes_materiality_and_noise_budget_from_a_still_record(tmp_path, capsys):
    """``calibrate fit --still``: the still record's bias instability (as the loop reads a floor) is the materiality."""
    log = tmp_path / 'LOG.csv'
    assert main(['simulate', '--serial', 'NAVC4058', '--hours', '2', '--rate-hz', '2', '--seed', '4',
                 '--effect', 'shupe', '--out', str(log)]) == 0
    rng = np.random.default_rng(10)
    fs, n, bias = 10.0, 1 << 19, 1e-3   # 3.6 deg/h, above what the simulated residual holds
    still = _csv(tmp_path / 'still.csv', np.arange(n) / fs,
                 rng.normal(0.0, 0.003 * math.sqrt(fs), n) + flicker(n, fs, bias, rng))
    common = ['--rows', '3', '--columns', '2', '--serial', 'NAVC4058', '--draws', '40']
    assert main(['fit', str(log), *common, '--out', str(tmp_path / 'a.yaml'),
                 '--report', str(tmp_path / 'a.json')]) == 0
    assert main(['fit', str(log), *common, '--still', str(still), '--out', str(tmp_path / 'b.yaml'),
                 '--report', str(tmp_path / 'b.json')]) == 0
    capsys.readouterr()
    alone, with_still = (json.loads((tmp_path / f'{n}.json').read_text()) for n in 'ab')
    measured = with_still['still']['materiality_bias_instability_dph']
    assert measured == pytest.approx(3.6, rel=0.2)
    assert with_still['still']['source'] == str(still) and with_still['still']['samples'] == n
    assert with_still['materiality_dph'] == pytest.approx(measured, rel=1e-12)
    assert with_still['bias_instability_dph'] == pytest.approx(measured, rel=1e-12)
    assert with_still['adequacy']['bias_instability_dph'] == pytest.approx(measured, rel=1e-12)
    assert alone['materiality_dph'] < 0.6 * measured and 'still' not in alone
