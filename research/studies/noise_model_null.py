"""What if the loop's chance knew the gyro's noise? The loop study's runs, chance from a still log's noise model.

``nice -n 10 .venv/bin/python research/studies/noise_model_null.py --loop-results build/loop-validation.json``
(about 10 minutes on two cores). The loop draws its chance from the residual itself
(phase-randomised, without the strongest candidate's fit: :func:`analysis.trace.null_spectrum`),
which holds any effect the residual carries: over one chamber cycle a small Shupe effect is then
as likely by chance as by cause (research/doc/oracle-power.md: "lost to the loop's chance"). A lab may
also have a long record of the gyro at rest. This experiment gives every case of
``research/studies/loop_validation.py`` such a record (``--still-hours`` more of the same gyro, table
still, chamber held at one temperature, its first hour dropped for the warm-up; every effect of
the case in it, as in any run of that gyro), fits a noise model to its Allan variance (white
noise, a sum of Gauss-Markov processes on a grid of correlation times and a rate random walk:
non-negative least squares on the relative Allan variance, each form's Allan variance being
linear in its power) and draws the loop's chance from that model (simulated in time, the random
walk from zero) instead of the residual. Everything else is the loop of ``calibrate fit`` and
the study's replay. It writes ``research/doc/noise-model-null.md`` and ``build/noise-model-null.json``.

An experiment, not a feature: it swaps the two functions of :mod:`analysis.trace` that make the
chance residuals.
"""

from __future__ import annotations

import os

os.environ.setdefault('OPENBLAS_NUM_THREADS', '1')   # the workers are the parallelism

import argparse  # noqa: E402
import json  # noqa: E402
import math  # noqa: E402
import multiprocessing  # noqa: E402
import time  # noqa: E402
from collections import defaultdict  # noqa: E402
from dataclasses import replace  # noqa: E402
from functools import partial  # noqa: E402
from pathlib import Path  # noqa: E402
from typing import Any  # noqa: E402

import numpy as np  # noqa: E402
from numpy.typing import NDArray  # noqa: E402
from scipy.optimize import nnls  # type: ignore[import-untyped]  # noqa: E402  # scipy ships no types
from scipy.signal import lfilter  # type: ignore[import-untyped]  # noqa: E402  # scipy ships no types

import loop_validation as lv  # noqa: E402
from art_gyro_calibration.analysis import trace  # noqa: E402
from art_gyro_calibration.analysis.allan import allan_deviation  # noqa: E402
from art_gyro_calibration.analysis.simulate import simulate_run  # noqa: E402
from art_gyro_calibration.calibration import load_packaged_calibration  # noqa: E402
from art_gyro_calibration.units import SECONDS_PER_HOUR  # noqa: E402

REPO = Path(__file__).resolve().parents[2]
# Correlation times of the Gauss-Markov grid (s): from the bias instability's minutes to the wander of hours.
GM_TAU_S = (10.0, 30.0, 100.0, 300.0, 1000.0, 3000.0, 10000.0, 30000.0)
BIN_S = 1.0   # the loop's bins (DEFAULT_BIN_S), each of RATE_HZ rows
# The cells: every effect at 0.25 and 0.5 on 2 h logs (where the loop misses), and drift x 0.25 on 6 h.
CELLS = [(effect, magnitude, 2.0) for effect in lv.ALL_EFFECTS for magnitude in (0.25, 0.5)] + [('drift', 0.25, 6.0)]


def gm_avar(tau_s: NDArray[np.float64], correlation_s: float) -> NDArray[np.float64]:
    """Allan variance of a unit-variance first-order Gauss-Markov process."""
    x = tau_s / correlation_s
    return 2.0 / x ** 2 * (x - 1.5 + 2.0 * np.exp(-x) - 0.5 * np.exp(-2.0 * x))


def noise_model(bin_means: NDArray[np.float64]) -> tuple[float, NDArray[np.float64], float]:
    """White variance per bin, Gauss-Markov variances (GM_TAU_S) and random-walk variance per bin, fitted."""
    allan = allan_deviation(bin_means, 1.0 / BIN_S, min_clusters=4)
    keep = allan.tau_s >= 2.0 * BIN_S   # the closed forms are of continuous time
    tau, avar = allan.tau_s[keep], allan.adev[keep] ** 2
    columns = np.column_stack([BIN_S / tau, *[gm_avar(tau, c) for c in GM_TAU_S], tau / (3.0 * BIN_S)])
    coefficients, _ = nnls(columns / avar[:, None], np.ones(len(avar)))
    return float(coefficients[0]), coefficients[1:-1], float(coefficients[-1])


