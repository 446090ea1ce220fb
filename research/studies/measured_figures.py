"""Figures of the measured-data study (PNG, matplotlib)."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any, cast

import numpy as np
from numpy.typing import NDArray

from art_gyro_calibration.analysis.report import STAGES
from art_gyro_calibration.units import DEG_PER_H_PER_DPS, SECONDS_PER_HOUR

from importers import StaticRecord, runs
from measured_folds import STAGE_TITLES, Fold
from measured_injection import EFFECT_TITLES, Cell
from measured_phone import STREAMS, PhoneAxis
from measured_record import AXES, block_means, orientation_labels

STAGE_COLOURS = {'uncalibrated': 'tab:gray', 'art': 'tab:blue', 'extended': 'tab:red'}


def _pyplot() -> Any:
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt
    return plt


def _save(fig: Any, path: Path) -> Path:
    """Write a figure as PNG and free it."""
    fig.tight_layout()
    fig.savefig(path, dpi=80)
    _pyplot().close(fig)
    return path


def _save_allan(fig: Any, axes: Any, ylabel: str, path: Path) -> Path:
    """Label a row of Allan-deviation panels (legend in the first) and write the figure."""
    for ax in axes[0]:
        ax.set_xlabel('tau (s)')
        ax.grid(True, which='both', alpha=0.3)
    axes[0][0].set_ylabel(ylabel)
    axes[0][0].legend(fontsize=7)
    return _save(fig, path)


def plot_record(record: StaticRecord, still: NDArray[np.bool_], path: Path) -> Path:
    """The record: 10-minute means of the three gyro axes, temperature and gravity, still runs shaded."""
    plt = _pyplot()
    t0 = record.t[0]
    fig, axes = plt.subplots(3, 1, figsize=(11, 8), sharex=True)
    for a in AXES:
        tm, vm = block_means(record.t[still], record.channels[f'gyro_{a}'][still])
        axes[0].plot((tm - t0) / SECONDS_PER_HOUR, vm, '.', ms=2, label=f'gyro {a}')
    axes[0].set_ylabel('rate, 10-min means (deg/s)')
    axes[1].plot((record.t - t0) / SECONDS_PER_HOUR, record.temp_c, color='tab:orange')
    axes[1].set_ylabel('IMU temperature (degC)')
    for a in AXES:
        axes[2].plot((record.t - t0) / SECONDS_PER_HOUR, record.channels[f'acc_{a}'], lw=0.6, label=f'acc {a}')
    axes[2].set_ylim(-12, 12)
    axes[2].set_ylabel('acceleration (m/s^2)')
    axes[2].set_xlabel('hours since the record started')
    for start, stop in runs(still):
        for ax in axes:
            ax.axvspan((record.t[start] - t0) / SECONDS_PER_HOUR, (record.t[stop - 1] - t0) / SECONDS_PER_HOUR,
                       color='tab:green', alpha=0.07, lw=0)
    for ax in (axes[0], axes[2]):
        ax.legend(fontsize=8, ncol=3)
    for ax in axes:
        ax.grid(True, alpha=0.3)
    axes[0].set_title('CATS tag lying still (green: still runs used), three orientations in turn')
    return _save(fig, path)


def plot_temperature(folds: Sequence[Fold], path: Path) -> Path:
    """Rate against temperature (10-min means), one colour per day, with the ART polynomial of the training days."""
    plt = _pyplot()
    fig, axes = plt.subplots(1, len(folds), figsize=(5 * len(folds), 4.5), squeeze=False)
    for ax, fold in zip(axes[0], folds):
        log = fold.log
        labels, names = orientation_labels(log)
        for k, name in enumerate(names):
            rows = labels == k
            _, rate = block_means(log.t[rows], log.rate_dps[rows])
            _, temp = block_means(log.t[rows], log.temp_c[rows])
            held = ' (held out)' if np.all(fold.held[rows]) else ''
            ax.plot(temp, rate, '.', ms=3, label=f'day {k + 1}, {name}{held}')
        grid = np.linspace(log.temp_c.min(), log.temp_c.max(), 100)
        ax.plot(grid, fold.loop.art.polynomial.error(np.zeros_like(grid), grid), 'k-', lw=1,
                label='ART polynomial of the training days')
        ax.set_title(f'gyro {fold.axis}')
        ax.set_xlabel('temperature (degC)')
        ax.grid(True, alpha=0.3)
        ax.legend(fontsize=7)
    axes[0][0].set_ylabel('rate of the still gyro, 10-min means (deg/s)')
    return _save(fig, path)


def plot_fold(fold: Fold, path: Path) -> Path:
    """What ART leaves over the record with the effects kept, and every stage on the held-out day."""
    plt = _pyplot()
    log, t0 = fold.log, fold.log.t[0]
    assert log.ref_rate is not None   # a record's: the gyro lay still
    art_residual = log.rate_dps - log.ref_rate - fold.comp('art')
    fig, axes = plt.subplots(2, 1, figsize=(11, 7.5))
    for rows, label, colour in ((~fold.held, 'training days', 'tab:blue'),
                                (fold.held, f'held-out day ({fold.held_name})', 'tab:purple')):
        tm, vm = block_means(log.t[rows], art_residual[rows] - np.mean(art_residual[~fold.held]))
        axes[0].plot((tm - t0) / SECONDS_PER_HOUR, vm, '.', ms=3, color=colour, label=f'{label}: rate - ART polynomial')
    terms = fold.kept_effects
    if terms:
        # A sum of arrays (terms is not empty), never the start value 0.
        effect = cast(NDArray[np.float64], sum(term.evaluate(fold.signals.get(term.signal)) for term in terms))
        tm, vm = block_means(log.t, effect - np.mean(effect[~fold.held]))
        axes[0].plot((tm - t0) / SECONDS_PER_HOUR, vm, '-', color='tab:red', lw=1,
                     label='effects kept: ' + '; '.join(t.describe() for t in terms))
    axes[0].set_ylabel('10-min means (deg/s)')
    axes[0].set_title(f'gyro {fold.axis}: what the ART polynomial fitted on the training days leaves')
    twin = axes[0].twinx()
    twin.plot((log.t - t0) / SECONDS_PER_HOUR, log.temp_c, color='tab:orange', lw=0.6, alpha=0.6)
    twin.set_ylabel('temperature (degC)', color='tab:orange')
    axes[0].set_xlabel('hours since the record started')
    t_span = log.t[fold.span]
    for stage in STAGES:
        tm, vm = block_means(t_span, fold.errors[stage, 'bias_settled'])
        rms = fold.field[stage, 'bias_settled'].systematic_rms_dps
        axes[1].plot((tm - t0) / SECONDS_PER_HOUR, vm, '.-', ms=3, lw=0.8, color=STAGE_COLOURS[stage],
                     label=f'{STAGE_TITLES[stage]}: 10-min rms {rms:.4f} deg/s ({rms * DEG_PER_H_PER_DPS:.0f} deg/h)')
    for way, colour in (('bias_start', 'tab:gray'), ('bias_settled', 'tab:green')):
        window = log.t[fold.bias_windows[way]]
        axes[1].axvspan((window[0] - t0) / SECONDS_PER_HOUR, (window[-1] - t0) / SECONDS_PER_HOUR, color=colour,
                        alpha=0.3, lw=0)
    axes[1].set_ylabel('held-out error, 10-min means (deg/s)')
    axes[1].set_xlabel('hours since the record started (shaded: static bias at the start, grey; '
                       'after the transient, green)')
    axes[1].set_title(f'held-out day ({fold.held_name}): static bias after the handling transient, then each model')
    for ax in axes:
        ax.grid(True, alpha=0.3)
        ax.legend(fontsize=7, loc='best')
    return _save(fig, path)


def plot_allan(folds: Sequence[Fold], path: Path) -> Path:
    """Allan deviation of the held-out error of every stage, one panel per axis."""
    plt = _pyplot()
    fig, axes = plt.subplots(1, len(folds), figsize=(5 * len(folds), 4.5), sharey=True, squeeze=False)
    for ax, fold in zip(axes[0], folds):
        for stage in STAGES:
            a = fold.allan[stage]
            ax.loglog(a.tau_s, a.adev, 'o-', ms=3, color=STAGE_COLOURS[stage], label=STAGE_TITLES[stage])
        white = fold.allan['extended']
        ax.loglog(white.tau_s, white.adev[0] * np.sqrt(white.tau_s[0] / white.tau_s), ':', color='k',
                  label='white noise alone (tau^-1/2)')
        ax.axhline(fold.bias_instability_dps, color='tab:green', ls='--', lw=0.8,
                   label=f'training floor {fold.bias_instability_dps:.4f} deg/s')
        ax.set_title(f'gyro {fold.axis}, held-out day ({fold.held_name})')
    return _save_allan(fig, axes, 'Allan deviation of the held-out error (deg/s)', path)


def plot_injection(cells: Sequence[Cell], path: Path) -> Path:
    """Per injected effect: detection rate and the held-out 10-min rms with and without the traced terms."""
    plt = _pyplot()
    effects = list(dict.fromkeys(c.effect for c in cells))
    fig, axes = plt.subplots(2, len(effects), figsize=(3.6 * len(effects), 6.5), squeeze=False, sharex=True)
    for j, effect in enumerate(effects):
        mine = [c for c in cells if c.effect == effect]
        x = np.array([c.factor for c in mine])
        axes[0][j].plot(x, [c.detected / len(c.trials) for c in mine], 'o-', color='tab:red', label='signal named')
        axes[0][j].plot(x, [c.new_claims() / len(c.trials) for c in mine], 's--', color='tab:gray',
                        label='another signal claimed')
        axes[0][j].set_ylim(-0.05, 1.05)
        axes[0][j].set_title(EFFECT_TITLES[effect], fontsize=9)
        for stage, way, style in (('art', 'bias_settled', 'o-'), ('extended', 'bias_settled', 'o-'),
                                  ('art', 'predicted', 'x:'), ('extended', 'predicted', 'x:')):
            med = [np.median(c.held_out(stage, way)) for c in mine]
            how = 'bias after transient' if way == 'bias_settled' else 'as predicted'
            axes[1][j].plot(x, med, style, color=STAGE_COLOURS[stage],
                            label=f'{STAGE_TITLES[stage].split(" (")[0]}, {how}')
        axes[1][j].set_xlabel('injected rms / bias instability')
        for ax in (axes[0][j], axes[1][j]):
            ax.set_xscale('log')
            ax.grid(True, which='both', alpha=0.3)
    axes[0][0].set_ylabel('fraction of trials')
    axes[1][0].set_ylabel('held-out 10-min rms, median (deg/h)')
    axes[0][0].legend(fontsize=7)
    axes[1][0].legend(fontsize=6)
    return _save(fig, path)


def plot_phone(phone: Sequence[PhoneAxis], cats: dict[str, dict[str, Any]], path: Path) -> Path:
    """Allan deviation of the phone's two gyro streams beside the CATS gyro's (raw and after ART), per axis."""
    plt = _pyplot()
    fig, axes = plt.subplots(1, len(phone), figsize=(5 * len(phone), 4.5), sharey=True, squeeze=False)
    for ax, p in zip(axes[0], phone):
        for stream, style in zip(STREAMS, ('o-', 'x:')):
            a = p.allan[stream]
            ax.loglog(a.tau_s, a.adev, style, ms=3, color='tab:purple', label=f'phone, {stream} stream (10 Hz)')
        for key, colour in (('raw', 'tab:gray'), ('art', 'tab:blue')):
            a = cats[p.axis][key]
            ax.loglog(a.tau_s, a.adev, 'o-', ms=3, color=colour,
                      label=f'CATS tag, {"raw" if key == "raw" else "after the ART polynomial"} (1 Hz)')
        ax.set_title(f'gyro {p.axis}')
    return _save_allan(fig, axes, 'Allan deviation (deg/s)', path)
