"""Does the calibration loop hold on the robot? Null runs and a power table over the project's simulator.

``nice -n 10 .venv/bin/python studies/loop_validation.py`` (about 45 minutes of CPU, 25 of wall
time on two cores; ``--quick`` for a two-minute smoke run) fits :func:`analysis.loop.close_loop` to one
simulated run of a gyro and validates on two other runs of the same gyro, as the node would
use the calibration (:func:`analysis.replay.replay`): one started cold, one a warm restart
three hours after power-on at another heading. Every run has a slow bias wander
(Gauss-Markov, 1 h) and a rate random walk. It writes ``doc/loop-validation.md``, its
figures ``doc/figures/loop-*.png`` and the raw results (``build/loop-validation.json``).

Three calibrations are replayed: the report's (ART polynomial alone), the loop's extended
one, and a fit that knows the true form (:func:`analysis.fit.fit_model` with the true term,
its time constant included; for the effects no term can express, the true signal as an
extra log column, or for the lagging coil the true lagged temperature).
"""

from __future__ import annotations

import os

# One BLAS thread per worker: the workers are the parallelism, and the machine is shared.
os.environ.setdefault('OPENBLAS_NUM_THREADS', '1')
os.environ.setdefault('OMP_NUM_THREADS', '1')

import argparse  # noqa: E402
import json  # noqa: E402
import multiprocessing  # noqa: E402
import subprocess  # noqa: E402
import time  # noqa: E402
from collections import Counter  # noqa: E402
from dataclasses import dataclass, replace  # noqa: E402
from pathlib import Path  # noqa: E402
from typing import Any  # noqa: E402

import numpy as np  # noqa: E402
from numpy.typing import NDArray  # noqa: E402

from art_gyro_calibration.analysis.fit import TermSpec, fit_model  # noqa: E402
from art_gyro_calibration.analysis.loop import LoopOptions, close_loop  # noqa: E402
from art_gyro_calibration.analysis.replay import replay_field, startup_check  # noqa: E402
from art_gyro_calibration.analysis.simulate import (COIL_LAG_TAU_S, EFFECTS,  # noqa: E402
                                                    SimulatedRun, SimulationSettings, effect_size, lagged,
                                                    same_gyro, simulate_run, warm_restart)
from art_gyro_calibration.calibration import Calibration, load_packaged_calibration  # noqa: E402
from art_gyro_calibration.compensation import RunStart  # noqa: E402
from art_gyro_calibration.log import GyroLog  # noqa: E402
from art_gyro_calibration.signals import compute_signals  # noqa: E402
from art_gyro_calibration.static_bias import DEFAULT_SAMPLES  # noqa: E402
from art_gyro_calibration.units import DEG_PER_H_PER_DPS, SECONDS_PER_HOUR  # noqa: E402

REPO = Path(__file__).resolve().parent.parent
SERIAL = 'NAVC3545'
RATE_HZ = 10.0
# Slow noise of every run: a bias wander of 0.0003 deg/s (1.1 deg/h) over an hour, a rate random walk.
WANDER_DPS = 3e-4
WANDER_TAU_S = SECONDS_PER_HOUR
RATE_RANDOM_WALK_DPH_RTHR = 0.5
# The power table's effects: the simulator's first seven (shupe_true_rate is in the cold-start section).
ALL_EFFECTS = ('shupe', 'warmup', 'supply_voltage', 'coil_lag', 'rate_t3', 'rate_temperature_rate', 'drift')
MAGNITUDES = (0.1, 0.25, 0.5, 1.0)
HOURS = (2.0, 6.0)
VALIDATION_HOURS = 2.0
WARM_START_S = 3 * SECONDS_PER_HOUR
WARM_HEADING_DEG = 137.0
SCENARIOS = ('cold', 'warm')
CALIBRATIONS = ('art', 'extended', 'oracle')
# Targets of issue 8.
MAX_FALSE_ALARM_RATE = 0.05
MAX_WORSENING_DPH = 1.0
MIN_TARGET_MAGNITUDE = 0.25
MAX_ORACLE_RATIO = 1.5
MIN_DETECTION_RATE = 0.9
# The effects a term of the first loop can express must be found by their own signal.
# How the node is told each second run started: the cold one at power-on; the warm one left at
# the node's default (unknown: a warm-up term counts as decayed).
STARTS = {'cold': RunStart(powered_on_at_start=True), 'warm': RunStart()}
START_NOTE = ('; told `powered_on_at_start` on the cold run and left at the default (unknown: a warm-up term '
              'counts as decayed) on the warm one')
