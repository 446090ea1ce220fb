"""REPORT.json and its markdown summary: what ``calibrate fit`` found and how much it helps.

Errors are measured the way the gyro is used: a static bias over the log's first
``bias_samples`` rows (the gyro must rest there), then compensation of every row
(:func:`compensation.apply_calibration`), compared with the table's rate on the
steady rows. ``uncalibrated`` is the scale factor and static bias only, ``art`` the
report's polynomial, ``extended`` the polynomial with the traced terms.
"""

from __future__ import annotations

import json
import os
from collections.abc import Sequence
from dataclasses import asdict, replace
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from art_gyro_calibration.compensation import RunStart, apply_calibration
from art_gyro_calibration.log import GyroLog, LogError
from art_gyro_calibration.analysis.loop import ADEQUACY_RATIO, Effect, LoopResult, not_written_reason
from art_gyro_calibration.analysis.metrics import error_metrics
from art_gyro_calibration.analysis.replay import Validation, judged_cold
from art_gyro_calibration.analysis.trace import DEFAULT_ALPHA, DEFAULT_DRAWS, FORMS_TRIED
from art_gyro_calibration.static_bias import static_bias

STAGES = ('uncalibrated', 'art', 'extended')
# Rows compensated at a time for the stage errors: the compensation's own arrays never span the log. Not
# calibrate apply's READ_CHUNK_ROWS (a chunk of text): a chunk's edge restarts the filtered signals, and this value
# gives the report's numbers as they have always been (another moves them by up to 1e-9).
STAGE_CHUNK_ROWS = 1 << 18


def misfit_reason(residual_rms_dph: float, budget_dph: float, excess_dph: float,
                  shapes: Sequence[tuple[str, float]]) -> str:
    """Why the lack-of-fit alarm rang, as its numbers say: the residual beyond its budget, a shape, or both."""
    named = ', '.join(f'{signal} ({shape_dph:.2f} deg/h)' for signal, shape_dph in shapes)
    shape = f'a shape beyond chance and the materiality against {named}'
    if residual_rms_dph > ADEQUACY_RATIO * budget_dph:
        level = (f'what it leaves, held out, over 10-minute means is {residual_rms_dph:.2f} deg/h, more than '
                 f'{ADEQUACY_RATIO:g} x the noise budget of {budget_dph:.2f} deg/h ({excess_dph:.2f} deg/h beyond it)')
        return f'{level}; and it has {shape}' if shapes else level
    return (f'what it leaves has {shape} (its level, held out, over 10-minute means, {residual_rms_dph:.2f} deg/h, '
            f'is within {ADEQUACY_RATIO:g} x the noise budget of {budget_dph:.2f} deg/h)')


def stage_error(log: GyroLog, result: LoopResult, bias_samples: int, stage: str) -> NDArray[np.float64]:
    """Corrected rate minus table rate, per row, for one of :data:`STAGES`, the log started as the loop took it.

    Several runs (``result.runs``): each started as the node starts it, with its own static bias.
    """
    if len(result.runs) > 1:
        return np.concatenate([stage_error(log.slice(slice(run.first_row, run.stop)), replace(
            result, runs=(), start=RunStart(run.powered_on_at_start)), bias_samples, stage) for run in result.runs])
    reference = log.ref_rate
    if reference is None:
        raise LogError('the log has no ref_rate column: errors need the rate table\'s true rate')
    n = bias_samples
    if not 2 <= n <= len(log):
        raise ValueError(f'bias_samples must be between 2 and the {len(log)} rows of the log, got {n}')
    if stage == 'uncalibrated':
        return log.rate_dps - static_bias(log.rate_dps[:n], np.zeros(n)).static_bias_drift_dps - reference
    calibration = {'art': result.art, 'extended': result.extended}[stage]
    # Chunk by chunk, as ``calibrate apply`` streams (the same result): the compensation's own arrays
    # then never span the log, only the errors do.
    size = STAGE_CHUNK_ROWS
    edges = [0, *range(max(n, size), len(log), size), len(log)]   # the first chunk holds the bias window
    out = np.empty(len(log))
    applied = None
    for start, stop in zip(edges[:-1], edges[1:]):
        part = log.slice(slice(start, stop))
        applied = apply_calibration(part, calibration, n, after=applied, start=result.start)
        out[start:stop] = applied.corrected_dps - reference[start:stop]
    return out


