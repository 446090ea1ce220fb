"""The pure helpers of research/studies/drift_null.py: telling the two worlds apart, and the summary of the runs."""

from collections.abc import Callable
from types import ModuleType
from typing import Any

import numpy as np
import pytest


@pytest.fixture(scope='module')
def dn(load_study: Callable[[str], ModuleType]) -> ModuleType:
    """The study as a module."""
    return load_study('drift_null')


def _nulls(dn: ModuleType, world: str, told_scale: float, count: int, rng: np.random.Generator) -> list[dict[str, Any]]:
    """Null runs whose spectrum bins are exponential about 1, those the test reads about ``told_scale``."""
    mean = np.ones(dn.BINS)
    mean[list(dn.TOLD_BINS)] = told_scale
    return [{'world': world, 'drift': False, 'power_dph2': rng.exponential(mean).tolist()} for _ in range(count)]


def test_one_log_tells_the_worlds_apart_as_far_as_their_slow_spectra_differ(dn):
    rng = np.random.default_rng(1)
    bounded, walk = dn.WORLDS
    far = dn.told_apart({bounded: _nulls(dn, bounded, 1.0, 400, rng), walk: _nulls(dn, walk, 10.0, 400, rng)})
    assert min(far.values()) > 0.95
    alike = dn.told_apart({bounded: _nulls(dn, bounded, 1.0, 400, rng), walk: _nulls(dn, walk, 1.0, 400, rng)})
    assert abs(sum(alike.values()) / 2 - 0.5) < 0.1   # a coin, both worlds weighed alike


def _run(world: str, drift: bool, statistic: float, found: list[str] | None = None,
         art: float = 3.0, extended: float = 3.0) -> dict[str, Any]:
    run: dict[str, Any] = {'world': world, 'drift': drift, 'seed': 0, 'period_h': 12.0,
                           'power_dph2': [1.0] * 16, 'statistics': {'fitted': statistic, 'held_out': statistic}}
    if found is not None:
        run['found'] = found
        run['field'] = {s: {'art': {'systematic_rms_dph': art}, 'extended': {'systematic_rms_dph': extended}}
                        for s in ('cold', 'warm')}
    return run


def test_the_summary_holds_each_test_to_each_worlds_null_and_counts_the_loops_harm(dn):
    bounded, walk = dn.WORLDS
    results = [_run(bounded, False, x) for x in np.linspace(0.0, 1.0, 200)]
    results += [_run(walk, False, x) for x in np.linspace(0.0, 4.0, 200)]
    results += [_run(bounded, True, 2.0, ['time'], art=5.0, extended=3.0) for _ in range(10)]
    results += [_run(walk, True, 5.0, [], art=5.0, extended=5.0) for _ in range(10)]
    # Two loop runs on the random walk's nulls: a harmless claim and one 1.5 deg/h worse on both second runs.
    results[200] = _run(walk, False, 0.0, ['time'], art=3.0, extended=3.2)
    results[201] = _run(walk, False, 0.0, ['time_since_power_on'], art=3.0, extended=4.5)
    s = dn.summarise(results)
    one = s['tests']['fitted']['0.01']
    assert one['bounded_drift_found'] == {bounded: 1.0, walk: 0.0}   # 2.0: beyond 1.0, short of 3.96
    assert one['walk_drift_found'] == 1.0
    assert one['walk_nulls_beyond_bounded'] == pytest.approx(np.mean(np.linspace(0.0, 4.0, 200)[2:] > 0.995), abs=0.01)
    loop = s['loop']
    assert loop[walk] | {'null_largest_worsening_dph': 0} == {
        'null_runs': 2, 'null_any': 2, 'null_time': 1, 'null_worse': 1, 'null_largest_worsening_dph': 0,
        'drift_runs': 10, 'drift_time': 0, 'drift_art_dph': 5.0, 'drift_extended_dph': 5.0}
    assert loop[walk]['null_largest_worsening_dph'] == pytest.approx(1.5)
    assert loop[bounded]['drift_time'] == 10 and loop[bounded]['drift_extended_dph'] == pytest.approx(3.0)