FOUND_BY_SIGNAL = {'shupe': 'temperature_rate', 'warmup': 'time_since_power_on', 'supply_voltage': 'supply_v',
                   'drift': 'time'}


@dataclass(frozen=True)
class Case:
    """One study run: an effect (or none) at a magnitude, a fit log length, a repetition."""

    effect: str | None
    magnitude: float
    hours: float
    seed: int

    def settings(self) -> SimulationSettings:
        """Simulator settings of the fitted run."""
        effects = (self.effect,) if self.effect else ()
        base = SimulationSettings(hours=self.hours, rate_hz=RATE_HZ, seed=self.seed, wander_dps=WANDER_DPS,
                                  wander_tau_s=WANDER_TAU_S, rate_random_walk_dph_rthr=RATE_RANDOM_WALK_DPH_RTHR,
                                  effects=effects)
        if self.effect:
            base = replace(base, effect_sizes={self.effect: self.magnitude * effect_size(self.effect, base)})
        return base


def oracle_log(log: GyroLog, case: Case, calibration: Calibration) -> tuple[GyroLog, list[TermSpec]]:
    """The log as a fit that knows the true form sees it, and the true terms' shapes.

    Signals are computed from the log itself, causally from its first sample, as a node could.
    """
    effect = case.effect
    if effect is None:
        return log, []
    if effect in EFFECTS:
        signal, form, _, tau, _ = EFFECTS[effect]
        return log, [TermSpec(signal, form, (1,) if form == 'power' else (), tau)]
    signals = compute_signals(log.t, log.rate_dps, log.temp_c)
    if effect == 'drift':
        return log, [TermSpec('time', 'power', (1,))]
    if effect == 'coil_lag':
        size = effect_size(effect, case.settings())
        temp = log.temp_c + size * (lagged(log.t, log.temp_c, COIL_LAG_TAU_S) - log.temp_c)
        return GyroLog(log.t, log.rate_dps, temp, log.ref_rate, log.extras), []
    low, high = calibration.expected_range_c
    if effect == 'rate_t3':
        u = (log.temp_c - 0.5 * (low + high)) / (0.5 * (high - low))
        column = log.rate_dps * u ** 3
    else:  # rate_temperature_rate
        column = log.rate_dps * signals.temperature_rate
    name = f'true_{effect}'
    return GyroLog(log.t, log.rate_dps, log.temp_c, log.ref_rate, {**log.extras, name: column}), \
        [TermSpec(name, 'power', (1,))]


def oracle_fit(log: GyroLog, case: Case, art: Calibration, index: NDArray[np.int64]) -> Calibration:
    """The fit that knows the true form, on the fitted log's steady rows."""
    seen, specs = oracle_log(log, case, art)
    signals = compute_signals(seen.t, seen.rate_dps, seen.temp_c, seen.extras, art.filters)
    fit = fit_model(signals, seen.rate_dps - seen.ref_rate, art.polynomial.rows, art.polynomial.columns, specs, index)
    return replace(art, polynomial=fit.model.polynomial, terms=fit.model.terms)


def validation_runs(calibration: Calibration, case: Case) -> dict[str, SimulatedRun]:
    """A cold run and a warm restart at another heading of the same gyro, each VALIDATION_HOURS long."""
    settings = replace(case.settings(), hours=VALIDATION_HOURS)
    return {'cold': simulate_run(calibration, same_gyro(settings, case.seed + 1_000_000)),
            'warm': warm_restart(calibration, same_gyro(settings, case.seed + 2_000_000), WARM_START_S,
                                 WARM_HEADING_DEG)}


def run_case(case: Case) -> dict[str, Any]:
    """Fit, validate, measure; the result as plain data (with the CPU seconds it took)."""
    start = time.process_time()
    truth = load_packaged_calibration(SERIAL)
    rows, columns = truth.polynomial.rows, truth.polynomial.columns
    log = simulate_run(truth, case.settings()).log(truth)
    loop = close_loop(log, rows, columns,
                      LoopOptions(serial_number=SERIAL, rate_scale_factor=truth.rate_scale_factor, seed=case.seed))
    # As ``calibrate fit`` does: the loop, then its start-up check on restarts of the fitted log.
    result, check, _ = startup_check(loop, log)
    calibrations = {'art': result.art, 'extended': result.extended,
                    'oracle': oracle_fit(log, case, result.art, result.segments.rows())}
    field: dict[str, dict[str, Any]] = {}
    for scenario, run in validation_runs(truth, case).items():
        other = run.log(truth)
        field[scenario] = {}
        for name, calibration in calibrations.items():
            seen = oracle_log(other, case, calibration)[0] if name == 'oracle' else other
            field[scenario][name] = replay_field(seen, calibration, DEFAULT_SAMPLES, start=STARTS[scenario]).to_dict()
    adequacy = getattr(result, 'adequacy', None)
    return {
        'effect': case.effect, 'magnitude': case.magnitude, 'hours': case.hours, 'seed': case.seed,
        # Found: written, or reported and not written (a supply voltage the node does not have, a heading).
        'found': [e.term.signal for e in (*result.effects, *result.findings)],
        'found_by_loop': [e.term.signal for e in loop.effects],
        'dropped_by_check': [] if check is None else [d.term.signal for d in check.dropped],
        'descriptions': [e.term.describe() for e in result.effects],
        'model_adequate': None if adequacy is None else bool(adequacy.model_adequate),
        'field': field,
        'cpu_s': time.process_time() - start,
    }