def stage_errors(log: GyroLog, result: LoopResult, bias_samples: int) -> dict[str, NDArray[np.float64]]:
    """:func:`stage_error` of every stage."""
    return {stage: stage_error(log, result, bias_samples, stage) for stage in STAGES}


def build_report(log: GyroLog, result: LoopResult, bias_samples: int, source: str = '') -> dict[str, Any]:
    """The report as plain data (JSON-ready)."""
    adequacy = result.adequacy
    return {
        'source': source,
        'serial_number': result.extended.serial_number,
        'rows': len(log),
        'steady_rows': int(result.segments.counts.sum()),
        'steady_segments': len(result.segments),
        'bias_samples': bias_samples,
        'polynomial': {'rows': result.art.polynomial.rows, 'columns': result.art.polynomial.columns,
                       'art_coefficients': result.art.polynomial.coefficients.tolist(),
                       'extended_coefficients': result.extended.polynomial.coefficients.tolist()},
        'noise_floor_dps': result.noise_floor_dps,
        'bias_instability_dph': result.bias_instability_dph,
        'materiality_dph': result.materiality_dph,
        'model_adequate': adequacy.model_adequate if adequacy else True,
        'adequacy': {**asdict(adequacy), 'signals': [asdict(x) for x in adequacy.signals]} if adequacy else None,
        'held_out_rms_dps': {'art': result.held_out_rms_art_dps, 'extended': result.held_out_rms_extended_dps},
        'held_out_block_s': result.held_out_block_s,
        'effects': [_effect(e) for e in result.effects],
        'findings_not_written': [{**_effect(e), 'reason': not_written_reason(e.signal)} for e in result.findings],
        'forms_tried': FORMS_TRIED,
        # One stage's errors at a time: each is as long as the log.
        'errors': {stage: error_metrics(stage_error(log, result, bias_samples, stage), result.segments).to_dict()
                   for stage in STAGES},
        # Per round: the test's statistic is what a candidate explains fitted to all bins, standardised by
        # its own chance draws; ``chance_threshold_dps2`` is the least any candidate had to explain.
        'screens': [{'chance_threshold_dps2': found.threshold_dps2, 'chance_threshold_score': found.threshold_score,
                     'draws': found.draws, 'alpha': found.alpha,
                     'candidates': [{'signal': c.signal, 'held_out_improvement_dps2': c.improvement_dps2,
                                     'explained_dps2': c.explained_dps2,
                                     'chance_max_improvement_dps2': c.null_max_dps2,
                                     'chance_threshold_dps2': c.threshold_dps2, 'score': c.score,
                                     'p_value': c.p_value, 'effect_dph': c.effect_dph, 'stands_for': c.stands_for,
                                     'fraction_of_noise_floor_variance': c.fraction_of_floor,
                                     'significant': c.significant} for c in found.candidates]}
                    for found in result.rounds],
    }


def _effect(effect: Effect) -> dict[str, Any]:
    """One effect found, as the report lists it."""
    term, score = effect.term, effect.score
    entry: dict[str, Any] = {
        'signal': term.signal,
        'description': term.describe(),
        'form': term.form,
        'coefficients': list(term.coefficients),
        'held_out_rms_without_dps': effect.held_out_rms_without_dps,
        'held_out_rms_with_dps': effect.held_out_rms_with_dps,
        'held_out_improvement_dps2': score.improvement_dps2,
        'explained_dps2': score.explained_dps2,
        'chance_max_improvement_dps2': score.null_max_dps2,
        'chance_threshold_dps2': score.threshold_dps2,
        'p_value': score.p_value,
        'effect_dph': score.effect_dph,
        'fraction_of_noise_floor_variance': score.fraction_of_floor,
    }
    if term.form == 'power':
        entry['powers'] = list(term.powers)
        entry['rate_powers'] = list(term.rate_powers)
    if term.form == 'exp_decay' or term.time_constant_s:
        entry['time_constant_s'] = term.time_constant_s
    return entry


