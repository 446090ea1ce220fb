"""The calibration loop on real gyros' logs: a CATS tag's MEMS IMU lying still for three days, and a phone.

``python research/studies/measured_data.py`` downloads the records (they ship in the
scikit-diveMove 0.4.0 wheel; AGPL, so they are fetched at run time and never committed),
holds out each day of the CATS record in turn and runs the package's loop
(``loop.close_loop``, the code of ``calibrate fit``) on the others, adds known effects to
the real readings and runs the loop blind again, sets the phone's noise beside the tag's,
and writes ``research/doc/measured-data.md`` with its figures. ``--quick`` is a smoke run of every part.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import time
from collections import Counter
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from art_gyro_calibration.analysis.allan import AllanDeviation
from art_gyro_calibration.analysis.loop import DEFAULT_MAX_EFFECTS
from art_gyro_calibration.analysis.report import STAGES
from art_gyro_calibration.log import GyroLog
from art_gyro_calibration.units import DEG_PER_H_PER_DPS, SECONDS_PER_HOUR

# The study's parts beside it, and the research's importers one folder up (neither folder is a package).
sys.path[:0] = [str(Path(__file__).resolve().parent), str(Path(__file__).resolve().parents[1])]
from importers import StaticRecord, runs, static_log  # noqa: E402
import measured_figures as figures  # noqa: E402
from measured_folds import (AGREEMENT_SIGMAS, BIAS_SAMPLES, LOOP_BIN_S, ROWS, SETTLED_C_PER_H,  # noqa: E402
                            STAGE_TITLES, TIME_SIGNALS, WAY_TITLES, WAYS, Fold, record_allan, run_fold)
from measured_injection import (EFFECT_TITLES, EFFECTS, EXPECTED_SIGNALS, SIZES, WARMUP_TAU_S, Cell,  # noqa: E402
                                cells, run_injections)
from measured_phone import STAND_IN_C, TRAIN_FRACTION, PhoneAxis, phone_summary, run_phone_axis  # noqa: E402
from measured_record import (AXES, BLOCK_S, DEFAULT_DATA_DIR, MEMBERS, PACKAGE_SPEC,  # noqa: E402
                             DataUnavailable, fetch_records, import_cats, import_phone, orientation_labels)


@dataclass(frozen=True)
class Plan:
    """What a run covers: the full study or the quick smoke run."""

    hold_out: tuple[int, ...]  # 1-based days
    injection_days: tuple[int, ...]
    injection_axes: tuple[str, ...]
    sizes: tuple[float, ...]
    phone_axes: tuple[str, ...]


FULL = Plan((1, 2, 3), (2, 3), AXES, SIZES, AXES)
QUICK = Plan((3,), (3,), ('y',), SIZES[:1], ('z',))


@dataclass(frozen=True)
class Study:
    """Everything the document reports."""

    record: StaticRecord
    still: NDArray[np.bool_]
    names: tuple[str, ...]
    folds: dict[int, list[Fold]]  # held-out day (1-based) -> one fold per axis
    floors: dict[str, float]
    cats_allan: dict[str, dict[str, AllanDeviation]]
    cells: list[Cell]
    phone: list[PhoneAxis]
    plan: Plan
    cpu_s: float
    version: str = ''  # `` at commit <hash>`` of the code that ran, taken before anything is written


def run_study(paths: dict[str, Path], plan: Plan, max_effects: int = DEFAULT_MAX_EFFECTS) -> Study:
    """Every fold, the injections and the phone, with progress on stderr."""
    start = time.process_time()
    version = _version()

    def say(text: str) -> None:
        print(f'[{time.process_time() - start:6.0f} s cpu] {text}', file=sys.stderr, flush=True)

    record, still = import_cats(paths['cats'])
    logs: dict[str, GyroLog] = {a: static_log(record, f'gyro_{a}', still) for a in AXES}
    labels, names = orientation_labels(logs['x'])
    folds: dict[int, list[Fold]] = {}
    for day in plan.hold_out:
        folds[day] = [run_fold(logs[a], labels, day - 1, f'day {day} ({names[day - 1]})', a, max_effects)
                      for a in AXES]
        say(f'day {day} held out: ' + '; '.join(f'{f.axis}: {len(f.kept_effects)} effects kept' for f in folds[day]))
    cats_allan = {}
    for a in AXES:
        raw, art = record_allan(logs[a])
        cats_allan[a] = {'raw': raw, 'art': art}
    floors = {a: float(cats_allan[a]['art'].adev.min()) for a in AXES}
    bases = [f for day in plan.injection_days for f in folds[day] if f.axis in plan.injection_axes]
    trials = run_injections(bases, {a: labels for a in AXES}, floors, EFFECTS, plan.sizes, max_effects,
                            lambda t: say(f'injected {t.effect} x{t.factor:g} into {t.fold.axis}, '
                                          f'{t.fold.held_name} out: named {", ".join(t.named) or "nothing"}'))
    phone_record, phone_still = import_phone(paths['phone'])
    phone = [run_phone_axis(phone_record, phone_still, a, max_effects) for a in plan.phone_axes]
    say('phone done')
    return Study(record, still, names, folds, floors, cats_allan, cells(trials), phone, plan,
                 time.process_time() - start, version)


# --- the document ------------------------------------------------------------------------


def _version() -> str:
    """`` at commit <hash>`` of the source tree, when it is a git checkout."""
    try:
        done = subprocess.run(['git', 'describe', '--always', '--dirty'], capture_output=True, text=True,
                              timeout=10, cwd=Path(__file__).resolve().parent)
    except (OSError, subprocess.TimeoutExpired):
        return ''
    return f' at commit {done.stdout.strip()}' if done.returncode == 0 and done.stdout.strip() else ''


def _dph(dps: float) -> str:
    return f'{dps * DEG_PER_H_PER_DPS:.0f}'


def _deg(value: float) -> str:
    return 'n/a' if not np.isfinite(value) else f'{value:+.1f}'


def _effects(fold: Fold) -> str:
    """The effects the loop traced, and which of them the final model keeps."""
    if not fold.loop.effects and not fold.restart_dropped:
        return 'none'
    kept = {id(t) for t in fold.kept_effects}
    dropped = {id(a.term) for a in fold.agreements if not a.kept}
    out = []
    for e in fold.loop.effects:
        verdict = ' (dropped: the training days disagree)' if id(e.term) in dropped else ''
        out.append(e.term.describe() + verdict if id(e.term) in kept or verdict else e.term.describe())
    out += [f'{t.describe()} (dropped: the training days\' own restarts are better without)'
            for t in fold.restart_dropped]
    return '; '.join(out)


def headline_table(study: Study) -> list[str]:
    """Per axis and held-out day: effects, 10-min rms (deg/s and deg/h) and 1-h heading, every way."""
    lines = ['| gyro | held-out day | effects traced on the training days | 10-min rms (deg/s), static bias after '
             'the transient: static bias only / ART / ART + effects | ART + effects, 10-min rms (deg/h): '
             + ' / '.join(WAY_TITLES[w] for w in WAYS) + ' | ART + effects, heading after 1 h (deg): '
             + ' / '.join(WAY_TITLES[w] for w in WAYS) + ' |', '|---|---|---|---|---|---|']
    for i, axis in enumerate(AXES):
        for fold in (study.folds[day][i] for day in study.folds):
            settled = ' / '.join(f'{fold.field[s, "bias_settled"].systematic_rms_dps:.4f}' for s in STAGES)
            dph = ' / '.join(_dph(fold.field['extended', w].systematic_rms_dps) for w in WAYS)
            heading = ' / '.join(_deg(fold.field['extended', w].heading_1h_deg) for w in WAYS)
            lines.append(f'| {axis} | {fold.held_name} | {_effects(fold)} | {settled} | {dph} | {heading} |')
    return lines


def axis_table(study: Study, i: int) -> list[str]:
    """Every model, every way, on every held-out day of one axis."""
    head = ' | '.join(f'{WAY_TITLES[w]}: 10-min rms (mean) deg/h; heading 10 min / 1 h (deg)' for w in WAYS)
    lines = [f'| held-out day | model | {head} | 1-h heading rms over the day, static bias after the transient (deg) |',
             '|---' * (3 + len(WAYS)) + '|']
    for day in study.folds:
        fold = study.folds[day][i]
        for stage in STAGES:
            cells_ = []
            for w in WAYS:
                f = fold.field[stage, w]
                cells_.append(f'{_dph(f.systematic_rms_dps)} ({_dph(f.mean_bias_dps)}); '
                              f'{_deg(f.heading_10min_deg)} / {_deg(f.heading_1h_deg)}')
            lines.append(f'| {fold.held_name} | {STAGE_TITLES[stage]} | {" | ".join(cells_)} | '
                         f'{fold.heading_1h_rms_deg[stage, "bias_settled"]:.1f} |')
    return lines


def fold_notes(fold: Fold) -> str:
    """One line per fold: materiality, blocks, the transient, effects and their agreement, near misses."""
    t = fold.log.t
    settled_h = (t[fold.bias_windows['bias_settled'][0]] - t[fold.bias_windows['bias_start'][0]]) / SECONDS_PER_HOUR
    text = (f'{fold.held_name} held out (materiality {fold.loop.materiality_dph:.1f} deg/h, held-out blocks of '
            f'{fold.loop.held_out_block_s / SECONDS_PER_HOUR:.1f} h; the temperature settled {settled_h:.1f} h '
            'into the day): ')
    if fold.loop.effects:
        text += 'traced ' + '; '.join(f'{e.term.describe()} (cross-validated rms on the training days '
                                      f'{e.held_out_rms_without_dps:.5f} -> {e.held_out_rms_with_dps:.5f} deg/s)'
                                      for e in fold.loop.effects)
        if fold.agreements:
            text += '; each training day alone, gain on the time term: ' + '; '.join(
                a.describe() for a in fold.agreements)
    if fold.restart_dropped:
        text += ('; ' if fold.loop.effects else '') + 'dropped by the start-up check: ' + '; '.join(
            term.describe() for term in fold.restart_dropped)
    if not fold.loop.effects and not fold.restart_dropped:
        first = fold.loop.rounds[0].candidates[:3]
        text += 'no effect beyond the ART polynomial; best candidates: ' + ', '.join(
            f'{c.signal} ({c.effect_dph:.1f} deg/h, chance p = {c.p_value:.3f})' for c in first)
    adequacy = fold.loop.adequacy
    if adequacy is not None:
        text += (f'. Lack-of-fit alarm: {"quiet" if adequacy.model_adequate else "raised"} (block means of '
                 f'{adequacy.block_s / 60:.0f} min leave {adequacy.residual_rms_dph:.1f} deg/h against a budget of '
                 f'{adequacy.budget_dph:.1f})')
    return text + '.'


def injection_table(study: Study) -> list[str]:
    """Per effect and size: detection, signals named, take-up, held-out errors."""
    lines = ['| effect | size: rms (x bias instability) | coefficient (median over axes) | signal named | '
             'signals kept | another signal claimed | taken up by the named terms (median, range) | '
             'held-out 10-min rms, bias after transient: ART -> ART + effects (median deg/h) | '
             'same, as predicted (median deg/h) |', '|---' * 9 + '|']
    units = {'shupe': 'deg/s per degC/s', 'warmup': 'deg/s at power-on', 'drift': 'deg/s per day',
             'step': 'deg/s'}
    for cell in study.cells:
        n = len(cell.trials)
        rec = cell.recovered()
        taken = f'{np.median(rec):.2f} ({rec.min():.2f}..{rec.max():.2f})' if rec.size else 'n/a'
        coefficient = np.median([abs(t.coefficient) for t in cell.trials])
        size = np.median([t.rms_dps for t in cell.trials])
        lines.append(
            f'| {EFFECT_TITLES[cell.effect]} | {size:.4f} deg/s ({cell.factor:g}) | {coefficient:.3g} '
            f'{units[cell.effect]} | {cell.detected}/{n} | {cell.named()} | {cell.new_claims()}/{n} | {taken} | '
            f'{np.median(cell.held_out("art", "bias_settled")):.0f} -> '
            f'{np.median(cell.held_out("extended", "bias_settled")):.0f} | '
            f'{np.median(cell.held_out("art", "predicted")):.0f} -> '
            f'{np.median(cell.held_out("extended", "predicted")):.0f} |')
    return lines


def phone_table(study: Study) -> list[str]:
    """The phone's noise beside the tag's, and what the loop says on the phone."""
    lines = ['| gyro | phone: Allan at 1 s (deg/s) | phone: floor (deg/s) at tau | CATS raw: Allan at 1 s | '
             'CATS after ART: floor at tau | loop on the phone\'s first two thirds | phone, last third held out: '
             '10-min rms as predicted, ART -> ART + effects (deg/h) | same, mean removed (deg/h) |',
             '|---' * 8 + '|']
    for p in study.phone:
        white, floor, tau, _ = phone_summary(p)
        raw, art = study.cats_allan[p.axis]['raw'], study.cats_allan[p.axis]['art']
        k = int(np.argmin(art.adev))
        f = p.fold.field
        lines.append(f'| {p.axis} | {white:.4f} | {floor:.4f} at {tau:.0f} s | {raw.adev[0]:.4f} | '
                     f'{art.adev[k]:.4f} at {art.tau_s[k]:.0f} s | {_effects(p.fold)} | '
                     f'{_dph(f["art", "predicted"].systematic_rms_dps)} -> '
                     f'{_dph(f["extended", "predicted"].systematic_rms_dps)} | '
                     f'{_dph(f["art", "mean_removed"].systematic_rms_dps)} -> '
                     f'{_dph(f["extended", "mean_removed"].systematic_rms_dps)} |')
    return lines


def baseline_claims(study: Study) -> str:
    """Which effects the loop keeps on the record without injection, over every fold."""
    claims = [f'gyro {f.axis}, {f.held_name} out: {", ".join(t.describe() for t in f.kept_effects)}'
              for day in study.folds for f in study.folds[day] if f.kept_effects]
    total = sum(len(v) for v in study.folds.values())
    return (f'On the record without injection the loop keeps effects in {len(claims)} of {total} folds'
            + (': ' + '; '.join(claims) if claims else '') + '.')


def markdown(study: Study, figs: dict[str, Any]) -> str:
    """The text of research/doc/measured-data.md."""
    record, still = study.record, study.still
    hours = float(still.sum()) / SECONDS_PER_HOUR
    every = [f for day in study.folds for f in study.folds[day]]
    materiality = [f.loop.materiality_dph for f in every]
    white = [f.allan['art'].adev[0] for f in every]
    drops = [study.folds[d][0].log.temp_c[study.folds[d][0].bias_windows['bias_start'][0]]
             - study.folds[d][0].log.temp_c[study.folds[d][0].bias_windows['bias_settled'][0]] for d in study.folds]
    floors = list(study.floors.values())
    lines = [
        '# Real gyros\' logs: a CATS tag\'s MEMS IMU lying still for three days, and a phone for six hours',
        '',
        f'_Written by `nice -n 10 .venv/bin/python research/studies/measured_data.py`{study.version} in '
        f'{study.cpu_s / 60:.1f} min of CPU; every number below comes from that run._',
        '',
        '## What these records can and cannot test',
        '',
        '- **They can test the thermal-bias half of the model**: the report\'s temperature polynomial at rate '
        'power 0, fitted on some days and judged on another, the static bias as the node takes it, the tracer\'s '
        'verdicts on slow effects (a drift, a warm-up, a temperature-rate term, an orientation step) against a '
        'real gyro\'s real bias wander, and whether the noise model (white noise, then a bias-instability floor, '
        'then a slow wander) holds on two unrelated MEMS gyros.',
        '- **They cannot test the rate half**: both gyros lay still, so there is no scale factor, no '
        'scale-factor-temperature cross term, no non-linearity, no rate-dependent or turn-dependent effect (the '
        'loop does not even screen the signals derived from the rate, which on a still gyro are its own error). '
        'The CATS tag lay in one orientation per day, so an orientation effect cannot be told from the day; it '
        'was powered on once, so whether a drift restarts at power-on (what a `time` term assumes: the node '
        'counts `time` from its own start) cannot be told from the bias wander either. Both are MEMS gyros '
        f'({min(white):.2f}-{max(white):.2f} deg/s of white noise per 1 Hz sample on the tag, turn-on biases of '
        'degrees per second), not a fibre optic gyro: the sizes here say nothing about an RD2100\'s.',
        '- **What a rate-table record of an RD2100 would add**: the whole polynomial (rate powers and their '
        'temperature cross terms, from table rates of +-100 deg/s at several chamber temperatures), the '
        'scale-factor and Shupe (dT/dt) effects of a fibre coil at the sizes that matter for it (bias '
        'instability of hundredths of a deg/h, not tens), power cycles to tell a turn-on warm-up from a drift, '
        'orientation changes within a day to tell g-sensitivity from the day, and a known true rate for the '
        'heading errors after a full turn that `calibrate fit` reports.',
        '',
        '## The CATS record',
        '',
        f'`{MEMBERS["cats"][0]}` from the PyPI package `{PACKAGE_SPEC}` (AGPL: downloaded at run time into '
        '`data/`, never committed): a CATS tag\'s MEMS IMU lying still in three orientations, one day each, while '
        'its temperature swung between about 5 and 28 degC, resampled to 1 Hz. '
        f'{len(record.t)} samples over {(record.t[-1] - record.t[0]) / SECONDS_PER_HOUR:.1f} h; the importer '
        f'(`importers.still_mask`) keeps {hours:.1f} h in {len(runs(still))} still runs, cutting the handling '
        f'between orientations with 5 min either side. Orientations in turn: {", ".join(study.names)}. Each day '
        f'starts with a handling transient: the temperature falls by {min(drops):.1f}-{max(drops):.1f} degC before '
        'it settles.',
        '',
        f'![the record]({figs["record"]})',
        '',
        'Each gyro axis becomes a log in the project\'s format (`importers.static_log`): `rate_dps` (mrad/s '
        'converted), `temp_c`, `ref_rate` = 0 (it lay still), and every other channel as an extra column the '
        'tracer screens: the other two gyro axes, `acc_x/y/z`, `mag_x/y/z`, `depth` (the tag\'s pressure sensor).',
        '',
        '## The loop',
        '',
        f'`loop.close_loop`, the code of `calibrate fit`, called as it is (no copy), with the report\'s {ROWS} '
        'temperature powers and rate power 0, and its defaults but one: it screens bin means of '
        f'{LOOP_BIN_S:g} s instead of 1 s (every effect in question lives on hours; on gyro y with day 3 held out '
        'the verdict and the best candidates were the same with 1-s bins, at 15 times the CPU). Its time '
        'candidates are a linear drift in `time` (from the run\'s start) and a warm-up `exp(-t/tau)` in '
        '`time_since_power_on`, tau from 30 s to four times the run, a candidate only when the log starts at the '
        'power-on (`from_power_on`).',
        '',
        '- **Held out: each day in turn**, which is one orientation too. Day 1 holds the power-on; with day 1 '
        'held out the training days do not start at it, so the loop is told so (`from_power_on=False`: no '
        'warm-up candidate), its `time` counts from the first training sample (day 2), and the held-out day is '
        'evaluated on that clock, before the training days: a drift is then extrapolated backwards.',
        '- **Chance and materiality are the loop\'s own** (`calibrate fit`\'s defaults): a candidate must beat '
        'the 95 % quantile of the best chance score over phase-randomised copies of what the base model leaves, '
        'and its fitted size over the logged envelope must reach the bias instability of what the ART '
        f'polynomial leaves on the training days (here {min(materiality):.1f}-{max(materiality):.1f} deg/h, given '
        'per fold below).',
        f'- **A time term is kept only if the training days agree on it** (the study\'s rule, after the loop): on '
        f'each training day alone, the 10-minute means of what the rest of the model leaves are regressed on the '
        f'term\'s correction, with a free constant (the day\'s bias), giving that day\'s gain (1 = the joint fit) '
        f'with a Newey-West standard error over the lags the residual stays correlated. A day judges if the term '
        f'varies there by more than the bias instability; the term is kept if every judging day confirms it '
        f'(gain > {AGREEMENT_SIGMAS:g} standard errors) and any two agree within {AGREEMENT_SIGMAS:g} standard '
        f'errors; otherwise the rest is refitted without it (`fit.fit_model`).',
        f'- **Errors on the held-out day, four ways**, in deg/s, deg/h and heading: *as predicted* (the model\'s '
        f'absolute bias, nothing removed), *static bias at the start* (the node\'s `StaticBias()` over the day\'s '
        f'first {BIAS_SAMPLES / 60:.0f} min, in the handling transient), *static bias after the transient* (over '
        f'the first {BIAS_SAMPLES / 60:.0f} min in which the temperature changes by at most {SETTLED_C_PER_H:g} '
        f'degC/h), and *mean removed* (the best constant: what is left is the wander). All four are measured over '
        f'the same span, from the end of the settled bias window to the end of the day: "10-min rms" is the rms of '
        f'{BLOCK_S / 60:.0f}-minute means (the systematic part, bias included), the heading is the error '
        f'integrated from the start of the span over 10 min and 1 h (`metrics.field_errors`; one draw of the '
        f'white noise alone, which is {np.median(white) * np.sqrt(600):.1f} and {np.median(white) * 60:.1f} deg rms '
        'for this gyro), and the 1-h heading rms over the day is over 1-h missions starting every 10 min.',
        '',
        '## Results: each day held out',
        '',
    ]
    lines += headline_table(study) + ['', f'![rate against temperature]({figs["temperature"]})', '']
    for i, axis in enumerate(AXES):
        lines += [f'### Gyro {axis}', ''] + axis_table(study, i) + ['']
        lines += [f'- {fold_notes(study.folds[day][i])}' for day in study.folds] + ['']
        for day in study.folds:
            lines += [f'![gyro {axis}, day {day} held out]({figs["folds"][day][i]})', '']
    lines += ['## Allan deviation of what is left', '']
    for day in study.folds:
        lines += [f'![Allan deviation, day {day} held out]({figs["allan"][day]})', '']
    lines += ['| held-out day | axis | white noise at 1 s (deg/s) | floor (deg/s) at tau | '
              'ART: at the longest tau | ART + effects: at the longest tau |', '|---|---|---|---|---|---|']
    for day in study.folds:
        for f in study.folds[day]:
            a, art = f.allan['extended'], f.allan['art']
            k = int(np.argmin(a.adev))
            lines.append(f'| {f.held_name} | {f.axis} | {a.adev[0]:.4f} | {a.adev[k]:.4f} at {a.tau_s[k]:.0f} s | '
                         f'{art.adev[-1]:.4f} at {art.tau_s[-1]:.0f} s | {a.adev[-1]:.4f} at {a.tau_s[-1]:.0f} s |')
    plan = study.plan
    lines += [
        '',
        '## Injection: known effects added to the real record, found blind',
        '',
        'Each effect is added to the real readings of a gyro axis (its real noise, temperature history and bias '
        'wander stay) and every fold is run again exactly as above; nothing about the effect is told to the loop. '
        f'Sizes are rms over the still record in units of the axis\'s bias instability (Allan floor of what the '
        f'ART polynomial fitted to the whole record leaves: {min(floors):.4f}-{max(floors):.4f} deg/s, '
        f'{min(floors) * DEG_PER_H_PER_DPS:.0f}-{max(floors) * DEG_PER_H_PER_DPS:.0f} deg/h), '
        f'{", ".join(f"{s:g}" for s in plan.sizes)} times it. '
        f'Trials: gyro {", ".join(plan.injection_axes)} with day {", ".join(map(str, plan.injection_days))} '
        'held out (day 1 is not held out here: a warm-up lives in it, and with it held out the training days '
        'never see the step).',
        '',
        f'- **Effects**: {EFFECT_TITLES["shupe"]} (`temperature_rate`, the node\'s own filtered dT/dt); '
        f'{EFFECT_TITLES["warmup"]} from the record\'s start (`time_since_power_on`, tau '
        f'{WARMUP_TAU_S / SECONDS_PER_HOUR:g} h); '
        f'{EFFECT_TITLES["drift"]} over the whole record (`time`); {EFFECT_TITLES["step"]} (a constant added from '
        'day 2 on).',
        '- **Signal named**: the loop kept a term on the effect\'s signal (for the step: any accelerometer or '
        f'magnetometer axis: {", ".join(EXPECTED_SIGNALS["step"])}). **Another signal claimed**: it kept a term on '
        'a signal that neither names the effect nor was kept without the injection.',
        '- **Taken up**: the named terms\' correction minus that of the fold without injection, regressed on the '
        'injected effect over the training days: 1 = the effect exactly, more = the record\'s own effect on that '
        'signal came along; its coefficient error is this minus 1.',
        '- **Held-out error**: the held-out day of the injected record, median over the trials.',
        '',
    ]
    lines += injection_table(study) + ['', f'![injection]({figs["injection"]})', '', baseline_claims(study), '']
    lines += [
        '## A second record: a phone lying still',
        '',
        f'`{MEMBERS["phone"][0]}` (same wheel, AGPL, fetched at run time): a Samsung Galaxy S5 lying still, '
        f'{(study.phone[0].log.t[-1] - study.phone[0].log.t[0]) / SECONDS_PER_HOUR if study.phone else 0:.1f} h '
        'of still samples at 10 Hz, two gyro streams (the phone\'s output and its measured stream, nearly the same '
        'readings), no temperature (`importers.read_phone_netcdf`). The loop runs on the output stream with '
        f'no temperature power (a constant {STAND_IN_C:g} degC stands in, said so to `static_log`), the other '
        f'stream never a candidate, trained on the first {TRAIN_FRACTION:.0%} and judged on the rest.',
        '',
        f'![Allan deviation, phone and CATS tag]({figs["phone"]})',
        '',
    ]
    lines += phone_table(study)
    lines += ['', '## What was found and what was not', ''] + findings(study)
    return '\n'.join(lines) + '\n'


def findings(study: Study) -> list[str]:
    """Plain statements drawn from the numbers."""
    out = []
    every = [f for day in study.folds for f in study.folds[day]]
    for way in ('predicted', 'bias_start', 'bias_settled'):
        better = sum(f.field['art', way].systematic_rms_dps < f.field['uncalibrated', way].systematic_rms_dps
                     for f in every)
        out.append(f'- **ART against no model, {WAY_TITLES[way]}**: the temperature polynomial lowers the held-out '
                   f'10-min rms in {better} of {len(every)} folds.')
    settled = sum(f.field['extended', 'bias_settled'].systematic_rms_dps
                  < f.field['extended', 'bias_start'].systematic_rms_dps for f in every)
    out.append(f'- **The static bias after the transient** beats the one taken at the start in {settled} of '
               f'{len(every)} folds (ART + effects, 10-min rms).')
    traced = [f for f in every if f.loop.effects or f.restart_dropped]
    helped = [f for f in every if f.kept_effects and f.field['extended', 'bias_settled'].systematic_rms_dps
              < f.field['art', 'bias_settled'].systematic_rms_dps]
    dropped = sum(not a.kept for f in every for a in f.agreements)
    restarted = Counter(t.signal for f in every for t in f.restart_dropped)
    out.append(f'- **Effects beyond temperature**: the loop traced something in {len(traced)} of {len(every)} '
               f'folds; the start-up check (the training days restarted from a quarter and from half of them on, '
               'as `calibrate fit` does) dropped '
               + (', '.join(f'{k} ({n})' for k, n in restarted.most_common()) or 'nothing')
               + f'; the training-day agreement dropped {dropped} time term(s); the effects kept lowered the '
               f'held-out 10-min rms (bias after the transient) in {len(helped)} folds.')
    timed = sum(any(e.signal in TIME_SIGNALS for e in f.loop.effects) for f in every)
    out.append(f'- **A drift on the record itself**: the loop traced a time term in {timed} of {len(every)} folds '
               '(a drift or slow warm-up must beat the chance of phase-randomised copies of the bias wander, '
               'which on two training days it rarely does).')
    for effect in dict.fromkeys(c.effect for c in study.cells):
        mine = [c for c in study.cells if c.effect == effect]
        out.append(f'- **Injected {EFFECT_TITLES[effect]}**: named in '
                   + ', '.join(f'{c.detected} of {len(c.trials)} at {c.factor:g} x' for c in mine)
                   + ' the bias instability.')
    runs_ = [(f, f.held_name) for f in every] + [(t.fold, f'{t.fold.held_name}, {t.effect} x{t.factor:g}')
                                                 for c in study.cells for t in c.trials]
    wild = [(f, name) for f, name in runs_ if f.kept_effects and f.field['extended', 'predicted'].systematic_rms_dps
            > 2.0 * f.field['art', 'predicted'].systematic_rms_dps]
    signals = Counter(t.signal for f, _ in wild for t in f.kept_effects)
    out.append(f'- **Terms that extrapolate**: in {len(wild)} of {len(runs_)} runs (folds and injection trials) the '
               'kept effects more than doubled the held-out 10-min rms as predicted; their signals: '
               + (', '.join(f'{k} ({n})' for k, n in signals.most_common()) or 'none')
               + '. A term on a magnetometer or accelerometer axis fitted on two orientations is extrapolated to a '
               'third one the training days never saw; a static bias takes its offset out, not its change within '
               'the day.')
    if study.phone:
        parts = []
        for p in study.phone:
            a = p.allan['gyro']
            k = int(np.argmax(np.where(a.tau_s < 10.0, a.adev, 0.0)))
            parts.append(f'{p.axis}: {a.adev[0]:.4f} deg/s at {a.tau_s[0]:g} s, {a.adev[k]:.4f} at {a.tau_s[k]:g} s')
        out.append('- **The phone\'s noise**: its Allan deviation first rises (' + '; '.join(parts) + ') and only '
                   'then falls as white noise would: its 10 Hz streams were filtered (the file says subset and '
                   'decimated), so its first value is not its white noise. Beyond that it reaches a floor of the '
                   'same order as the tag\'s and rises again: the same shape of noise model on a second, unrelated '
                   'MEMS gyro.')
    ext = [f.allan['extended'] for f in every]
    rising = sum(a.adev[-1] > 1.3 * a.adev.min() for a in ext)
    out += [
        f'- **Random, not traced**: the Allan deviation of what is left on the held-out day falls as tau^-1/2 to a '
        f'floor of {min(a.adev.min() for a in ext):.4f}-{max(a.adev.min() for a in ext):.4f} deg/s and rises '
        f'again at longer tau in {rising} of the {len(ext)} cases: a slow wander of the bias that no logged '
        'signal explains on a day the model was not fitted on.',
        '- **Not claimed**: an effect the loop reports beat chance and the bias instability on blocks of the '
        'training days; a term that passes there can still fail on another day, which is why each verdict above '
        'is the held-out day\'s.',
    ]
    return out


def write_figures(study: Study, fig_dir: Path, doc: Path) -> dict[str, Any]:
    """Every figure, and its path relative to the document."""
    fig_dir.mkdir(parents=True, exist_ok=True)
    rel = Path(os.path.relpath(fig_dir, doc.parent))

    def name(path: Path) -> str:
        return str(rel / path.name)

    first = study.folds[2 if 2 in study.folds else min(study.folds)]
    out: dict[str, Any] = {
        'record': name(figures.plot_record(study.record, study.still, fig_dir / 'measured-record.png')),
        'temperature': name(figures.plot_temperature(first, fig_dir / 'measured-temperature.png')),
        'folds': {day: [name(figures.plot_fold(f, fig_dir / f'measured-{f.axis}-day{day}.png')) for f in folds]
                  for day, folds in study.folds.items()},
        'allan': {day: name(figures.plot_allan(folds, fig_dir / f'measured-allan-day{day}.png'))
                  for day, folds in study.folds.items()},
        'injection': name(figures.plot_injection(study.cells, fig_dir / 'measured-injection.png')),
        'phone': name(figures.plot_phone(study.phone, study.cats_allan, fig_dir / 'measured-phone-allan.png')),
    }
    return out


def main(argv: Sequence[str] | None = None) -> int:
    """Download, run every part, write the figures and the document."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--data-dir', default=str(DEFAULT_DATA_DIR), help='download cache (default %(default)s)')
    parser.add_argument('--doc', help='document to write (default research/doc/measured-data.md, '
                                      'out/measured-quick/measured-data.md with --quick)')
    parser.add_argument('--figures', help='directory of the figures (default: figures/ beside a quick document, '
                                          'research/doc/figures otherwise)')
    parser.add_argument('--quick', action='store_true',
                        help='smoke run: day 3 held out, one injected axis at one size, one phone axis')
    parser.add_argument('--max-effects', type=int, default=DEFAULT_MAX_EFFECTS)
    args = parser.parse_args(argv)
    doc = Path(args.doc or ('out/measured-quick/measured-data.md' if args.quick else 'research/doc/measured-data.md'))
    fig_dir = Path(args.figures or (doc.parent / 'figures' if args.quick or args.doc else 'research/doc/figures'))
    try:
        paths = fetch_records(args.data_dir)
    except DataUnavailable as e:
        print(f'measured: {e}', file=sys.stderr)
        return 2
    study = run_study(paths, QUICK if args.quick else FULL, args.max_effects)
    figs = write_figures(study, fig_dir, doc)
    doc.parent.mkdir(parents=True, exist_ok=True)
    doc.write_text(markdown(study, figs), encoding='utf-8')
    print(f'wrote {doc} and its figures in {fig_dir} ({study.cpu_s / 60:.1f} min of CPU)')
    return 0


if __name__ == '__main__':
    sys.exit(main())