def run_all(cases: list[Case], jobs: int) -> list[dict[str, Any]]:
    """Every case, on ``jobs`` worker processes."""
    if jobs <= 1:
        return [run_case(c) for c in cases]
    with multiprocessing.get_context('fork').Pool(jobs) as pool:
        return pool.map(run_case, cases, chunksize=1)


# ---- summaries -------------------------------------------------------------------------------------------


def detected(r: dict[str, Any]) -> bool:
    """The loop reported the run's effect: its own signal for a term the first loop can express, else any
    term or the lack-of-fit alarm."""
    if r['effect'] in FOUND_BY_SIGNAL:
        return FOUND_BY_SIGNAL[r['effect']] in r['found']
    return bool(r['found']) or r['model_adequate'] is False


def field_dph(r: dict[str, Any], calibration: str, key: str = 'systematic_rms_dph') -> float:
    """A field measure over the cold and warm runs: rms of the two."""
    values = [r['field'][s][calibration][key] for s in SCENARIOS]
    values = [v for v in values if v is not None]
    return float(np.sqrt(np.mean(np.square(values)))) if values else float('nan')


def worsening_dph(r: dict[str, Any]) -> float:
    """How much the extended calibration worsens the worse of the two runs against ART (deg/h, > 0 worse)."""
    return max(r['field'][s]['extended']['systematic_rms_dph'] - r['field'][s]['art']['systematic_rms_dph']
               for s in SCENARIOS)


def summarise(results: list[dict[str, Any]]) -> dict[str, Any]:
    """Tables and targets from the raw results."""
    nulls = [r for r in results if r['effect'] is None]
    alarms = [r for r in nulls if r['found']]
    lack_of_fit = [r for r in nulls if r['model_adequate'] is False]
    worse = [r for r in alarms if worsening_dph(r) > MAX_WORSENING_DPH]
    null_rows = []
    for hours in HOURS:
        group = [r for r in nulls if r['hours'] == hours]
        if group:
            null_rows.append(_null_row(f'{hours:g} h', group))
    if nulls:
        null_rows.append(_null_row('all', nulls))
    cells = []
    for effect in ALL_EFFECTS:
        for magnitude in MAGNITUDES:
            for hours in HOURS:
                group = [r for r in results if r['effect'] == effect and r['magnitude'] == magnitude
                         and r['hours'] == hours]
                if group:
                    cells.append(_cell(effect, magnitude, hours, group))
    targeted = [c for c in cells if c['magnitude'] >= MIN_TARGET_MAGNITUDE]
    failing = [c for c in targeted if not at_target(c)]
    dropping = [r for r in results if r.get('dropped_by_check')]
    return {
        'startup_check': {
            'runs_with_drops': len(dropping), 'null_runs_with_drops': sum(r['effect'] is None for r in dropping),
            'dropped_signals': Counter(s for r in dropping for s in r['dropped_by_check']).most_common(),
            'effect_runs_with_drops': Counter(r['effect'] for r in dropping if r['effect']).most_common(),
            'own_signal_dropped': sum(FOUND_BY_SIGNAL.get(r['effect']) in r['dropped_by_check'] for r in dropping),
        },
        'null_runs': len(nulls), 'false_alarms': len(alarms), 'false_alarm_rate': len(alarms) / max(len(nulls), 1),
        'lack_of_fit_alarms': len(lack_of_fit), 'alarms_worsening': len(worse), 'null_rows': null_rows,
        'false_alarm_signals': Counter(s for r in alarms for s in r['found']).most_common(),
        'cells': cells, 'failing_cells': [(c['effect'], c['magnitude'], c['hours']) for c in failing],
        'targets': {
            'false_alarm_rate': len(alarms) / max(len(nulls), 1) <= MAX_FALSE_ALARM_RATE,
            'no_alarm_worsens': not worse,
            'power_and_field_error': bool(targeted) and not failing,
        },
    }


