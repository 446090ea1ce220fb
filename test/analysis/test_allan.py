"""Allan deviation against the two noises whose Allan deviation is known in closed form."""

import numpy as np
import pytest

from art_gyro_calibration.analysis.allan import allan_deviation


def _slope(result, lo, hi):
    pick = (result.tau_s >= lo) & (result.tau_s <= hi)
    return np.polyfit(np.log(result.tau_s[pick]), np.log(result.adev[pick]), 1)[0]


def test_white_noise_falls_as_inverse_root_tau():
    fs, sigma = 10.0, 0.3
    x = np.random.default_rng(1).normal(0.0, sigma, 200_000)
    result = allan_deviation(x, fs)
    assert result.tau_s[0] == pytest.approx(1 / fs)
    assert np.allclose(np.diff(np.log2(result.tau_s)), 1.0)
    expected = sigma / np.sqrt(result.tau_s * fs)
    # Relative error of each value ~ 1/sqrt(independent clusters); stay where there are >= 200.
    good = result.terms / (result.tau_s * fs) >= 200
    assert good.sum() >= 8
    assert np.allclose(result.adev[good], expected[good], rtol=0.12)
    assert _slope(result, 0.1, 50.0) == pytest.approx(-0.5, abs=0.03)
    assert result.at(0.4) == pytest.approx(sigma / 2, rel=0.05)


def test_rate_random_walk_rises_as_root_tau():
    fs, q = 1.0, 0.01
    x = np.cumsum(np.random.default_rng(2).normal(0.0, q, 400_000))
    result = allan_deviation(x, fs)
    assert _slope(result, 16.0, 4096.0) == pytest.approx(0.5, abs=0.06)
    tau = 256.0
    assert result.at(tau) == pytest.approx(q * np.sqrt(fs * tau / 3), rel=0.15)


def test_runs_keep_a_jump_between_them_out():
    rng = np.random.default_rng(3)
    x = np.concatenate([rng.normal(0.0, 1.0, 5000), rng.normal(50.0, 1.0, 5000)])
    run = np.repeat([0, 1], 5000)
    pooled = allan_deviation(x, 1.0, run)
    joined = allan_deviation(x, 1.0)
    assert pooled.at(64.0) == pytest.approx(1 / 8, rel=0.25)
    assert joined.at(64.0) > 10 * pooled.at(64.0)
    # The longest run bounds the taus.
    assert pooled.tau_s[-1] * 3 <= 5000


def test_refuses_bad_input():
    with pytest.raises(ValueError, match='finite'):
        allan_deviation([1.0, np.nan, 2.0, 3.0, 4.0, 5.0], 1.0)
    with pytest.raises(ValueError, match='too few'):
        allan_deviation([1.0, 2.0, 3.0], 1.0)
    with pytest.raises(ValueError, match='positive'):
        allan_deviation(np.zeros(100), 0.0)
    with pytest.raises(ValueError, match='outside'):
        allan_deviation(np.random.default_rng(0).normal(size=100), 1.0).at(1000.0)


def test_streamed_in_chunks_and_through_a_file_equals_allantools():
    """Every overlapping difference, as allantools.oadev sums them: to 1e-9 relative, in memory or spilled to a file."""
    allantools = pytest.importorskip('allantools')
    from art_gyro_calibration.analysis.allan import AllanAccumulator
    rng = np.random.default_rng(5)
    n, fs = 300_007, 100.0
    x = 12.5 + rng.normal(0.0, 0.02, n) + np.cumsum(rng.normal(0.0, 1e-5, n))
    taus, expected, _, counts = allantools.oadev(x, rate=fs, data_type='freq', taus='octave')
    for memory in (1 << 30, 1000):   # the second spills the angle to a temporary file after 1000 samples
        with AllanAccumulator(memory_samples=memory) as acc:
            for part in np.array_split(x, 13):
                acc.add(part)
            got = acc.result(fs)
        m = np.rint(got.tau_s * fs)
        pick = np.isin(np.rint(taus * fs), m)
        assert pick.sum() >= 15 and np.all(np.isin(m, np.rint(taus * fs)))
        assert np.allclose(got.adev, expected[pick], rtol=1e-9, atol=0)
        assert np.array_equal(got.terms, counts[pick])
    assert np.allclose(allan_deviation(x, fs).adev, got.adev, rtol=1e-12)


def test_long_taus_read_three_windows_from_the_store(monkeypatch):
    """Past the windowed levels each tau reads its three windows apart: the same sums."""
    from art_gyro_calibration.analysis import allan
    x = np.random.default_rng(6).normal(size=5000)
    whole = allan_deviation(x, 1.0)
    monkeypatch.setattr(allan, '_SHORT_MAX_M', 2)
    monkeypatch.setattr(allan, '_WINDOW_MAX_M', 8)
    monkeypatch.setattr(allan, '_SHORT_BLOCK', 7)
    monkeypatch.setattr(allan, '_LONG_BLOCK', 100)
    with allan.AllanAccumulator(memory_samples=64) as acc:
        acc.add(x)
        split = acc.result(1.0)
    assert np.allclose(split.adev, whole.adev, rtol=1e-12)


def test_confidence_interval_holds_the_truth_about_as_often_as_it_says():
    fs, sigma = 10.0, 1.0
    rng = np.random.default_rng(7)
    inside = []
    for _ in range(40):
        result = allan_deviation(rng.normal(0.0, sigma, 4096), fs)
        low, high = result.confidence(fs, 0.683)
        truth = sigma / np.sqrt(result.tau_s * fs)
        assert np.all(low < result.adev) and np.all(result.adev < high)
        inside.append((low <= truth) & (truth <= high))
    share = np.mean(inside, axis=0)
    assert np.all((share[:6] > 0.45) & (share[:6] < 0.9)), share
