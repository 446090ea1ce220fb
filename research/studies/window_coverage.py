"""Does a window term's implied mission bias cover the error it makes? (issue 35, item 2), from a field check's output.

``.venv/bin/python research/studies/window_coverage.py [--field-check out/field-check]`` reads what
``research/studies/field_check.py`` left (``results.json``, and per fit ``REPORT.json`` and the written file) and
writes ``research/doc/window-coverage.md``. It imports nothing of the package.

For every fit of a case whose gyro has a Shupe term (the field check's ``shupe_k``, on the true temperature rate)
that wrote a linear temperature-rate term: ``REPORT.json``'s ``window_terms`` give the term's value in the static-bias
window (``window_dph``, at the coefficient the window cost fitted, named in its description) and its implied mission
bias (``implied_bias_dph``, the 1-sigma the report states). The window's temperature rate is ``window_dph`` over that
coefficient; the written file's error there is that rate times (written coefficient - true ``shupe_k``): a bias every
cold start of the node carries for the whole mission. ``z`` = |error| / implied bias: for a 1-sigma that holds,
|z| > 2 in about 5 % of fits and the median |z| is about 0.67.
"""

from __future__ import annotations

import argparse
import json
import re
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray
import yaml

REPO = Path(__file__).resolve().parents[2]
DOC = REPO / 'research' / 'doc' / 'window-coverage.md'
LABELS = {'loop_6h': 'one 6 h run', 'loop_multi': 'the lab protocol (several runs)'}
FITTED = re.compile(r'^power \[1\] of temperature_rate: \[([-+0-9.e]+)\]$')


def written_rate_coefficient(path: Path) -> float | None:
    """The written file's linear temperature-rate coefficient (None: no such term, or not linear alone)."""
    p = yaml.safe_load(path.read_text())['/**']['ros__parameters']
    term = (p.get('extended') or {}).get('temperature_rate')
    if not term or term.get('form') != 'power' or list(term.get('powers', [])) != [1]:
        return None
    return float(term['coefficients'][0])


def rows(out: Path) -> tuple[list[dict[str, Any]], list[str]]:
    """One row per fit that wrote a linear temperature-rate term of a Shupe case; and the fits left out, why."""
    results = json.loads((out / 'results.json').read_text())['results']
    found, skipped = [], []
    for r in results:
        k_true = float(r['physics'].get('shupe_k', 0.0))
        if k_true == 0.0:
            continue
        for label in LABELS:
            run = out / f'{r["case"]}-{r["rep"]}'
            report = run / f'{label}-REPORT.json'
            if not report.exists():
                continue
            name = f'{r["case"]} run {r["rep"]}, {LABELS[label]}'
            k_written = written_rate_coefficient(run / f'{label}.yaml')
            terms = [t for t in (json.loads(report.read_text()).get('window_terms') or {}).get('terms', [])
                     if t['signal'] == 'temperature_rate' and t['written']]
            fitted = FITTED.match(terms[0]['description']) if terms else None
            if k_written is None or fitted is None:
                skipped.append(f'{name}: no linear temperature-rate term written alone'
                               if k_written is None else f'{name}: the window cost fitted another form')
                continue
            window_rate = terms[0]['window_dph'] / float(fitted.group(1))   # deg/h per unit coefficient
            error = window_rate * (k_written - k_true)
            found.append({'case': r['case'], 'rep': r['rep'], 'fit': label, 'k_true': k_true,
                          'k_written': k_written, 'window_dph': window_rate * k_written, 'error_dph': error,
                          'implied_dph': terms[0]['implied_bias_dph'],
                          'z': abs(error) / terms[0]['implied_bias_dph'],
                          'warm_up': float(r['physics'].get('warmup_dph', 0.0)) > 0.0})
    return found, skipped


def _z(found: list[dict[str, Any]], fit: str) -> NDArray[np.float64]:
    """The z of every row of the fit ``fit``."""
    return np.array([f['z'] for f in found if f['fit'] == fit])


def summary(found: list[dict[str, Any]], fit: str) -> str:
    """One table row: how often the error exceeds twice the implied bias, and the median and rms of z."""
    z = _z(found, fit)
    if not z.size:
        return f'| {LABELS[fit]} | 0 | | | |'
    return (f'| {LABELS[fit]} | {z.size} | {np.mean(z > 2.0) * 100:.0f} % ({int(np.sum(z > 2.0))}) | '
            f'{np.median(z):.2f} | {np.sqrt(np.mean(z ** 2)):.2f} |')


def reading(found: list[dict[str, Any]]) -> list[str]:
    """What the summary says, a sentence per fit: the rms of z is the factor the implied bias understates by."""
    out = []
    for fit, name in LABELS.items():
        z = _z(found, fit)
        if z.size:
            verdict = ('covers the error' if np.mean(z > 2.0) <= 0.1 and np.sqrt(np.mean(z ** 2)) <= 1.5 else
                       f'understates the error: by about {np.sqrt(np.mean(z ** 2)):.1f} x in rms')
            out.append(f'- {name.capitalize()}: the implied mission bias {verdict} ({np.sum(z > 2.0)} of {z.size} '
                       f'fits beyond twice it, worst z {z.max():.1f}).')
    return out


def document(found: list[dict[str, Any]], skipped: list[str], out: Path, commit: str) -> str:
    """The report."""
    lines = ['# Window terms: does the implied mission bias cover the error the written coefficient makes?', '',
             f'Generated by `research/studies/window_coverage.py --field-check {out}` from the field check at commit '
             f'{commit} (`research/doc/field-check.md`); see the script\'s docstring for the method. The Shupe '
             'cases only: their true coefficient is known, so the written coefficient\'s error in the window is '
             '(written - true) times the window\'s temperature rate, a bias every cold start carries for the whole '
             'mission. `z` = |that error| / the implied mission bias REPORT.json states.', '',
             '| fit | fits | error > 2 x implied (expected about 5 %) | median z (expected about 0.67) | rms z '
             '(expected 1) |', '|---|---:|---:|---:|---:|',
             *(summary(found, fit) for fit in LABELS), '', *reading(found), '',
             '| case | run | fit | true | written | in the window (deg/h) | error (deg/h) | implied (deg/h) | z | '
             'a warm-up beside |', '|---|---:|---|---:|---:|---:|---:|---:|---:|---|']
    for f in found:
        lines.append(f'| {f["case"]} | {f["rep"]} | {LABELS[f["fit"]]} | {f["k_true"]:g} | {f["k_written"]:.3f} | '
                     f'{f["window_dph"]:.2f} | {f["error_dph"]:+.2f} | {f["implied_dph"]:.2f} | '
                     f'{f["z"]:.2f} | {"yes" if f["warm_up"] else ""} |')
    if skipped:
        lines += ['', 'Left out: ' + '; '.join(skipped) + '.']
    return '\n'.join(lines) + '\n'


def main() -> int:
    """Read the field check's output, write the report."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--field-check', type=Path, default=Path('out/field-check'))
    args = parser.parse_args()
    out = args.field_check
    meta = json.loads((out / 'results.json').read_text()).get('meta', {})
    found, skipped = rows(out)
    DOC.write_text(document(found, skipped, out, str(meta.get('commit', 'unknown'))))
    print(f'wrote {DOC}: {len(found)} fits, {len(skipped)} left out')
    return 0


if __name__ == '__main__':
    raise SystemExit(main())