def at_target(cell: dict[str, Any]) -> bool:
    """A cell (:func:`_cell`) meets issue 8's power target: found often enough, field error near the oracle's."""
    return cell['detection'] >= MIN_DETECTION_RATE and cell['ratio_extended_oracle'] <= MAX_ORACLE_RATIO


def _null_row(label: str, group: list[dict[str, Any]]) -> dict[str, Any]:
    alarms = [r for r in group if r['found']]
    worsening = [worsening_dph(r) for r in group]
    return {'label': label, 'runs': len(group), 'false_alarms': len(alarms),
            'lack_of_fit': sum(r['model_adequate'] is False for r in group),
            'worsening_max_dph': float(np.max(worsening)),
            **{f'{c}_{s}_dph': float(np.median([r['field'][s][c]['systematic_rms_dph'] for r in group]))
               for c in ('art', 'extended') for s in SCENARIOS}}


def _cell(effect: str, magnitude: float, hours: float, group: list[dict[str, Any]]) -> dict[str, Any]:
    names = Counter(s for r in group for s in r['found']).most_common(2)
    cell: dict[str, Any] = {
        'effect': effect, 'magnitude': magnitude, 'hours': hours, 'runs': len(group),
        'detection': float(np.mean([detected(r) for r in group])),
        'alarm': float(np.mean([r['model_adequate'] is False for r in group])),
        'named': ', '.join(f'{n} ({k})' for n, k in names) or 'nothing',
    }
    for c in CALIBRATIONS:
        for s in SCENARIOS:
            cell[f'{c}_{s}_dph'] = float(np.median([r['field'][s][c]['systematic_rms_dph'] for r in group]))
            cell[f'{c}_{s}_heading_1h_deg'] = float(np.median([abs(r['field'][s][c]['heading_1h_deg'])
                                                               for r in group]))
    extended = np.median([field_dph(r, 'extended') for r in group])
    oracle = np.median([field_dph(r, 'oracle') for r in group])
    cell['ratio_extended_oracle'] = float(extended / oracle)
    return cell


# ---- document --------------------------------------------------------------------------------------------


def figures(summary: dict[str, Any], results: list[dict[str, Any]], out_dir: Path) -> list[str]:
    """Detection and field-error figures; returns the file names written."""
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt
    out_dir.mkdir(parents=True, exist_ok=True)
    names = []
    cells = summary['cells']
    fig, axes = plt.subplots(1, len(HOURS), figsize=(11, 4.2), sharey=True)
    for ax, hours in zip(axes, HOURS):
        for effect in ALL_EFFECTS:
            row = [c for c in cells if c['effect'] == effect and c['hours'] == hours]
            if row:
                ax.plot([c['magnitude'] for c in row], [100 * c['detection'] for c in row], 'o-', label=effect)
        ax.axhline(100 * MIN_DETECTION_RATE, color='grey', ls=':')
        ax.axvline(MIN_TARGET_MAGNITUDE, color='grey', ls=':')
        ax.set_xscale('log')
        ax.set_xticks(MAGNITUDES, [f'{m:g}' for m in MAGNITUDES])
        ax.set_xlabel('magnitude (fraction of the calibrate simulate size)')
        ax.set_title(f'fit log {hours:g} h')
    axes[0].set_ylabel('runs where the loop reported the effect (%)')
    axes[-1].legend(fontsize=7, loc='lower right')
    fig.tight_layout()
    names.append('loop-detection.png')
    fig.savefig(out_dir / names[-1], dpi=110)
    plt.close(fig)

    fig, axes = plt.subplots(1, len(SCENARIOS), figsize=(11, 4.2), sharey=True)
    for ax, scenario in zip(axes, SCENARIOS):
        full = [c for c in cells if c['magnitude'] == 1.0 and c['hours'] == max(HOURS)]
        x = np.arange(len(full))
        for k, (calibration, colour) in enumerate(zip(CALIBRATIONS, ('tab:red', 'tab:blue', 'tab:green'))):
            ax.bar(x + (k - 1) * 0.27, [c[f'{calibration}_{scenario}_dph'] for c in full], 0.27,
                   color=colour, label=calibration)
        ax.set_xticks(x, [c['effect'] for c in full], rotation=30, ha='right', fontsize=8)
        ax.set_yscale('log')
        ax.set_title(f'{scenario} second run, effect at magnitude 1, fit on {max(HOURS):g} h')
    axes[0].set_ylabel('systematic rms with the bias (deg/h), median')
    axes[0].legend(fontsize=8)
    fig.tight_layout()
    names.append('loop-field-errors.png')
    fig.savefig(out_dir / names[-1], dpi=110)
    plt.close(fig)

    nulls = [r for r in results if r['effect'] is None]
    if nulls:
        fig, axes = plt.subplots(1, 2, figsize=(11, 4))
        for scenario in SCENARIOS:
            axes[0].hist([r['field'][scenario]['art']['systematic_rms_dph'] for r in nulls], bins=30, alpha=0.6,
                         label=f'{scenario} second run')
        axes[0].set_xlabel('ART calibration: systematic rms with the bias (deg/h)')
        axes[0].set_ylabel('null runs')
        axes[0].set_title('what noise, wander and random walk leave')
        axes[0].legend(fontsize=8)
        alarms = [r for r in nulls if r['found']]
        for scenario in SCENARIOS:
            axes[1].plot([r['field'][scenario]['art']['systematic_rms_dph'] for r in alarms],
                         [r['field'][scenario]['extended']['systematic_rms_dph'] - r['field'][scenario]['art']
                          ['systematic_rms_dph'] for r in alarms], 'o', label=f'{scenario} second run')
        axes[1].axhline(MAX_WORSENING_DPH, color='k', ls=':', label='target: worse by at most 1 deg/h')
        low, high = axes[1].get_ylim()
        axes[1].set_ylim(min(low, -3.0), max(high, 3.0))
        axes[1].set_xlabel('ART: systematic rms with the bias (deg/h)')
        axes[1].set_ylabel('extended - ART (deg/h)')
        axes[1].set_title(f'the {len(alarms)} false alarms of {len(nulls)} null runs')
        axes[1].legend(fontsize=8)
        fig.tight_layout()
        names.append('loop-null.png')
        fig.savefig(out_dir / names[-1], dpi=110)
        plt.close(fig)
    return names