def simulated_noise(model: tuple[float, NDArray[np.float64], float], n: int, count: int,
                    rng: np.random.Generator) -> NDArray[np.float64]:
    """``count`` series of ``n`` bins of the model's noise (deg/s), (n, count)."""
    white, gm, walk = model
    out = rng.normal(0.0, math.sqrt(white), (n, count))
    for correlation_s, variance in zip(GM_TAU_S, gm):
        if variance > 0.0:
            phi = math.exp(-BIN_S / correlation_s)
            drive = rng.normal(0.0, math.sqrt(variance * (1.0 - phi * phi)), (n, count))
            drive[0] = rng.normal(0.0, math.sqrt(variance), count)
            out += lfilter([1.0], [1.0, -phi], drive, axis=0)
    if walk > 0.0:
        out += np.cumsum(rng.normal(0.0, math.sqrt(walk), (n, count)), axis=0)
    return out


def still_record(case: lv.Case, still_hours: float) -> NDArray[np.float64]:
    """Bin means of the case's gyro at rest (deg/s), its first hour dropped, less its mean and supply column."""
    truth = load_packaged_calibration(lv.SERIAL)
    settings = replace(case.settings(), hours=still_hours + 1.0, seed=case.seed + 3_000_000,
                       hold_s=1e12, initial_rest_s=1e12)
    log = simulate_run(truth, settings).log(truth)
    per_bin = int(round(lv.RATE_HZ * BIN_S))
    first = int(SECONDS_PER_HOUR * lv.RATE_HZ)
    m = (len(log) - first) // per_bin
    means = log.rate_dps[first:first + m * per_bin].reshape(m, per_bin).mean(axis=1)
    supply = log.extras['supply_v'][first:first + m * per_bin].reshape(m, per_bin).mean(axis=1)
    basis = np.column_stack([np.ones(m), (supply - supply.mean()) / max(float(supply.std()), 1e-12)])
    residual: NDArray[np.float64] = means - basis @ np.linalg.lstsq(basis, means, rcond=None)[0]
    return residual


_MODEL: dict[str, tuple[float, NDArray[np.float64], float]] = {}


def _own_residual_spectrum(screen: Any, families: Any, residual: NDArray[np.float64],
                           held_out: Any) -> NDArray[np.complex128]:
    """Only its length matters here: the draws come from the model."""
    return trace.mirrored_spectrum(residual)


def _model_draws(spectrum: NDArray[np.complex128], count: int, rng: np.random.Generator) -> NDArray[np.float64]:
    """The chance residuals: the model's noise, weighted as the loop weights its bins (to one row's noise)."""
    return simulated_noise(_MODEL['model'], len(spectrum) - 1, count, rng) * math.sqrt(lv.RATE_HZ * BIN_S)


def run_case(case: lv.Case, still_hours: float) -> dict[str, Any]:
    """The loop study's case, its chance from the noise model of its gyro's still record."""
    _MODEL['model'] = noise_model(still_record(case, still_hours))
    trace.null_spectrum = _own_residual_spectrum
    trace.phase_surrogates = _model_draws
    return lv.run_case(case)


def _cells(results: list[dict[str, Any]]) -> dict[tuple[Any, ...], list[dict[str, Any]]]:
    groups: dict[tuple[Any, ...], list[dict[str, Any]]] = defaultdict(list)
    for r in results:
        groups[(r['effect'], r['magnitude'], r['hours'])].append(r)
    return groups


