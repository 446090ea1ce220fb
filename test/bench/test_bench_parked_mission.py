"""The parked-bias mission benchmark's claims on a short run: a bias at every long stop, none on a creep."""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path
from types import ModuleType

import numpy as np
import pytest

pytest.importorskip('rclpy')   # the benchmark runs the node's collections (ros/bias_service.py)

BENCH = Path(__file__).resolve().parents[2] / 'bench' / 'bench_parked_mission.py'


@pytest.fixture(scope='module')
def bench() -> ModuleType:
    """The benchmark script as a module (bench/ is no package)."""
    spec = importlib.util.spec_from_file_location('bench_parked_mission', BENCH)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module   # its dataclasses look their module up
    spec.loader.exec_module(module)
    return module


def test_a_parked_bias_at_every_stop_long_enough(bench: ModuleType) -> None:
    """Two hours of legs and stops: one parked bias per stop of settle_s + the window, the shorter ones 'moved'."""
    calibration = bench.load_packaged_calibration(bench.SERIAL)
    settings = bench.default_settings()
    mission = bench.day_mission(calibration, np.random.default_rng(3), 7200.0)
    parked = bench.parked_biases(mission, settings, False)
    long_stops = bench.long_enough(mission, settings)
    assert long_stops >= 5
    assert parked.updates == len(parked.biases) - 1 == long_stops
    assert parked.refused['moved'] == len(mission.stops) - 1 - long_stops


@pytest.mark.parametrize('creep_dps', [0.05, 0.1, 0.2, 0.5])
def test_no_parked_bias_on_a_creep_with_the_gyro_stillness(bench: ModuleType, creep_dps: float) -> None:
    """A topic that says parked while the robot creeps: the gyro's stillness refuses every collection."""
    calibration = bench.load_packaged_calibration(bench.SERIAL)
    settings = bench.default_settings()
    rng = np.random.default_rng(4)
    assert bench.creep_taken(calibration, rng, settings, creep_dps, 3, True, False) == 0
    # The same creeps reach a collection: a Bool alone believes one below the service's 0.1 deg/s mean check.
    if creep_dps < settings.static_bias_max_mean_dps:
        assert bench.creep_taken(calibration, rng, settings, creep_dps, 3, False, False) == 12


def test_quick_run_prints_its_tables(bench: ModuleType, capsys: pytest.CaptureFixture[str]) -> None:
    """``--quick`` runs the whole benchmark small and prints both tables."""
    assert bench.main(['--quick']) == 0
    out = capsys.readouterr().out
    assert '| parked bias (Bool + gyro stillness) |' in out and '| 0.5 | 0 of 20 |' in out