def findings(summary: dict[str, Any]) -> list[str]:
    """Statements read off the tables: where the extended calibration is worse than the report's on a second run."""
    out = []
    for c in summary['cells']:
        if c['magnitude'] != 1.0:
            continue
        for scenario in SCENARIOS:
            art, extended = c[f'art_{scenario}_dph'], c[f'extended_{scenario}_dph']
            if extended > art + MAX_WORSENING_DPH:
                out.append(f'- {c["effect"]} (magnitude 1, {c["hours"]:g} h fit): the extended calibration is worse '
                           f'than ART on the {scenario} run, {extended:.1f} against {art:.1f} deg/h (median).')
    weak = [c for c in summary['cells'] if c['magnitude'] == 1.0 and c['detection'] < MIN_DETECTION_RATE]
    out += [f'- {c["effect"]} at magnitude 1 on {c["hours"]:g} h logs is found in {c["detection"]:.0%} of runs '
            f'(named: {c["named"]}).' for c in weak]
    return out or ['- At magnitude 1 the extended calibration is nowhere worse than ART on a second run, and every '
                   'effect is found in at least 90 % of runs.']


def startup_check_lines(summary: dict[str, Any]) -> list[str]:
    """What the start-up check (``analysis.replay.startup_check``) dropped from the loop's terms."""
    check = summary.get('startup_check')
    if check is None:
        return []

    def listed(pairs: list[tuple[str, int]]) -> str:
        return ', '.join(f'{n} ({k})' for n, k in pairs) or 'none'

    return ['', '## Start-up check', '',
            'After the loop, `calibrate fit` replays its calibration on restarts of the fitted log itself (from a '
            'quarter and from half of it on, power-on unknown) and drops each term the restarts are better '
            'without by more than the loop\'s materiality. The tables above are after the check. It dropped terms in '
            f'{check["runs_with_drops"]} runs: {check["null_runs_with_drops"]} null runs and effect runs of '
            f'{listed(check["effect_runs_with_drops"])}; the terms dropped: {listed(check["dropped_signals"])}; '
            f'in {check["own_signal_dropped"]} of them the dropped term was on the signal of the simulated effect.']


def _yes(ok: bool) -> str:
    return 'holds' if ok else '**fails**'