def document(results: list[dict[str, Any]], loop: list[dict[str, Any]], meta: dict[str, Any]) -> str:
    """The page: null runs and cells, this chance beside the loop's (the same runs)."""
    ours, theirs = _cells(results), _cells(loop)
    lines = ['# The loop with a noise model for its chance', '',
             'Generated by `nice -n 10 .venv/bin/python research/studies/noise_model_null.py` '
             f'at commit `{meta["commit"]}`; '
             f'{len(results)} runs, {meta["cpu_s"]:.0f} s of CPU; still record {meta["still_hours"]:g} h per run. '
             'See the script\'s docstring for the method. *Loop*: the loop\'s own chance (phase-randomised '
             f'residuals) on the same runs, from `{meta["loop_results"]}`.', '',
             '## Null runs', '',
             '| fit log | runs | effect claimed: noise model | loop | worsen a second run by > 1 deg/h: noise '
             'model | loop | largest worsening (deg/h): noise model | loop |',
             '|---|---:|---:|---:|---:|---:|---:|---:|']
    for hours in lv.HOURS:
        mine, base = ours.get((None, 0.0, hours), []), theirs.get((None, 0.0, hours), [])
        if not mine:
            continue
        base = [r for r in base if r['seed'] in {m['seed'] for m in mine}]
        rows = [lv._null_row('', group) for group in (mine, base)]
        harm = [sum(bool(r['found']) and lv.worsening_dph(r) > lv.MAX_WORSENING_DPH for r in group)
                for group in (mine, base)]
        lines.append(f'| {hours:g} h | {len(mine)} | {rows[0]["false_alarms"]} | {rows[1]["false_alarms"]} | '
                     f'{harm[0]} | {harm[1]} | {rows[0]["worsening_max_dph"]:.2f} | '
                     f'{rows[1]["worsening_max_dph"]:.2f} |')
    harmful = [r for r in results if r['effect'] is None and r['found'] and lv.worsening_dph(r) > lv.MAX_WORSENING_DPH]
    if harmful:
        lines += ['', 'Null runs whose claim worsens a second run by more than 1 deg/h (noise model): ' + '; '.join(
            f'seed {r["seed"]} ({r["hours"]:g} h): {", ".join(r["descriptions"])}, {lv.worsening_dph(r):.2f} deg/h'
            for r in harmful) + '.']
    lines += ['', '## Cells', '', 'Found: share of runs in which the effect was reported (as in the loop study). '
              'Ratio: median field error of the extended calibration over the oracle\'s (cold and warm runs).', '',
              '| effect | magnitude | fit log | runs | found: noise model | loop | ratio: noise model | loop |',
              '|---|---:|---:|---:|---:|---:|---:|---:|']
    met = {'noise model': 0, 'loop': 0}
    for key in CELLS:
        mine, base = ours.get(key, []), theirs.get(key, [])
        if not mine:
            continue
        cells = {name: lv._cell(*key, group) for name, group in (('noise model', mine), ('loop', base))}
        for name, cell in cells.items():
            met[name] += lv.at_target(cell)
        mine_cell, base_cell = cells['noise model'], cells['loop']
        lines.append(f'| {key[0]} | {key[1]:g} | {key[2]:g} h | {len(mine)} | {100 * mine_cell["detection"]:.0f}% | '
                     f'{100 * base_cell["detection"]:.0f}% | {mine_cell["ratio_extended_oracle"]:.2f} | '
                     f'{base_cell["ratio_extended_oracle"]:.2f} |')
    lines += ['', f'Cells at the loop study\'s target (found in at least {100 * lv.MIN_DETECTION_RATE:.0f}% of runs, '
              f'ratio at most {lv.MAX_ORACLE_RATIO:g}): noise model {met["noise model"]}, loop {met["loop"]} of '
              f'{len(CELLS)}.']
    return '\n'.join(lines) + '\n'


def main() -> int:
    """Run the experiment and write the page."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--loop-results', type=Path, required=True,
                        help='loop_validation.py\'s results (the same runs)')
    parser.add_argument('--null-runs', type=int, default=400, help='the loop study\'s first null runs')
    parser.add_argument('--reps', type=int, default=20, help='runs per cell')
    parser.add_argument('--still-hours', type=float, default=12.0, help='hours of the still record per run')
    parser.add_argument('--jobs', type=int, default=2)
    parser.add_argument('--doc', type=Path, default=REPO / 'research' / 'doc' / 'noise-model-null.md')
    parser.add_argument('--results', type=Path, default=REPO / 'build' / 'noise-model-null.json')
    parser.add_argument('--from-results', type=Path, help='rewrite the page from saved results')
    args = parser.parse_args()
    loop = json.loads(args.loop_results.read_text())
    loop = loop['results'] if isinstance(loop, dict) else loop
    if args.from_results:
        saved = json.loads(args.from_results.read_text())
        meta, results = saved['meta'], saved['results']
    else:
        nulls, power = lv.cases_for(400, args.reps)
        cases = nulls[:args.null_runs] + [c for c in power if (c.effect, c.magnitude, c.hours) in CELLS]
        start = time.process_time()
        with multiprocessing.get_context('fork').Pool(args.jobs) as pool:
            results = pool.map(partial(run_case, still_hours=args.still_hours), cases, chunksize=1)
        meta = {'commit': lv._commit(), 'still_hours': args.still_hours, 'loop_results': str(args.loop_results),
                'cpu_s': time.process_time() - start + sum(r['cpu_s'] for r in results)}
        args.results.parent.mkdir(parents=True, exist_ok=True)
        args.results.write_text(json.dumps({'meta': meta, 'results': results}) + '\n')
    args.doc.write_text(document(results, loop, meta))
    print(args.doc.read_text(), end='')
    return 0


if __name__ == '__main__':
    raise SystemExit(main())
