"""What could any test find? Tests that know each effect's true form, on the loop study's runs.

``nice -n 10 .venv/bin/python research/studies/oracle_power.py`` (about 10 minutes on two cores) takes
the runs of ``research/studies/loop_validation.py`` (the same simulator, slow noise and seeds of its
cases, magnitudes from 0.25) and asks, for each effect x magnitude x log length, how often a test that knows the
effect's form (its time constant too) finds it at the loop's level (1 %). On the fitted log
the ART polynomial is fitted and the residual binned as :func:`analysis.loop.close_loop`
bins it; the true form alone is then scored by two statistics:

- **held out**: how much it lowers the error of blocks of time held out from the fit
  (``Screen.held_out_improvements``);
- **fitted**: how much it explains, fitted to all bins (``Screen.explained``);

each against two nulls:

- **the loop's chance**: 200 phase-randomised copies of the residual without the form's fit
  (``trace.null_spectrum``), as the loop draws them;
- **the exact null**: the same statistic of the same form on simulated runs without any
  effect (the test then also knows the noise model), its 99th percentile over ``--null-runs``
  runs per log length.

A cell the exact test misses is at the information limit of its statistic; one the loop
misses but the loop's-chance test finds is lost by the loop (its search over forms, its
maximum over candidates). It writes ``research/doc/oracle-power.md`` and ``build/oracle-power.json``;
with ``--loop-results`` (``build/loop-validation.json``) the loop's own share beside.
"""

from __future__ import annotations

import os

os.environ.setdefault('OPENBLAS_NUM_THREADS', '1')   # the workers are the parallelism

import argparse  # noqa: E402
import json  # noqa: E402
import multiprocessing  # noqa: E402
import resource  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402
from typing import Any  # noqa: E402

import numpy as np  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parent))
from loop_validation import HOURS, REPO, SERIAL, Case, _commit, cases_for, detected  # noqa: E402

from art_gyro_calibration.analysis.fit import TermSpec  # noqa: E402
from art_gyro_calibration.analysis.loop import LoopOptions, close_loop  # noqa: E402
from art_gyro_calibration.analysis.metrics import correlation_time_s  # noqa: E402
from art_gyro_calibration.analysis.simulate import COIL_LAG_TAU_S, EFFECTS, simulate_run  # noqa: E402
from art_gyro_calibration.analysis.trace import (DEFAULT_ALPHA, DEFAULT_BIN_S, DEFAULT_BLOCK_S,  # noqa: E402
                                                 DEFAULT_DRAWS, DEFAULT_FOLDS, SURROGATE_BATCH, Binned, Screen,
                                                 null_spectrum, phase_surrogates)
from art_gyro_calibration.calibration import load_packaged_calibration  # noqa: E402
from art_gyro_calibration.log import GyroLog  # noqa: E402
from art_gyro_calibration.signals import LAGGED_SIGNAL  # noqa: E402

# The simulator's effects this study measures (not shupe_true_rate, which came later and has no term form).
ALL_EFFECTS = ('shupe', 'warmup', 'supply_voltage', 'coil_lag', 'rate_t3', 'rate_temperature_rate', 'drift')
MAGNITUDES = (0.25, 0.5, 1.0)
STATISTICS = ('held_out', 'fitted')
TARGET_SHARE = 0.9   # the loop study's: found in 90 % of runs


def true_form(effect: str, rows: int, columns: int) -> TermSpec:
    """The term that is the simulated effect (for rate x T**3, the next temperature row's rate column)."""
    if effect in EFFECTS:
        signal, form, _, tau, _ = EFFECTS[effect]
        return TermSpec(signal, form, (1,) if form == 'power' else (), tau)
    return {'coil_lag': TermSpec(LAGGED_SIGNAL, 'power', tuple(range(1, rows)), COIL_LAG_TAU_S, tuple(range(columns))),
            'rate_t3': TermSpec('temperature', 'power', (rows,), rate_powers=(1,)),
            'rate_temperature_rate': TermSpec('temperature_rate', 'power', (1,), rate_powers=(1,)),
            'drift': TermSpec('time', 'power', (1,))}[effect]


def _statistics(screen: Screen, spec: TermSpec, targets: np.ndarray) -> dict[str, np.ndarray]:
    family = {'true': [spec]}
    return {'held_out': screen.held_out_improvements(family, targets)['true'],
            'fitted': screen.explained(family, targets)['true'][0]}