def comparison(summary: dict[str, Any], baseline: dict[str, Any], label: str) -> list[str]:
    """A section setting this run's main numbers beside a baseline's (another loop, the same study)."""
    b, s = baseline, summary
    lines = ['', f'## Against the baseline ({label})', '',
             f'False alarms: {b["false_alarms"]} of {b["null_runs"]} null runs then, {s["false_alarms"]} of '
             f'{s["null_runs"]} now; cells at magnitude >= {MIN_TARGET_MAGNITUDE} missing the target: '
             f'{len(b["failing_cells"])} then, {len(s["failing_cells"])} now. Per cell (then -> now): share of runs '
             'found, median systematic rms with the bias of the extended calibration on the cold and warm second '
             'runs (deg/h).', '',
             '| effect | magnitude | fit log | found | ext. cold | ext. warm |', '|---|---:|---:|---:|---:|---:|']
    then = {(c['effect'], c['magnitude'], c['hours']): c for c in b['cells']}
    for c in s['cells']:
        old = then.get((c['effect'], c['magnitude'], c['hours']))
        if old is None:
            continue
        lines.append(f'| {c["effect"]} | {c["magnitude"]:g} | {c["hours"]:g} h | {old["detection"]:.0%} -> '
                     f'{c["detection"]:.0%} | {old["extended_cold_dph"]:.2f} -> {c["extended_cold_dph"]:.2f} | '
                     f'{old["extended_warm_dph"]:.2f} -> {c["extended_warm_dph"]:.2f} |')
    return lines


