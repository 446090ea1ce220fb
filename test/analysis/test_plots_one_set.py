"""The figures read as one set: rate errors in deg/h, compared panels on one y scale, axes where the effect is."""

from __future__ import annotations

from pathlib import Path

import matplotlib.pyplot as plt
import numpy as np
import pytest
from matplotlib.figure import Figure

from art_gyro_calibration.analysis.cli import main
from art_gyro_calibration.analysis.loop import LoopOptions
from art_gyro_calibration.analysis.pipeline import FitResult, FitSettings, fit_log
from art_gyro_calibration.analysis.plots import WARM_UP_SHOWN_TAUS, plot_all
from art_gyro_calibration.analysis.simulate import SimulationSettings, simulate_run, write_run
from art_gyro_calibration.calibration import load_packaged_calibration
from art_gyro_calibration.static_bias import StaticBias


@pytest.fixture(scope='module')
def warm_fit(tmp_path_factory: pytest.TempPathFactory) -> FitResult:
    """A 6 h cold start of NAVC4058 with a warm-up and a Shupe effect (2 Hz), fitted 3 x 2."""
    directory = tmp_path_factory.mktemp('figures')
    cal = load_packaged_calibration('NAVC4058')
    log = directory / 'LOG.csv'
    write_run(log, simulate_run(cal, SimulationSettings(hours=6.0, rate_hz=2.0, seed=1, effects=('warmup', 'shupe'))))
    options = LoopOptions(serial_number='NAVC4058', rate_scale_factor=cal.rate_scale_factor,
                          temp_scale_factor=cal.temp_scale_factor)
    return fit_log(str(log), FitSettings(3, 2, options), str(directory / 'CAL.yaml'), lambda warning: None)


@pytest.fixture(scope='module')
def figures(warm_fit: FitResult, tmp_path_factory: pytest.TempPathFactory) -> dict[str, Figure]:
    """Each figure of ``calibrate fit --plots`` by file name, kept open to read back."""
    kept: list[Figure] = []
    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(plt, 'close', kept.append)
        paths = plot_all(warm_fit.log, warm_fit.loop, 100, tmp_path_factory.mktemp('plots'))
    yield {p.name: f for p, f in zip(paths, kept)}
    for figure in kept:
        plt.close(figure)


def _panels(figure: Figure) -> list:
    return [ax for ax in figure.axes if ax.get_visible()]


def test_the_warm_up_is_found_and_drawn(figures: dict[str, Figure]) -> None:
    assert 'residual-time_since_power_on.png' in figures, sorted(figures)


def test_rate_errors_are_in_deg_per_hour_and_headings_in_deg(figures: dict[str, Figure]) -> None:
    for name, figure in figures.items():
        ylabels = {ax.get_ylabel() for ax in _panels(figure)} - {''}
        if name == 'heading-360.png':
            assert ylabels == {'heading error after a full turn (deg)'}
        else:
            assert ylabels and all(label.endswith('(deg/h)') for label in ylabels), (name, ylabels)


@pytest.mark.parametrize('name', ['error-vs-rate.png', 'heading-360.png', 'residual-vs-signals.png'])
def test_compared_panels_share_one_y_scale_holding_all_data(figures: dict[str, Figure], name: str) -> None:
    panels = _panels(figures[name])
    assert len(panels) >= 3
    limits = {ax.get_ylim() for ax in panels}
    assert len(limits) == 1, limits
    assert len({ax.get_yscale() for ax in panels}) == 1
    low, high = limits.pop()
    for ax in panels:
        for line in ax.get_lines():
            y = np.asarray(line.get_ydata(), dtype=float)
            y = y[np.isfinite(y)]
            assert np.all((y >= low) & (y <= high)), (name, ax.get_title())


@pytest.mark.parametrize('name', ['error-vs-rate.png', 'heading-360.png'])
def test_every_stage_panel_has_a_readable_legend(figures: dict[str, Figure], name: str) -> None:
    for ax in _panels(figures[name]):
        legend = ax.get_legend()
        assert legend is not None, ax.get_title()
        assert min(text.get_fontsize() for text in legend.get_texts()) >= 9


def test_heading_lines_never_join_the_two_directions_through_zero(figures: dict[str, Figure]) -> None:
    for ax in _panels(figures['heading-360.png']):
        for line in ax.get_lines():
            x = np.asarray(line.get_xdata(), dtype=float)
            if len(x) < 3:
                continue   # the zero line
            joined = np.isfinite(x[1:]) & np.isfinite(x[:-1]) & (np.sign(x[1:]) != np.sign(x[:-1]))
            assert not joined.any(), x


def test_the_warm_up_residual_spans_its_time_constants_and_summarises_the_rest(
        warm_fit: FitResult, figures: dict[str, Figure]) -> None:
    tau = next(e.term.time_constant_s for e in warm_fit.loop.effects if e.signal == 'time_since_power_on')
    ax, = _panels(figures['residual-time_since_power_on.png'])
    assert ax.get_xlim() == pytest.approx((0.0, WARM_UP_SHOWN_TAUS * tau))
    assert WARM_UP_SHOWN_TAUS * tau < 0.5 * np.ptp(warm_fit.log.t)   # the log goes well beyond it
    points = np.asarray(ax.get_lines()[0].get_xdata(), dtype=float)
    assert len(points) >= 30 and points.max() <= WARM_UP_SHOWN_TAUS * tau
    assert any(f'after {WARM_UP_SHOWN_TAUS:g} time constants' in t.get_text() for t in ax.texts)


def test_the_allan_bias_window_label_is_off_the_curve(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    rng = np.random.default_rng(1)
    fs, n = 10.0, 1 << 17
    rate = 0.002 + rng.normal(0.0, 0.1 / 60.0 * np.sqrt(fs), n) + np.cumsum(rng.normal(0.0, 2e-7, n))
    still = tmp_path / 'still.csv'
    np.savetxt(still, np.c_[np.arange(n) / fs, rate, np.full(n, 25.0)], delimiter=',', header='t,rate_dps,temp_c',
               comments='', fmt='%.9f')
    kept: list[Figure] = []
    monkeypatch.setattr(plt, 'close', kept.append)
    assert main(['allan', str(still), '--out', str(tmp_path / 'A.json'), '--plots', str(tmp_path / 'p')]) == 0
    monkeypatch.undo()
    figure, = kept
    ax = figure.axes[0]
    label, = [t for t in ax.texts if t.get_text().startswith('bias window')]
    renderer = figure.canvas.get_renderer()
    box = label.get_window_extent(renderer)
    for line in ax.get_lines():
        xy = ax.transData.transform(np.c_[line.get_xdata(), line.get_ydata()])
        xy = xy[np.all(np.isfinite(xy), axis=1)]
        inside = (xy[:, 0] >= box.x0) & (xy[:, 0] <= box.x1) & (xy[:, 1] >= box.y0) & (xy[:, 1] <= box.y1)
        assert not inside.any(), line.get_label()
    plt.close(figure)


def test_a_refinement_below_the_printed_precision_is_said_in_deg_per_hour() -> None:
    text = StaticBias(0.01, 0.0, 100, 0.001, refined_dps=-4.0e-7).describe()
    assert 'refined by -0.00144 deg/h' in text and '0.000000 deg/s,' not in text.split('refined')[1]
    assert 'refined' not in StaticBias(0.01, 0.0, 100, 0.001).describe()
