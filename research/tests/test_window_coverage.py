"""The window-coverage study reads a field check's output and sets each written coefficient's error against its bias."""

import json
from pathlib import Path

import pytest
import window_coverage as wc
import yaml


def _fit(run: Path, label: str, written: dict[str, object], description: str) -> None:
    run.mkdir(parents=True, exist_ok=True)
    params = {'serial_number': 'NAVC3545', 'extended': {'signals': ['temperature_rate'], 'temperature_rate': written}}
    (run / f'{label}.yaml').write_text(yaml.safe_dump({'/**': {'ros__parameters': params}}))
    term = {'signal': 'temperature_rate', 'description': description, 'window_dph': 60.0,
            'implied_bias_dph': 3.0, 'written': True}
    (run / f'{label}-REPORT.json').write_text(json.dumps({'window_terms': {'terms': [term]}}))


def test_the_error_is_the_window_s_rate_times_the_coefficient_s_error(tmp_path: Path) -> None:
    """60 deg/h in the window at a fitted 2.0: 30 deg/h per unit; written 2.2 for 2.4 is -6 deg/h, z = 2."""
    results = [{'case': 'shupe', 'rep': 0, 'physics': {'shupe_k': 2.4, 'warmup_dph': 0.0}},
               {'case': 'null', 'rep': 0, 'physics': {'shupe_k': 0.0}}]
    (tmp_path / 'results.json').write_text(json.dumps({'meta': {'commit': 'abc'}, 'results': results}))
    _fit(tmp_path / 'shupe-0', 'loop_6h', {'form': 'power', 'powers': [1], 'coefficients': [2.2]},
         'power [1] of temperature_rate: [2]')
    _fit(tmp_path / 'shupe-0', 'loop_multi', {'form': 'power', 'powers': [1, 2], 'coefficients': [2.2, 40.0]},
         'power [1, 2] of temperature_rate: [2.2, 40]')
    found, skipped = wc.rows(tmp_path)
    [row] = found
    assert row['fit'] == 'loop_6h' and row['error_dph'] == pytest.approx(-6.0)
    assert row['window_dph'] == pytest.approx(66.0)
    assert skipped == ['shupe run 0, the lab protocol (several runs): no linear temperature-rate term written alone']
    text = wc.document(found, skipped, tmp_path, 'abc')
    assert '| one 6 h run | 1 | 0 % (0) | 2.00 | 2.00 |' in text
