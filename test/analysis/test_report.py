"""``analysis.report``: REPORT.json and the REPORT.md a person reads, from a small fitted log."""

from __future__ import annotations

import copy
import json
from pathlib import Path
from typing import Any

import pytest

from test_pipeline import fit_simulated

from art_gyro_calibration.analysis.pipeline import FitResult
from art_gyro_calibration.analysis.report import (STAGES, baseline_markdown, detection_markdown, markdown_summary,
                                                  write_report)


@pytest.fixture(scope='module')
def fitted(tmp_path_factory: pytest.TempPathFactory) -> FitResult:
    return fit_simulated(tmp_path_factory.mktemp('report'))


@pytest.fixture
def report(fitted: FitResult) -> dict[str, Any]:
    return copy.deepcopy(fitted.report)


def test_the_summary_has_the_gyro_a_row_per_stage_the_effect_and_what_is_written(report) -> None:
    summary = markdown_summary(report)
    lines = summary.splitlines()
    assert lines[0] == '# Calibration of NAVC4058'
    for stage in STAGES:
        row = next(line for line in lines if line.startswith(f'| {stage} |'))
        assert f'{report["errors"][stage]["rms_dps"]:.5f}' in row
    assert any(line.startswith('- **temperature_rate**: ') for line in lines)
    written = report['written']['calibration']
    assert f'Written: {written}, the baseline\'s polynomial with temperature_rate beyond it.' in lines
    assert '## Against the calibration the gyro has (baseline)' in lines
    assert '**Verdict: the baseline polynomial is kept.**' in summary
    assert 'Warning' not in summary and '**not written**' not in summary


def test_a_model_that_does_not_fit_and_a_finding_not_written_are_said(report) -> None:
    report['adequacy']['model_adequate'] = False
    report['findings_not_written'] = [{'signal': 'supply_v', 'description': 'c * supply_v', 'effect_dph': 3.5,
                                       'reason': 'the node has no supply_v at run time'}]
    summary = markdown_summary(report)
    assert '**Warning: the model does not fit:** ' in summary
    assert '- found, **not written**: c * supply_v (3.50 deg/h): the node has no supply_v at run time' in summary


def test_no_effect_and_node_parameters_needed(report) -> None:
    report['effects'] = []
    report['written']['node_parameters'] = {'extra_signals.supply_v.topic': 'the topic of the supply voltage'}
    summary = markdown_summary(report)
    assert 'Effects beyond the ART polynomial: nothing found.' in summary
    assert 'gyro_node refuses this calibration unless these parameters are set:' in summary
    assert '- `extra_signals.supply_v.topic`: the topic of the supply voltage' in summary


def test_detection_lists_only_the_forms_whose_limit_is_above_the_materiality() -> None:
    def limit(value: float | None) -> dict[str, Any]:
        return {'limit_dph': value, 'shape': '', 'exponent': None, 'hours_to_materiality': None, 'note': ''}

    report = {'materiality_dph': 1.0, 'detection_limit_dph': {'time': limit(0.5), 'rate': limit(4.0),
                                                              'angle': limit(None)}}
    lines = detection_markdown(report)
    assert '1 of 3 are below the materiality (1.00 deg/h).' in lines[1]
    assert lines[-2:] == ['- **rate**: 4.00 deg/h', '- **angle**: no finite limit']
    assert detection_markdown({'materiality_dph': 1.0}) == []


def test_baseline_markdown_without_a_baseline_and_when_the_baseline_is_kept(report) -> None:
    assert baseline_markdown({'source': None, 'verdict': 'none', 'message': 'no baseline: none given'})[-1] == \
        'No baseline: none given.'
    kept = dict(report['baseline'], verdict='baseline', message='the refit was not better held out')
    lines = baseline_markdown(kept)
    assert '**Verdict: the baseline polynomial is kept.** The refit was not better held out.' in lines
    assert f'Baseline {kept["source"]}.' in lines[3]


def test_write_report_writes_the_json_and_the_summary_beside_it(tmp_path: Path, report) -> None:
    summary = write_report(tmp_path / 'REPORT.json', report)
    assert summary == tmp_path / 'REPORT.md'
    assert json.loads((tmp_path / 'REPORT.json').read_text()) == report
    assert summary.read_text() == markdown_summary(report)
