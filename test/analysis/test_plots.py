"""``analysis.plots``: the figures ``calibrate fit --plots`` promises, each axis labelled with its unit."""

from __future__ import annotations

import re
from pathlib import Path

import matplotlib.pyplot as plt
import pytest
from matplotlib.figure import Figure

from test_pipeline import fit_simulated

from art_gyro_calibration.analysis.plots import plain_term, plot_all, signal_label
from art_gyro_calibration.terms import Term

PNG = b'\x89PNG\r\n\x1a\n'
UNIT = re.compile(r'\([^()]+\)$')   # a label ends with its unit in parentheses


def test_plot_all_writes_each_promised_png_with_units_on_every_axis(tmp_path: Path,
                                                                    monkeypatch: pytest.MonkeyPatch) -> None:
    fitted = fit_simulated(tmp_path)
    figures: list[Figure] = []
    monkeypatch.setattr(plt, 'close', figures.append)   # keep each figure to read its labels
    paths = plot_all(fitted.log, fitted.loop, 50, tmp_path / 'plots', prefix='g1-')
    monkeypatch.undo()
    assert [p.name for p in paths] == ['g1-error-vs-rate.png', 'g1-heading-360.png',
                                       'g1-residual-temperature_rate.png', 'g1-residual-vs-signals.png']
    assert sorted(p.name for p in (tmp_path / 'plots').iterdir()) == sorted(p.name for p in paths)
    assert all(p.read_bytes()[:8] == PNG for p in paths)
    assert len(figures) == len(paths)
    for figure in figures:
        axes = [ax for ax in figure.axes if ax.get_visible()]
        labels = [label for ax in axes for label in (ax.get_xlabel(), ax.get_ylabel()) if label]
        assert any(ax.get_xlabel() for ax in axes) and any(ax.get_ylabel() for ax in axes)
        assert all(UNIT.search(label) for label in labels), labels
        plt.close(figure)


def test_signal_label_names_the_unit_or_says_there_is_none() -> None:
    assert signal_label('temperature_rate') == 'temperature rate (degC/s)'
    assert signal_label('rate') == 'rate (deg/s)'
    assert signal_label('rate_sign') == 'rate sign (-1, 0 or 1)'
    assert signal_label('angle') == 'heading modulo 360 (deg)'
    assert signal_label('supply_v') == 'supply_v (log column, in its own units)'


@pytest.mark.parametrize('term, words', [
    (Term('temperature_rate', 'power', (0.2,), (1,)), 'fitted effect: proportional to temperature_rate'),
    (Term('temperature', 'power', (0.1, 0.2), (1, 2)), 'fitted effect: a degree-2 polynomial in temperature'),
    (Term('temperature_lag', 'power', (0.1,), (1,), 600.0),
     'fitted effect: proportional to the temperature lagged by 600 s'),
    (Term('temperature', 'power', (0.1, 0.2), (1,), rate_powers=(0, 1)),
     'fitted effect: proportional to temperature, times powers of the rate'),
    (Term('time_since_power_on', 'exp_decay', (0.05,), (), 1800.0),
     'fitted warm-up: decays after power-on with a 1800 s time constant'),
    (Term('angle', 'harmonic', (0.01, 0.02)), 'fitted once-per-turn effect of the heading'),
])
def test_plain_term_says_the_term_in_words(term: Term, words: str) -> None:
    assert plain_term(term) == words