def document(summary: dict[str, Any], meta: dict[str, Any], figure_names: list[str],
             baseline: dict[str, Any] | None = None) -> str:
    """doc/loop-validation.md."""
    s = summary
    lines = [
        '# Loop validation: does a calibration make another run of the gyro better?', '',
        f'Generated by `nice -n 10 .venv/bin/python studies/loop_validation.py{" --quick" if meta["quick"] else ""}`'
        f' at commit `{meta["commit"]}`; {meta["cases"]} runs, {meta["cpu_s"]:.0f} s of CPU '
        f'({meta["wall_s"]:.0f} s wall on {meta["jobs"]} processes).', '',
        *([meta['note'], ''] if meta.get('note') else []),
        '## Setup', '',
        f'- Gyro: the packaged {SERIAL} polynomial ({meta["rows"]} x {meta["columns"]}) is the true error; '
        f'{RATE_HZ:g} Hz; `calibrate simulate`\'s rate table and chamber (10-50 degC, 1 degC/min ramps); white '
        f'noise 0.1 deg/sqrt(h); turn-on bias 0.005 deg/s; bias instability 0.0003 deg/s (Gauss-Markov, 300 s); '
        f'**slow bias wander {WANDER_DPS} deg/s ({WANDER_DPS * DEG_PER_H_PER_DPS:.1f} deg/h, Gauss-Markov, '
        f'{WANDER_TAU_S / SECONDS_PER_HOUR:g} h)** and **rate random walk {RATE_RANDOM_WALK_DPH_RTHR} '
        'deg/h/sqrt(h)** in every run.',
        '- Fit: `close_loop` (the loop of `calibrate fit`, defaults) on one run of 2 h or 6 h.',
        f'- Validation: two more runs of the same gyro ({VALIDATION_HOURS:g} h each; other seeds for noise, turn-on '
        f'bias, wander and table order): **cold** (powered on at the start) and **warm** (a node restarted '
        f'{WARM_START_S / SECONDS_PER_HOUR:g} h after power-on, after the table turned to {WARM_HEADING_DEG:g} '
        'deg). Each calibration is applied as the node applies it (`analysis.replay.replay`: static bias over the '
        f'first {DEFAULT_SAMPLES} rows, causal signals from the first sample{START_NOTE}) and measured against the '
        'table from the end of the static bias: systematic rms = rms of the steady segments\' mean errors **with '
        'the bias included**, and the heading error after 1 h.',
        '- Calibrations: **ART** (the polynomial alone), **extended** (the loop\'s), **oracle** (`fit_model` '
        'with the true form: the true term and time constant; for rate x T^3 and rate x dT/dt the true product as '
        'a log column; for the lagging coil the polynomial at the true lagged temperature, the lag started at '
        'the run\'s first sample as a node would).',
        '- Effects (size at magnitude 1 = the `calibrate simulate` default): '
        + '; '.join(f'`{e}` {effect_size(e, SimulationSettings()):g}' for e in ALL_EFFECTS) + '. Magnitudes '
        + ', '.join(f'{m:g}' for m in MAGNITUDES) + f'; {meta["reps"]} repetitions per effect x magnitude x '
        f'length (budget: {meta["budget_s"]:.0f} s of CPU), {s["null_runs"]} null runs.',
        '- Found: for shupe, warmup, supply_voltage and drift the loop must name the effect\'s signal '
        '(temperature_rate, time_since_power_on, supply_v, time); for the effects no single-signal term of the '
        'first loop expresses (coil_lag, rate_t3, rate_temperature_rate), any term found or the lack-of-fit alarm '
        '(`model_adequate: false`) counts, and the table names what was found.',
        '',
        '## Targets', '',
        '| target | measured | |', '|---|---|---|',
        f'| false alarms <= {MAX_FALSE_ALARM_RATE:.0%} of null runs | {s["false_alarms"]} of {s["null_runs"]} '
        f'({s["false_alarm_rate"]:.1%}) | {_yes(s["targets"]["false_alarm_rate"])} |',
        f'| no false alarm worsens a second run by more than {MAX_WORSENING_DPH:g} deg/h | {s["alarms_worsening"]} '
        f'do | {_yes(s["targets"]["no_alarm_worsens"])} |',
        f'| every effect at magnitude >= {MIN_TARGET_MAGNITUDE} found (in >= {MIN_DETECTION_RATE:.0%} of runs) with '
        f'field error <= {MAX_ORACLE_RATIO}x the oracle\'s (medians) | {len(s["failing_cells"])} of '
        f'{sum(c["magnitude"] >= MIN_TARGET_MAGNITUDE for c in s["cells"])} cells fail | '
        f'{_yes(s["targets"]["power_and_field_error"])} |', '',
        '## Null runs (no effect)', '',
        'Median systematic rms with the bias (deg/h) on the second runs.', '',
        '| fit log | runs | any effect found | lack-of-fit alarm | ART cold | extended cold | ART warm | '
        'extended warm | largest worsening (deg/h) |', '|---|---:|---:|---:|---:|---:|---:|---:|---:|']
    for r in s['null_rows']:
        lines.append(f'| {r["label"]} | {r["runs"]} | {r["false_alarms"]} | {r["lack_of_fit"]} | '
                     f'{r["art_cold_dph"]:.2f} | {r["extended_cold_dph"]:.2f} | {r["art_warm_dph"]:.2f} | '
                     f'{r["extended_warm_dph"]:.2f} | {r["worsening_max_dph"]:.2f} |')
    if s['false_alarm_signals']:
        lines += ['', 'Signals of the false alarms: '
                  + ', '.join(f'{n} ({k})' for n, k in s['false_alarm_signals']) + '.']
    lines += ['', '## Power table', '',
              'Found: share of runs where the loop reported the effect. Field errors: medians of the systematic '
              'rms with the bias (deg/h); ratio = median extended / median oracle, each the rms over the cold and '
              'warm run.', '',
              '| effect | magnitude | fit log | runs | found | alarm | named (runs) | ART cold | ext. cold | '
              'oracle cold | ART warm | ext. warm | oracle warm | ratio | ext. heading 1 h cold/warm (deg) |',
              '|---|---:|---:|---:|---:|---:|---|---:|---:|---:|---:|---:|---:|---:|---:|']
    for c in s['cells']:
        lines.append(f'| {c["effect"]} | {c["magnitude"]:g} | {c["hours"]:g} h | {c["runs"]} | '
                     f'{c["detection"]:.0%} | {c["alarm"]:.0%} | {c["named"]} | '
                     + ' | '.join(f'{c[f"{k}_{sc}_dph"]:.2f}' for sc in SCENARIOS for k in CALIBRATIONS)
                     + f' | {c["ratio_extended_oracle"]:.2f} | {c["extended_cold_heading_1h_deg"]:.2f} / '
                     f'{c["extended_warm_heading_1h_deg"]:.2f} |')
    if s['failing_cells']:
        lines += ['', 'Cells at magnitude >= 0.25 that miss the target: '
                  + '; '.join(f'{e} x {m:g} on {h:g} h' for e, m, h in s['failing_cells']) + '.']
    lines += startup_check_lines(s)
    if baseline is not None:
        lines += comparison(summary, baseline['summary'], baseline['label'])
    lines += ['', '## Figures', '']
    lines += [f'![{n}](figures/{n})' for n in figure_names]
    lines += ['', '## Findings', '', *findings(s)]
    return '\n'.join(lines) + '\n'


def _commit() -> str:
    try:
        done = subprocess.run(['git', '-C', str(REPO), 'log', '-1', '--format=%h %s'], capture_output=True,
                              text=True, check=True)
        dirty = subprocess.run(['git', '-C', str(REPO), 'status', '--porcelain', '--untracked-files=no'],
                               capture_output=True, text=True, check=True).stdout.strip()
        return done.stdout.strip().split(' ')[0] + (' + uncommitted changes' if dirty else '')
    except (OSError, subprocess.CalledProcessError):
        return 'unknown'