def markdown_summary(report: dict[str, Any]) -> str:
    """A short summary for people."""
    lines = [f'# Calibration of {report["serial_number"]}', '',
             f'Log: {report["source"] or "(unnamed)"}, {report["rows"]} rows, {report["steady_rows"]} steady rows '
             f'in {report["steady_segments"]} segments; polynomial {report["polynomial"]["rows"]} x '
             f'{report["polynomial"]["columns"]}; white-noise floor {report["noise_floor_dps"]:.5f} deg/s.', '',
             '| model | rms (deg/s) | systematic rms (deg/s) | max heading error after 360 deg (deg) |',
             '|---|---|---|---|']
    for stage in STAGES:
        e = report['errors'][stage]
        lines.append(f'| {stage} | {e["rms_dps"]:.5f} | {e["systematic_rms_dps"]:.5f} | '
                     f'{e["heading_360_deg_max"]:.4f} |')
    held = report['held_out_rms_dps']
    screen = report['screens'][0] if report['screens'] else {'draws': DEFAULT_DRAWS, 'alpha': DEFAULT_ALPHA}
    lines += ['', f'Held-out rms: ART {held["art"]:.5f} deg/s, extended {held["extended"]:.5f} deg/s. An effect '
              f'counts if what it explains beats chance ({screen["draws"]} phase-randomised residuals, each '
              f'candidate against its own chance, the best of all candidates, {100 * screen["alpha"]:g} %) and '
              f'reaches {report["materiality_dph"]:.2f} deg/h over the logged envelope (the bias instability).', '']
    if not report['effects']:
        lines.append('Effects beyond the ART polynomial: nothing found.')
    else:
        lines += ['Effects beyond the ART polynomial (held-out rms without -> with the term):', '']
        for e in report['effects']:
            lines.append(f'- **{e["signal"]}**: {e["description"]}; {e["held_out_rms_without_dps"]:.5f} -> '
                         f'{e["held_out_rms_with_dps"]:.5f} deg/s; {e["effect_dph"]:.2f} deg/h, chance '
                         f'p = {e["p_value"]:.3f}')
    for e in report['findings_not_written']:
        lines.append(f'- found, **not written**: {e["description"]} ({e["effect_dph"]:.2f} deg/h): '
                     f'{e.get("reason", not_written_reason(e["signal"]))}')
    adequacy = report['adequacy']
    if adequacy and not adequacy['model_adequate']:
        shapes = [x for x in adequacy.get('signals', []) if x['found']]
        reason = misfit_reason(adequacy['residual_rms_dph'], adequacy['budget_dph'], adequacy['excess_dph'],
                               [(x['signal'], x['shape_dph']) for x in shapes])
        lines += ['', f'**Warning: the model does not fit:** {reason}: an effect none of the forms tried describes. '
                      'Look at the residual against each signal (--plots).']
        if shapes:
            lines += ['', 'Held out, what the written model leaves has a shape no form assumed (means in groups of '
                          'the signal, beyond phase-randomised chance and the materiality) against: '
                      + ', '.join(f'**{x["signal"]}** ({x["shape_dph"]:.2f} deg/h, score {x["score"]:.1f} against '
                                  f'chance {x["chance_score"]:.1f})' for x in shapes) + '.']
    lines += detection_markdown(report)
    lines += [line for warning in report.get('warnings', []) for line in ('', f'**Warning:** {warning}.')]
    lines += ['', 'Forms tried: ' + '; '.join(f'{name} ({what})' for name, what in report['forms_tried'].items()) + '.']
    if 'startup_check' in report:
        cold = judged_cold([r['source'] for r in report['startup_check']['runs']])
        lines += validation_markdown(
            report['startup_check'],
            'Start-up check: the fitted log run ' + ('from its power-on and ' if cold else '') + 'restarted warm',
            ('The fitted log from its power-on (the node told so) and ' if cold else 'The fitted log ')
            + 'restarted later, power-on unknown (a warm-up counts as decayed'
            + ('' if cold else ' and is kept') + '), each calibration applied as the node applies it')
    if 'retraced' in report:
        lines += ['', f'Asked again: {report["retraced"]["message"]}.']
    if 'window_terms' in report:
        lines += window_markdown(report['window_terms'], report['bias_samples'])
    if 'validation' in report:
        lines += validation_markdown(report['validation'])
    if 'baseline' in report:
        lines += baseline_markdown(report['baseline'])
    if 'written' in report:
        written = report['written']
        polynomial = {'baseline': 'the baseline\'s polynomial',
                      'baseline_bias_refitted': 'the baseline\'s polynomial with its bias column refitted'}.get(
            report.get('baseline', {}).get('verdict'), 'the ART polynomial refitted')
        lines += ['', f'Written: {written["calibration"]}, {polynomial} with '
                      f'{", ".join(written["terms"]) or "no term"} beyond it.']
        if 'temperature_range_c' in written:
            low, high = written['temperature_range_c']
            lines[-1] += f' Outside {low:g}..{high:g} degC (the fitted logs\' range) it is {written["beyond_range"]}.'
        needed = written.get('node_parameters', {})
        if needed:
            lines += ['', 'gyro_node refuses this calibration unless these parameters are set:', '']
            lines += [f'- `{name}`: {what}' for name, what in needed.items()]
    return '\n'.join(lines) + '\n'


