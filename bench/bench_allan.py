"""Benchmark: ``calibrate allan``'s overlapping Allan deviation against allantools, and its memory on a day at 1 kHz.

- ``speed``: the same record (white noise, a rate random walk, a bias) in memory, timed in one
  run through ``allantools.oadev(data_type='freq', taus='octave')`` and through
  :class:`~art_gyro_calibration.analysis.allan.AllanAccumulator` (fed in chunks of 65,536, as
  ``calibrate allan`` feeds it); the ratio of their times and the largest relative difference.
- ``memory``: a node-style raw log of ``--hours`` at ``--rate-hz`` (a still gyro, counts),
  written in bounded memory, then ``calibrate allan`` on it as a child process: wall and
  CPU time, and its peak resident memory (``ru_maxrss`` from ``wait4``), its address space
  capped at ``--cap-gib``.

``python bench/bench_allan.py speed --samples 1e6 8.64e6 3e7``
``python bench/bench_allan.py memory --hours 24 --rate-hz 1000``

Prints markdown table rows. A benchmark, not a test.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from art_gyro_calibration.analysis.allan import AllanAccumulator
from art_gyro_calibration.analysis.csv_writer import CsvWriter
from art_gyro_calibration.units import SECONDS_PER_HOUR

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_offline import run_child  # noqa: E402

RATE_SCALE = 0.00305   # deg/s per count of the raw log


def record(n: int, seed: int = 0) -> np.ndarray:
    """A still gyro's rate, deg/s: a bias, white noise and a rate random walk."""
    rng = np.random.default_rng(seed)
    return 0.004 + rng.normal(0.0, 0.03, n) + np.cumsum(rng.normal(0.0, 1e-6, n))


def ours(x: np.ndarray, fs: float) -> tuple[np.ndarray, np.ndarray]:
    with AllanAccumulator() as acc:
        for start in range(0, len(x), 1 << 16):
            acc.add(x[start:start + (1 << 16)])
        result = acc.result(fs)
    return np.rint(result.tau_s * fs), result.adev


def bench_speed(args: argparse.Namespace) -> None:
    import allantools  # type: ignore[import-untyped]  # allantools ships no type hints
    fs = 1000.0
    print('| samples | allantools.oadev s | calibrate allan (AllanAccumulator) s | speed ratio | taus compared '
          '| largest relative difference |')
    print('|---:|---:|---:|---:|---:|---:|')
    for n in (int(float(v)) for v in args.samples):
        x = record(n)
        start = time.perf_counter()
        taus, expected, _, _ = allantools.oadev(x, rate=fs, data_type='freq', taus='octave')
        theirs_s = time.perf_counter() - start
        start = time.perf_counter()
        m, adev = ours(x, fs)
        ours_s = time.perf_counter() - start
        common = np.intersect1d(m, np.rint(taus * fs))
        a = adev[np.isin(m, common)]
        b = expected[np.isin(np.rint(taus * fs), common)]
        print(f'| {n:,} | {theirs_s:.2f} | {ours_s:.2f} | {theirs_s / ours_s:.1f} x | {len(common)} of '
              f'{len(m)} | {np.max(np.abs(a / b - 1)):.1e} |', flush=True)


def write_still_log(path: Path, hours: float, rate_hz: float, chunk_s: float = 600.0) -> int:
    """A raw log of a still gyro (counts), chunk by chunk; returns its rows."""
    rng = np.random.default_rng(1)
    rows = int(round(hours * SECONDS_PER_HOUR * rate_hz))
    step = int(chunk_s * rate_hz)
    walk = 0.0
    with open(path, 'wb') as stream:
        writer = CsvWriter(stream, ('t', 'raw_rate', 'raw_temp'))
        for start in range(0, rows, step):
            k = np.arange(start, min(rows, start + step))
            wander = walk + np.cumsum(rng.normal(0.0, 1e-6, k.size))
            walk = float(wander[-1])
            rate = 0.004 + wander + rng.normal(0.0, 0.03, k.size)
            writer.write({'t': 1.7e9 + k / rate_hz, 'raw_rate': np.round(rate / RATE_SCALE),
                          'raw_temp': np.full(k.size, 500.0)})
    return rows


def bench_memory(args: argparse.Namespace) -> None:
    print('| record | rows | CSV MB | write s | calibrate allan wall s | CPU s | peak RSS MiB |')
    print('|---|---:|---:|---:|---:|---:|---:|')
    with tempfile.TemporaryDirectory(prefix='bench-allan-', dir=args.work) as work:
        for hours in args.hours:
            for rate_hz in args.rate_hz:
                log = Path(work) / 'still.csv'
                start = time.perf_counter()
                rows = write_still_log(log, hours, rate_hz)
                written = time.perf_counter() - start
                run = run_child(['allan', str(log), '--rate-scale-factor', str(RATE_SCALE), '--node-rate-hz', '100',
                                 '--out', str(Path(work) / 'ALLAN.json'), '--force'], args.cap_gib)
                size = log.stat().st_size / 1e6
                ok = '' if run.status == 0 else f' (exit {run.status}: {run.stderr.strip()[-300:]})'
                print(f'| {hours:g} h x {rate_hz:g} Hz | {rows:,} | {size:,.0f} | {written:.0f} | {run.wall_s:.1f} | '
                      f'{run.cpu_s:.1f} | {run.peak_mib:,.0f}{ok} |', flush=True)
                log.unlink()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest='mode', required=True)
    p = sub.add_parser('speed')
    p.add_argument('--samples', nargs='+', default=['1e6', '8.64e6'])
    p.set_defaults(run=bench_speed)
    p = sub.add_parser('memory')
    p.add_argument('--hours', type=float, nargs='+', default=[24.0])
    p.add_argument('--rate-hz', type=float, nargs='+', default=[1000.0])
    p.add_argument('--cap-gib', type=float, default=4.0)
    p.add_argument('--work', help='directory for the log (default: the system\'s temporary directory)')
    p.set_defaults(run=bench_memory)
    args = parser.parse_args()
    args.run(args)


if __name__ == '__main__':
    main()