def cases_for(null_runs: int, reps: int, seed0: int = 1000) -> tuple[list[Case], list[Case]]:
    """Null cases (half on each log length) and the power table's, with distinct seeds."""
    nulls = [Case(None, 0.0, HOURS[i % len(HOURS)], seed0 + i) for i in range(null_runs)]
    cells = [(e, m, h) for e in ALL_EFFECTS for m in MAGNITUDES for h in HOURS]
    power = [Case(effect, magnitude, hours, seed0 + 100_000 + 1000 * k + rep)
             for k, (effect, magnitude, hours) in enumerate(cells) for rep in range(reps)]
    return nulls, power


def main() -> int:
    """Run the study and write the document."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--quick', action='store_true', help='a two-minute smoke run (few runs; not the document)')
    # A harmful false alarm in 1 % of runs needs hundreds to show: 100 runs of fe0cb1c showed no false alarm,
    # 300 more (seeds 5000-5299) showed 14, four of which worsened a second run by over 1 deg/h.
    parser.add_argument('--null-runs', type=int, default=400)
    parser.add_argument('--max-reps', type=int, default=20, help='most repetitions per power-table cell')
    parser.add_argument('--budget-s', type=float, default=2700.0, help='CPU seconds for the whole study')
    parser.add_argument('--jobs', type=int, default=2)
    parser.add_argument('--doc', type=Path, default=REPO / 'doc' / 'loop-validation.md')
    parser.add_argument('--results', type=Path, default=REPO / 'build' / 'loop-validation.json')
    parser.add_argument('--from-results', type=Path, help='rewrite the document and figures from saved results')
    parser.add_argument('--note', help='a paragraph for the top of the document (what loop this measures)')
    parser.add_argument('--baseline', type=Path, help='saved results of another loop to compare with')
    parser.add_argument('--baseline-label', default='baseline', help='what the baseline measured')
    args = parser.parse_args()
    if args.from_results:
        saved = json.loads(args.from_results.read_text(encoding='utf-8'))
        meta = {**saved['meta'], **({'note': args.note} if args.note else {})}
        return write(saved['results'], meta, args.doc, args.results, _baseline(args))
    if args.quick:
        args.null_runs, args.max_reps, args.budget_s = 6, 1, 120.0
        if args.doc == REPO / 'doc' / 'loop-validation.md':
            args.doc = REPO / 'build' / 'loop-validation-quick.md'
    wall, commit = time.time(), _commit()   # the code that runs, whatever is committed meanwhile
    nulls, _ = cases_for(args.null_runs, 0)
    null_results = run_all(nulls, args.jobs)
    spent = sum(r['cpu_s'] for r in null_results)
    per_run = {h: np.mean([r['cpu_s'] for r in null_results if r['hours'] == h]) for h in HOURS}
    # Effect runs cost about what null runs of their length do; the rest of the budget buys repetitions.
    cell_cost = len(ALL_EFFECTS) * len(MAGNITUDES) * sum(per_run.values())
    reps = int(max(1, min(args.max_reps, (args.budget_s - spent) // cell_cost)))
    print(f'{len(nulls)} null runs in {spent:.0f} s CPU; {reps} repetitions per cell', flush=True)
    _, power = cases_for(0, reps)
    results = null_results + run_all(power, args.jobs)
    truth = load_packaged_calibration(SERIAL)
    meta = {'quick': args.quick, 'commit': commit, 'cases': len(results),
            'cpu_s': sum(r['cpu_s'] for r in results), 'wall_s': time.time() - wall, 'jobs': args.jobs,
            'rows': truth.polynomial.rows, 'columns': truth.polynomial.columns, 'reps': reps,
            'budget_s': args.budget_s, 'note': args.note}
    return write(results, meta, args.doc, args.results, _baseline(args))


def _baseline(args: argparse.Namespace) -> dict[str, Any] | None:
    if args.baseline is None:
        return None
    saved = json.loads(args.baseline.read_text(encoding='utf-8'))
    return {'summary': saved['summary'], 'label': args.baseline_label}   # as judged when it ran


def write(results: list[dict[str, Any]], meta: dict[str, Any], doc: Path, results_path: Path,
          baseline: dict[str, Any] | None = None) -> int:
    """Summarise, save the raw results, draw the figures and write the document."""
    summary = summarise(results)
    results_path.parent.mkdir(parents=True, exist_ok=True)
    results_path.write_text(json.dumps({'meta': meta, 'summary': summary, 'results': results}, indent=1) + '\n',
                            encoding='utf-8')
    names = figures(summary, results, doc.parent / 'figures')
    doc.write_text(document(summary, meta, names, baseline), encoding='utf-8')
    print(f'{doc}: {summary["false_alarms"]} false alarms in {summary["null_runs"]} null runs; '
          f'targets {summary["targets"]}; results in {results_path}')
    return 0


if __name__ == '__main__':
    raise SystemExit(main())
