"""The report's figures, before and after calibration, as PNG (matplotlib, Agg backend).

- ``error-vs-rate.png``: mean error of each steady segment (deg/h) against the table rate, one
  colour per temperature band, for the uncalibrated, ART and extended models;
- ``heading-360.png``: heading error after a full turn (deg) against the rate, one line per
  temperature band and turning direction;
- ``residual-<signal>.png``: for each traced effect, what the model without it leaves (deg/h),
  against the effect's signal, with the fitted term.

The three stages' panels share one y scale, symmetric-logarithmic (linear within a small
band around 0) so that the uncalibrated error and the calibrated one, a thousand times
smaller, show on it together; the rate axis is symmetric-logarithmic beyond 1 deg/s, where
the table's rates lie.
"""

from __future__ import annotations

import os
from dataclasses import replace
from collections.abc import Callable
from pathlib import Path

import matplotlib

matplotlib.use('Agg')
import matplotlib.pyplot as plt  # noqa: E402 (the backend must be chosen first)
from matplotlib.axes import Axes  # noqa: E402
import numpy as np  # noqa: E402
from numpy.typing import NDArray  # noqa: E402

from art_gyro_calibration.log import GyroLog  # noqa: E402
from art_gyro_calibration.analysis.loop import LoopResult  # noqa: E402
from art_gyro_calibration.analysis.metrics import heading_errors_360  # noqa: E402
from art_gyro_calibration.analysis.report import STAGES, stage_errors  # noqa: E402
from art_gyro_calibration.signals import LAGGED_SIGNAL, SIGNALS  # noqa: E402
from art_gyro_calibration.terms import Term  # noqa: E402
from art_gyro_calibration.units import DEG_PER_H_PER_DPS  # noqa: E402

BAND_C = 10.0
# Where the shared symmetric-log y scales turn linear: about the bias instability (deg/h) of the gyros calibrated,
# and a little less than the heading that 1 deg/h gives over a 6 min turn (deg); the rate axis within the table's
# slowest rate (deg/s).
ERROR_LINEAR_DPH = 1.0
HEADING_LINEAR_DEG = 0.01
RATE_LINEAR_DPS = 1.0
# A warm-up's residual is shown over this many time constants after power-on; the rest is summarised.
WARM_UP_SHOWN_TAUS = 5.0
TITLES = {'uncalibrated': 'uncalibrated (scale factor, static bias)', 'art': 'ART polynomial',
          'extended': 'ART + traced effects'}


def _bands(result: LoopResult) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Temperature band (centre, degC) of each steady segment, and the distinct bands."""
    band = np.round(result.segments.means(result.signals.temperature) / BAND_C) * BAND_C
    return band, np.unique(band)


def plot_all(log: GyroLog, result: LoopResult, bias_samples: int, out_dir: str | os.PathLike[str],
             prefix: str = '') -> list[Path]:
    """Write every figure into ``out_dir`` (names start with ``prefix``); returns their paths."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    errors = stage_errors(log, result, bias_samples)
    paths = [_error_vs_rate(errors, result, out / f'{prefix}error-vs-rate.png'),
             _heading_360(errors, result, out / f'{prefix}heading-360.png')]
    for i, effect in enumerate(result.effects):
        paths.append(_residual(result, i, out / f'{prefix}residual-{effect.signal}.png'))
    paths.append(_residual_vs_signals(result, out / f'{prefix}residual-vs-signals.png'))
    return paths


# The signals a person checks what the final model leaves against (and every extra column of the log).
LOOK_AT = ('temperature', 'temperature_rate', 'time', 'rate', 'rate_change', 'angle')