def detection_markdown(report: dict[str, Any]) -> list[str]:
    """REPORT.md's lines on what the log cannot see: the candidates whose detection limit is above the materiality."""
    limits = report.get('detection_limit_dph')
    if not limits:
        return []
    materiality = report['materiality_dph']
    above = {name: d for name, d in limits.items() if d['limit_dph'] is None or d['limit_dph'] > materiality}
    lines = ['', f'What this log cannot see: the smallest effect of each form tried that the last screen would have '
                 f'found (worst case over the logged envelope, worst sign and shape); '
                 f'{len(limits) - len(above)} of {len(limits)} are below the materiality '
                 f'({materiality:.2f} deg/h).']
    if not above:
        return lines
    lines += ['', 'Above it (a smaller effect of these would have gone unseen; the length of log that would bring '
                  'each below, from how its limit falls on the log\'s first quarter and half):', '']
    for name, d in above.items():
        limit = 'no finite limit' if d['limit_dph'] is None else f'{d["limit_dph"]:.2f} deg/h'
        shape = f' ({d["shape"]})' if d['shape'] else ''
        scaling = '' if d['exponent'] is None else f'; limit ~ hours^{-d["exponent"]:.2f}'
        if d['hours_to_materiality'] is not None:
            needed = f'; about {d["hours_to_materiality"]:.3g} h of log would bring it below'
        else:
            needed = ''
        note = f' ({d["note"]})' if d['note'] else ''
        lines.append(f'- **{name}**{shape}: {limit}{scaling}{needed}{note}')
    return lines


def window_markdown(window: dict[str, Any], bias_samples: int) -> list[str]:
    """REPORT.md's lines on the terms active in the static-bias window: what each will cost a mission."""
    lines = ['', '## Terms in the static-bias window', '',
             f'The node takes its static bias over a run\'s first {bias_samples} rows with these terms applied: the '
             'error of a term\'s value there is a bias for the whole mission, while its own error decays. Implied '
             f'bias: the uncertainty of that value beyond the polynomial, from {window["method"]}; a 1-sigma for a '
             'wander no longer than the runs (a slower one adds to it). Removes: '
             'the rms after the window of what the term corrects beyond the polynomial, net of its window value. A '
             'term whose implied bias exceeds what it removes is not written.', '',
             '| term | in the window (deg/h) | implied mission bias (deg/h) | removes (deg/h) | written |',
             '|---|---:|---:|---:|---|']
    lines += [f'| {c["signal"]} | {c["window_dph"]:.2f} | {c["implied_bias_dph"]:.2f} | {c["removes_dph"]:.2f} | '
              f'{"yes" if c["written"] else "**no**"} |' for c in window['terms']]
    unsettled = [c for c in window['terms'] if not c['written']]
    if unsettled:
        lines += ['', 'Not written, and the run that would settle each:', '']
        lines += [f'- **{c["signal"]}** ({c["description"]}): {c["settle"]}' for c in unsettled]
    written = [c for c in window['terms'] if c['written']]
    if written and window['runs'] == 1:
        lines += ['', 'Written from one run, whose own noise is all that says how well: '
                  + '; '.join(f'{c["signal"]}: {c["settle"]}' for c in written) + '.']
    if window['stand_ins']:
        lines += ['', f'Stand-ins: {window["stand_ins"]}.']
    return lines