def first_screen(log: GyroLog, rows: int, columns: int, seed: int) -> Screen:
    """The loop's first screen: its ART fit and signals, bins, held-out blocks of the residual's correlation time."""
    art = close_loop(log, rows, columns, LoopOptions(max_effects=0, seed=seed))
    binned = Binned(art.signals, art.error, art.segments, rows, columns, DEFAULT_FOLDS, DEFAULT_BIN_S,
                    DEFAULT_BLOCK_S)
    residual = art.error - art.art.polynomial.error(log.rate_dps, log.temp_c)
    binned.refold(max(DEFAULT_BLOCK_S, correlation_time_s(log.t, residual, art.segments)))
    return Screen(binned)


def run_case(case: Case) -> dict[str, Any]:
    """The true forms' statistics on one run: every form's on a null run, its own form's and p-values on another."""
    truth = load_packaged_calibration(SERIAL)
    rows, columns = truth.polynomial.rows, truth.polynomial.columns
    log = simulate_run(truth, case.settings()).log(truth)
    screen = first_screen(log, rows, columns, case.seed)
    residual = screen.residual()
    out: dict[str, Any] = {'effect': case.effect, 'magnitude': case.magnitude, 'hours': case.hours,
                           'seed': case.seed, 'statistics': {}, 'p_values': {}}
    for effect in [case.effect] if case.effect else ALL_EFFECTS:
        spec = true_form(effect, rows, columns)
        real = _statistics(screen, spec, residual[:, None])
        out['statistics'][effect] = {k: float(v[0]) for k, v in real.items()}
    if case.effect:
        spec = true_form(case.effect, rows, columns)
        held = {'true': out['statistics'][case.effect]['held_out']}
        spectrum = null_spectrum(screen, {'true': [spec]}, residual, held)
        rng = np.random.default_rng(case.seed)
        chance: dict[str, list[np.ndarray]] = {k: [] for k in STATISTICS}
        for _ in range(0, DEFAULT_DRAWS, SURROGATE_BATCH):
            for k, v in _statistics(screen, spec, phase_surrogates(spectrum, SURROGATE_BATCH, rng)[:len(residual)]
                                    ).items():
                chance[k].append(v)
        out['p_values'] = {k: float((1 + np.sum(np.concatenate(v) >= out['statistics'][case.effect][k]))
                                    / (DEFAULT_DRAWS + 1)) for k, v in chance.items()}
    return out


def summarise(results: list[dict[str, Any]], loop: list[dict[str, Any]] | None) -> list[dict[str, Any]]:
    """Per cell: the share found by each statistic against each null (and by the loop, if given)."""
    nulls = [r for r in results if r['effect'] is None]
    cells = []
    for effect in ALL_EFFECTS:
        for magnitude in MAGNITUDES:
            for hours in HOURS:
                key = (effect, magnitude, hours)
                group = [r for r in results if (r['effect'], r['magnitude'], r['hours']) == key]
                if not group:
                    continue
                cell: dict[str, Any] = {'effect': effect, 'magnitude': magnitude, 'hours': hours, 'runs': len(group)}
                for k in STATISTICS:
                    exact = np.quantile([r['statistics'][effect][k] for r in nulls if r['hours'] == hours],
                                        1.0 - DEFAULT_ALPHA, method='higher')
                    cell[f'{k}_chance'] = float(np.mean([r['p_values'][k] <= DEFAULT_ALPHA for r in group]))
                    cell[f'{k}_exact'] = float(np.mean([r['statistics'][effect][k] > exact for r in group]))
                mine = [r for r in loop or [] if (r['effect'], r['magnitude'], r['hours']) == key]
                cell['loop'] = float(np.mean([detected(r) for r in mine])) if mine else None
                cells.append(cell)
    return cells