def _residual_vs_signals(result: LoopResult, path: Path) -> Path:
    """What the written model leaves against each signal, binned: where the lack-of-fit alarm sends a person.

    The heading is shown modulo 360 deg (a heading effect repeats every turn); a panel whose
    shape the form-free check found beyond chance and the materiality is titled in red.
    """
    rows = result.segments.rows()
    residual = (result.error - result.extended.model.error(result.signals))[rows] * DEG_PER_H_PER_DPS
    names = [*LOOK_AT, *result.signals.extras]
    found = {s.signal: s for s in (result.adequacy.signals if result.adequacy else ()) if s.found}
    fig, axes = plt.subplots(2, (len(names) + 1) // 2, figsize=(4 * ((len(names) + 1) // 2), 7), squeeze=False,
                             sharey=True)   # one residual: its size against each signal compared at a glance
    for ax, name in zip(axes.ravel(), names):
        x = result.signals.get(name)[rows]
        if name == 'angle':
            x = np.mod(x, 360.0)
            edges = np.linspace(0.0, 360.0, 41)
        else:
            # Bins of equal width, not of equal count: sorting by a noisy measured signal (the rate at
            # rest) would sort the residual's own noise into a slope.
            edges = np.linspace(x.min(), x.max(), 41)
        k = np.clip(np.searchsorted(edges, x, side='right') - 1, 0, 39)
        counts = np.bincount(k, minlength=40)
        sums = np.bincount(k, weights=residual - residual.mean(), minlength=40)
        full = counts >= 50
        centres = 0.5 * (edges[:-1] + edges[1:])
        ax.plot(centres[full], sums[full] / counts[full], 'o-', ms=3)
        ax.axhline(0.0, color='grey', lw=0.8)
        ax.set_xlabel(signal_label(name))
        ax.locator_params(axis='x', nbins=5)   # a rate's ticks (-0.015, ...) would run into each other
        if name in found:
            ax.set_title(f'shape beyond chance: {found[name].shape_dph:.1f} deg/h', color='red', fontsize=10)
        ax.grid(True, alpha=0.3)
    for ax in axes.ravel()[len(names):]:
        ax.set_visible(False)
    for ax in axes[:, 0]:
        ax.set_ylabel('residual, binned (deg/h)')
    adequacy = result.adequacy
    verdict = '' if adequacy is None else (' (adequate)' if adequacy.model_adequate else ' (DOES NOT FIT)')
    fig.suptitle(f'what the written model leaves, against each signal{verdict}')
    fig.tight_layout()
    fig.savefig(path, dpi=80)
    plt.close(fig)
    return path


def _per_stage(path: Path, ylabel: str, linear_within: float, draw: Callable[[Axes, str], None],
               title: str) -> Path:
    """One panel per stage (uncalibrated, ART, extended) on a shared y scale, each drawn by ``draw(ax, stage)``."""
    fig, axes = plt.subplots(1, len(STAGES), figsize=(15, 5), sharey=True)
    for ax, stage in zip(axes, STAGES):
        draw(ax, stage)
        ax.set_title(TITLES[stage])
        ax.set_xscale('symlog', linthresh=RATE_LINEAR_DPS)
        ax.set_yscale('symlog', linthresh=linear_within)
        ax.set_xlabel(f'table rate (deg/s, logarithmic beyond {RATE_LINEAR_DPS:g})')
        ax.axhline(0.0, color='grey', lw=0.8)
        ax.grid(True, which='major', alpha=0.3)
        ax.legend(title='temperature', fontsize=9, title_fontsize=9)
    axes[0].set_ylabel(ylabel)
    unit = ylabel.rsplit('(', 1)[-1].rstrip(')')
    fig.suptitle(f'{title}\none y scale for the three panels: linear within +-{linear_within:g} {unit}, '
                 'logarithmic beyond', fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)
    return path


def _error_vs_rate(errors: dict[str, NDArray[np.float64]], result: LoopResult, path: Path) -> Path:
    band, bands = _bands(result)
    colours = plt.cm.coolwarm(np.linspace(0, 1, len(bands)))

    def draw(ax: Axes, stage: str) -> None:
        means = result.segments.means(errors[stage]) * DEG_PER_H_PER_DPS
        for b, colour in zip(bands, colours):
            sel = band == b
            ax.plot(result.segments.rate[sel], means[sel], 'o', ms=3, color=colour, label=f'{b:.0f} degC')

    return _per_stage(path, 'mean rate error of a steady segment (deg/h)', ERROR_LINEAR_DPH, draw,
                      'mean rate error of each steady segment of the table')


def _heading_360(errors: dict[str, NDArray[np.float64]], result: LoopResult, path: Path) -> Path:
    """Heading error after a full turn: the rate error times the turn's 360/|rate| s, so a bias weighs as 1/rate."""
    band, bands = _bands(result)
    turning = result.segments.rate != 0.0
    colours = plt.cm.coolwarm(np.linspace(0, 1, len(bands)))

    def draw(ax: Axes, stage: str) -> None:
        rate, heading = heading_errors_360(errors[stage], result.segments)
        for b, colour in zip(bands, colours):
            sel = band[turning] == b
            if not sel.any():
                continue
            # One line per band and direction (a line through 0 deg/s would join two different turns): the mean
            # over the segments at each rate.
            rates = np.unique(rate[sel])
            mean = np.array([heading[sel][rate[sel] == r].mean() for r in rates])
            gap = np.flatnonzero(np.diff(np.sign(rates)) != 0) + 1
            ax.plot(np.insert(rates, gap, np.nan), np.insert(mean, gap, np.nan), '.-', color=colour,
                    label=f'{b:.0f} degC')

    slowest = float(np.min(np.abs(result.segments.rate[turning]))) if turning.any() else RATE_LINEAR_DPS
    return _per_stage(path, 'heading error after a full turn (deg)', HEADING_LINEAR_DEG, draw,
                      'heading error after a full turn = the rate error integrated over the turn, '
                      f'which lasts 360/|rate| s ({360 / slowest:.0f} s at {slowest:g} deg/s, '
                      f'{360 / 100:.1f} s at 100 deg/s): near 0 deg/s a bias weighs most')