def validation_section(validation: Validation, sources: Sequence[str]) -> dict[str, Any]:
    """REPORT.json's ``validation``: per run and calibration the field errors (deg/s, deg/h, deg), and the drops."""
    return {
        'runs': [{'source': source, 'calibrations': {name: e.to_dict() for name, e in run.items()}}
                 for source, run in zip(sources, validation.runs)],
        'dropped': [{'signal': d.term.signal, 'description': d.term.describe(), 'reason': d.reason}
                    for d in validation.dropped],
    }


def field_table(rows: Sequence[tuple[str, str, dict[str, Any]]]) -> list[str]:
    """Markdown table of field errors: one row per (run, calibration, ``FieldErrors.to_dict()``)."""
    def number(value: float | None, digits: int) -> str:
        return 'n/a' if value is None else f'{value:.{digits}f}'

    lines = ['| run | calibration | mean bias (deg/h) | systematic rms with bias (deg/h) | '
             'heading after 10 min (deg) | heading after 1 h (deg) |', '|---|---|---:|---:|---:|---:|']
    for run, name, e in rows:
        if e.get('bias_refused'):
            name += ' (static bias refused)'
        lines.append(f'| {run} | {name} | {number(e["mean_bias_dph"], 2)} | {number(e["systematic_rms_dph"], 2)} | '
                     f'{number(e["heading_10min_deg"], 3)} | {number(e["heading_1h_deg"], 3)} |')
    return lines


def validation_markdown(validation: dict[str, Any], title: str = 'Field replay on other runs',
                        what: str = 'Each calibration applied to another run as the node applies it') -> list[str]:
    """REPORT.md's lines on replayed runs: the ``--validate`` runs, or the start-up check's restarts."""
    lines = ['', f'## {title}', '',
             f'{what} (static bias over its first rows, signals from its first sample), errors from the end of '
             'the static bias on, the bias included.', '']
    lines += field_table([(run['source'], name, e) for run in validation['runs']
                          for name, e in run['calibrations'].items()])
    if validation['dropped']:
        lines += ['', 'Dropped from the written calibration:', '']
        lines += [f'- **{d["signal"]}** ({d["description"]}): {d["reason"]}' for d in validation['dropped']]
    return lines


def baseline_markdown(baseline: dict[str, Any]) -> list[str]:
    """REPORT.md's lines on the comparison with the gyro's current calibration."""
    lines = ['', '## Against the calibration the gyro has (baseline)', '']
    if baseline['source'] is None or 'runs' not in baseline:
        return lines + [baseline['message'][0].upper() + baseline['message'][1:] + '.']
    lines += [f'Baseline {baseline["source"]}. The refit is fitted again without each fold of held-out blocks; '
              'the node\'s runs on this log are replayed with it as the node applies it (static bias over the '
              'run\'s first rows, bias included), each row with the fit that did not see it; the baseline as it is.',
              '']
    lines += field_table([(run['run'], name, run[name]) for run in baseline['runs'] for name in ('refit', 'baseline')])
    verdict = {'refit': '**Verdict: the refit is written.**',
               'baseline_bias_refitted': '**Verdict: the baseline\'s rate terms are kept, its bias column refitted.**'
               }.get(baseline['verdict'], '**Verdict: the baseline polynomial is kept.**')
    lines += ['', f'{verdict} {baseline["message"][0].upper() + baseline["message"][1:]}.']
    operating, unknown = baseline.get('operating_range_c'), baseline.get('unknown_beyond_log')
    if operating is not None:
        lines += ['', f'Operating range {operating[0]:g}..{operating[1]:g} degC (--operating-range; default the '
                  'log\'s).' + ('' if unknown is None else f' Unknown: {unknown["message"]}.')]
    return lines


def write_report(path: str | os.PathLike[str], report: dict[str, Any]) -> Path:
    """Write REPORT.json and the markdown summary beside it (same name, ``.md``); returns the summary's path."""
    p = Path(path)
    p.write_text(json.dumps(report, indent=2) + '\n', encoding='utf-8')
    summary = p.with_suffix('.md')
    summary.write_text(markdown_summary(report), encoding='utf-8')
    return summary