def document(cells: list[dict[str, Any]], meta: dict[str, Any]) -> str:
    """The Markdown page."""
    lines = ['# What a test that knows the form finds', '',
             'Generated by `nice -n 10 .venv/bin/python research/studies/oracle_power.py` '
             f'at commit `{meta["commit"]}`; '
             f'{meta["null_runs"]} null runs per log length, {meta["reps"]} runs per cell, {meta["cpu_s"]:.0f} s of '
             'CPU. The runs are those of `research/studies/loop_validation.py` (its simulator, slow noise and cases); '
             'see '
             'the script\'s docstring for the method.', '',
             f'Share of runs in which the true form alone is found at the {DEFAULT_ALPHA:.0%} level: scored held out '
             'or fitted to all bins, against the loop\'s chance (phase-randomised residuals) or the exact null '
             '(its 99th percentile over runs without an effect). *Loop*: the share the loop found in '
             f'{meta["loop_source"]}.', '',
             '| effect | magnitude | fit log | runs | held out, loop\'s chance | held out, exact null | '
             'fitted, loop\'s chance | fitted, exact null | loop |', '|---|---:|---:|---:|---:|---:|---:|---:|---:|']
    for c in cells:
        loop = '' if c['loop'] is None else f'{c["loop"]:.0%}'
        lines.append(f'| {c["effect"]} | {c["magnitude"]:g} | {c["hours"]:g} h | {c["runs"]} | '
                     + ' | '.join(f'{c[f"{k}_{n}"]:.0%}' for k in STATISTICS for n in ('chance', 'exact'))
                     + f' | {loop} |')

    def named(group: list[dict[str, Any]]) -> str:
        return '; '.join(f'{c["effect"]} x {c["magnitude"]:g} on {c["hours"]:g} h' for c in group) or 'none'

    best = [max(c[f'{k}_{n}'] for k in STATISTICS for n in ('chance', 'exact')) for c in cells]
    limit = [c for c, b in zip(cells, best) if b < TARGET_SHARE]
    chance = [c for c in cells if c['fitted_chance'] < TARGET_SHARE <= max(c['fitted_exact'], c['held_out_exact'])]
    lost = [c for c in cells if c['loop'] is not None and c['loop'] < TARGET_SHARE <= c['fitted_chance']]
    lines += ['', '## Reading', '',
              f'- **Beyond any of these tests** (none finds the effect in {TARGET_SHARE:.0%} of runs, the loop '
              f'study\'s target): {named(limit)}. A loop that searches among forms cannot do better at this level.',
              f'- **Lost to the loop\'s chance** (the exact null finds it, the phase-randomised residuals do not: the '
              f'price of not knowing the noise model): {named(chance)}.',
              f'- **Lost by the loop** (the true form alone, fitted, beats the loop\'s chance; the loop, searching '
              f'over every form and taking the best chance score of all, does not): {named(lost)}.']
    return '\n'.join(lines) + '\n'


def _loop_source(path: Path | None, loop: dict[str, Any] | None) -> str:
    return f'`{path.name}` (commit {loop["meta"]["commit"]}, the same runs)' if path and loop else '(not given)'


def main() -> int:
    """Run the tests and write the page."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--null-runs', type=int, default=200, help='null runs per log length')
    parser.add_argument('--reps', type=int, default=20, help='runs per effect x magnitude x log length')
    parser.add_argument('--jobs', type=int, default=2)
    parser.add_argument('--loop-results', type=Path, help='loop_validation.py\'s results, for the loop\'s share')
    parser.add_argument('--doc', type=Path, default=REPO / 'research' / 'doc' / 'oracle-power.md')
    parser.add_argument('--results', type=Path, default=REPO / 'build' / 'oracle-power.json')
    parser.add_argument('--from-results', type=Path, help='rewrite the page from saved results')
    args = parser.parse_args()
    if args.from_results:
        saved = json.loads(args.from_results.read_text(encoding='utf-8'))
        loop = json.loads(args.loop_results.read_text(encoding='utf-8')) if args.loop_results else None
        cells = summarise(saved['results'], loop['results'] if loop else None)
        meta = {**saved['meta'], 'loop_source': _loop_source(args.loop_results, loop)}
        args.doc.write_text(document(cells, meta), encoding='utf-8')
        return 0
    commit, start = _commit(), time.time()
    # The loop study's runs (its seeds), and null runs of seeds of their own.
    cases = [Case(None, 0.0, h, 900_000 + 1000 * k + i) for k, h in enumerate(HOURS) for i in range(args.null_runs)]
    cases += [c for c in cases_for(0, args.reps)[1] if c.magnitude in MAGNITUDES]
    with multiprocessing.get_context('fork').Pool(args.jobs) as pool:
        results = pool.map(run_case, cases, chunksize=4)
    cpu = sum(getattr(resource.getrusage(who), k) for who in (resource.RUSAGE_SELF, resource.RUSAGE_CHILDREN)
              for k in ('ru_utime', 'ru_stime'))
    loop = json.loads(args.loop_results.read_text(encoding='utf-8')) if args.loop_results else None
    cells = summarise(results, loop['results'] if loop else None)
    meta = {'commit': commit, 'null_runs': args.null_runs, 'reps': args.reps, 'cpu_s': cpu,
            'wall_s': time.time() - start,
            'loop_source': _loop_source(args.loop_results, loop)}
    args.results.parent.mkdir(parents=True, exist_ok=True)
    args.results.write_text(json.dumps({'meta': meta, 'cells': cells, 'results': results}, indent=1) + '\n',
                            encoding='utf-8')
    args.doc.write_text(document(cells, meta), encoding='utf-8')
    print(f'{args.doc}; {args.results}')
    return 0


if __name__ == '__main__':
    raise SystemExit(main())