def signal_label(name: str) -> str:
    """An axis label for signal ``name``: what it is and its unit (an extra log column: its name, in its own units)."""
    if name == 'angle':
        return 'heading modulo 360 (deg)'
    if name not in SIGNALS:
        return f'{name} (log column, in its own units)'
    return f'{name.replace("_", " ")} ({SIGNALS[name].unit or "-1, 0 or 1"})'


def plain_term(term: Term) -> str:
    """A legend for a fitted term in words, not in coefficients (those are in REPORT.md)."""
    if term.form == 'exp_decay':
        return f'fitted warm-up: decays after power-on with a {term.time_constant_s:.0f} s time constant'
    if term.form == 'harmonic':
        return 'fitted once-per-turn effect of the heading'
    of = f'the temperature lagged by {term.time_constant_s:.0f} s' if term.signal == LAGGED_SIGNAL else term.signal
    degree = max(term.powers)
    shape = 'proportional to' if degree == 1 else f'a degree-{degree} polynomial in'
    return f'fitted effect: {shape} {of}' + ('' if term.rate_powers == (0,) else ', times powers of the rate')


def _residual(result: LoopResult, i: int, path: Path) -> Path:
    """What the extended model less term ``i`` leaves, against the term's signal, binned."""
    model = result.extended.model
    effect = result.effects[i]
    without = replace(model, terms=model.terms[:i] + model.terms[i + 1:])
    rows = result.segments.rows()
    x = result.signals.for_term(effect.term)[rows]
    partial = (result.error - without.error(result.signals))[rows]
    # The term on the same samples (a term with rate powers is no curve of its signal alone).
    term = model.term_error(effect.term, result.signals)[rows]
    # A warm-up is shown where it is: its first time constants, binned there; the rest is summarised.
    shown = x <= WARM_UP_SHOWN_TAUS * effect.term.time_constant_s if effect.term.form == 'exp_decay' else \
        np.ones(len(x), dtype=bool)
    if not shown.any() or shown.all():
        shown = np.ones(len(x), dtype=bool)
    order = np.flatnonzero(shown)[np.argsort(x[shown], kind='stable')]
    chunks = np.array_split(order, min(60, len(order)))
    bx = np.array([x[c].mean() for c in chunks])
    by = np.array([partial[c].mean() for c in chunks])
    bt = np.array([term[c].mean() for c in chunks])
    offset = float(np.mean(partial[shown]) - np.mean(term[shown]))   # the term drawn through the residual's mean
    fig, ax = plt.subplots(figsize=(7, 4.5))
    ax.plot(bx, by * DEG_PER_H_PER_DPS, 'o', ms=4, label='what the model leaves without this effect (binned means)')
    ax.plot(bx, (bt + offset) * DEG_PER_H_PER_DPS, '-', label=plain_term(effect.term))
    if not shown.all():
        rest = ~shown
        ax.set_xlim(0.0, WARM_UP_SHOWN_TAUS * effect.term.time_constant_s)
        ax.text(0.98, 0.5, f'after {WARM_UP_SHOWN_TAUS:g} time constants (to {x[rest].max():.0f} s, '
                f'{100 * rest.mean():.0f} % of the samples):\nleft {np.mean(partial[rest]) * DEG_PER_H_PER_DPS:.2f} '
                f'deg/h on average, the term {(np.mean(term[rest]) + offset) * DEG_PER_H_PER_DPS:.2f} deg/h',
                transform=ax.transAxes, ha='right', va='center', fontsize=8,
                bbox={'facecolor': 'white', 'edgecolor': 'grey', 'alpha': 0.9})
    ax.set_xlabel(signal_label(effect.signal))
    ax.set_ylabel('rate error left (deg/h)')
    ax.set_title(f'effect found: {effect.signal}')
    ax.grid(True, alpha=0.3)
    ax.legend(fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)
    return path
