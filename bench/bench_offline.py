"""Benchmark: wall time and peak memory of ``calibrate apply`` and ``calibrate fit`` against the log's length.

Each command runs as a child process (``python -m art_gyro_calibration ...``, as a user
runs it); its peak resident memory is the ``ru_maxrss`` that ``wait4`` reports for it, and
its address space is capped (``--cap-gib``) so that a run cannot exhaust a shared machine.

- ``apply``: node-style raw logs (epoch seconds, counts) of ``--hours`` x ``--rate-hz``,
  written by a generator in bounded memory, then ``calibrate apply`` with a calibration
  that has extended terms (so the causal signals are computed too).
- ``fit``: ``calibrate simulate`` (three effects), then ``calibrate fit --rows 3 --columns 4``;
  sizes in increasing order, each skipped when the memory growth measured so far
  extrapolates beyond ``--max-gib``.

``python bench/bench_offline.py apply --hours 24 96 --rate-hz 10 100``
``python bench/bench_offline.py fit --runs 6:10 24:10 48:10 96:10 24:100``

Prints one markdown table row per run. A benchmark, not a test.
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import resource
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from art_gyro_calibration.calibration import load_packaged_calibration, write_calibration
from art_gyro_calibration.analysis.csv_writer import CsvWriter
from art_gyro_calibration.terms import Term
from art_gyro_calibration.units import SECONDS_PER_HOUR

SERIAL = 'NAVC3545'
GIB = 1 << 30


@dataclasses.dataclass(frozen=True)
class Run:
    """One child process: wall time, peak resident memory, exit status, and what it printed on stderr."""

    wall_s: float
    cpu_s: float      # user + system time of the child
    peak_mib: float
    status: int
    stderr: str


def run_child(args: list[str], cap_gib: float) -> Run:
    """``python -m art_gyro_calibration ARGS`` with its address space capped; its own ru_maxrss."""
    cap = int(cap_gib * GIB)
    env = {k: v for k, v in os.environ.items() if k != '_ROS_WHEELS_BOOTSTRAP_COMPLETE'}

    def limit() -> None:
        resource.setrlimit(resource.RLIMIT_AS, (cap, cap))
    start = time.perf_counter()
    proc = subprocess.Popen([sys.executable, '-m', 'art_gyro_calibration', *args], stdout=subprocess.DEVNULL,
                            stderr=subprocess.PIPE, preexec_fn=limit, env=env)
    stderr = proc.stderr.read().decode(errors='replace') if proc.stderr else ''
    _, status, usage = os.wait4(proc.pid, 0)
    wall = time.perf_counter() - start
    proc.returncode = os.waitstatus_to_exitcode(status)
    return Run(wall, usage.ru_utime + usage.ru_stime, usage.ru_maxrss / 1024, proc.returncode, stderr)


def write_raw_log(path: Path, hours: float, rate_hz: float, chunk_s: float = SECONDS_PER_HOUR) -> int:
    """A node-style raw log: a still minute, then rate-table steps while the temperature ramps; returns its rows."""
    cal = load_packaged_calibration(SERIAL)
    rng = np.random.default_rng(1)
    rows = int(round(hours * SECONDS_PER_HOUR * rate_hz))
    step = int(chunk_s * rate_hz)
    t0 = 1.7e9
    with open(path, 'wb') as stream:
        writer = CsvWriter(stream, ('t', 'raw_rate', 'raw_temp'))
        for start in range(0, rows, step):
            k = np.arange(start, min(rows, start + step))
            t = k / rate_hz
            table = np.where(t < 60, 0.0, 20.0 * ((t // 120) % 9 - 4))   # -80..80 deg/s, 2 min each
            temp = 25.0 + 15.0 * np.sin(2 * np.pi * t / 21600)
            rate = table + rng.normal(0, 0.005 * np.sqrt(rate_hz / 10), k.size)
            writer.write({'t': t0 + t + rng.uniform(0, 0.1 / rate_hz, k.size),
                          'raw_rate': np.round(rate / cal.rate_scale_factor),
                          'raw_temp': np.round(temp / cal.temp_scale_factor)})
    return rows


def bench_apply(args: argparse.Namespace, work: Path) -> None:
    cal = dataclasses.replace(load_packaged_calibration(SERIAL), terms=(
        Term('temperature_rate', 'power', (0.24,), (1,)), Term('time', 'exp_decay', (0.02,), (), 1200.0)))
    write_calibration(work / 'CAL.yaml', cal)
    # The fixed cost of starting Python and importing the tools, taken off for the rate.
    startup = min((run_child(['apply', '--help'], args.cap_gib) for _ in range(3)), key=lambda r: r.cpu_s)
    print(f'start-up (`calibrate apply --help`): {startup.wall_s:.2f} s wall, {startup.cpu_s:.2f} s CPU, '
          f'{startup.peak_mib:.0f} MiB\n')
    print('| log | rows | CSV MB | apply wall s | apply CPU s | rows per CPU s after start-up | peak RSS MiB |')
    print('|---|---:|---:|---:|---:|---:|---:|')
    for hours in args.hours:
        for rate_hz in args.rate_hz:
            log = work / f'raw-{hours:g}h-{rate_hz:g}hz.csv'
            rows = write_raw_log(log, hours, rate_hz)
            run = run_child(['apply', str(log), '--calibration', str(work / 'CAL.yaml'),
                             '--out', str(work / 'out.csv'), '--force'], args.cap_gib)
            size = log.stat().st_size / 1e6
            log.unlink()
            (work / 'out.csv').unlink(missing_ok=True)
            ok = '' if run.status == 0 else f' (exit {run.status}: {run.stderr.strip()[-200:]})'
            print(f'| {hours:g} h x {rate_hz:g} Hz | {rows:,} | {size:,.0f} | {run.wall_s:.1f} | {run.cpu_s:.1f} | '
                  f'{rows / (run.cpu_s - startup.cpu_s):,.0f} | {run.peak_mib:,.0f}{ok} |', flush=True)


def peak_line(measured: list[tuple[int, float]]) -> tuple[float, float]:
    """The least-squares line through (rows, peak MiB): its slope (MiB per row) and intercept (MiB)."""
    rows, peaks = np.array(measured).T
    slope, intercept = np.polyfit(rows, peaks, 1)
    return float(slope), float(intercept)


def bench_fit(args: argparse.Namespace, work: Path) -> None:
    print('| log | rows | simulate wall s | simulate peak MiB | fit wall s | fit CPU s | fit peak MiB | '
          'fit MiB per M rows |')
    print('|---|---:|---:|---:|---:|---:|---:|---:|')
    measured: list[tuple[int, float]] = []
    for spec in args.runs:
        hours, rate_hz = (float(v) for v in spec.split(':'))
        rows = int(round(hours * SECONDS_PER_HOUR * rate_hz))
        if len(measured) >= 2:
            slope, intercept = peak_line(measured)
            expected = (slope * rows + intercept) / 1024
            if expected > args.max_gib:
                print(f'| {hours:g} h x {rate_hz:g} Hz | {rows:,} | | | skipped | | {expected:.1f} GiB expected | |')
                continue
        log = work / 'sim.csv'
        sim = run_child(['simulate', '--serial', SERIAL, '--hours', f'{hours:g}', '--rate-hz', f'{rate_hz:g}',
                         '--effect', 'shupe', '--effect', 'warmup', '--effect', 'supply_voltage', '--seed', '1',
                         '--out', str(log), '--force'], args.cap_gib)
        if sim.status != 0:
            print(f'| {hours:g} h x {rate_hz:g} Hz | {rows:,} | {sim.wall_s:.1f} | {sim.peak_mib:,.0f} | '
                  f'simulate failed: {sim.stderr.strip()[-200:]} | | | |', flush=True)
            continue
        fit = run_child(['fit', str(log), '--rows', '3', '--columns', '4', '--serial', SERIAL, '--force',
                         '--out', str(work / 'CAL.yaml'), '--report', str(work / 'REPORT.json')], args.cap_gib)
        ok = '' if fit.status == 0 else f' (exit {fit.status}: {fit.stderr.strip()[-200:]})'
        if fit.status == 0:
            measured.append((rows, fit.peak_mib))
        print(f'| {hours:g} h x {rate_hz:g} Hz | {rows:,} | {sim.wall_s:.1f} | {sim.peak_mib:,.0f} | '
              f'{fit.wall_s:.1f} | {fit.cpu_s:.1f} | {fit.peak_mib:,.0f}{ok} | {fit.peak_mib / rows * 1e6:,.0f} |',
              flush=True)
    if len(measured) >= 2:
        slope, intercept = peak_line(measured)
        print(f'\nfit peak memory ~ {intercept:.0f} MiB + {slope * 1e6:.0f} MiB per million rows '
              f'(least squares over {len(measured)} runs)')


def main() -> None:
    """Run the chosen benchmark."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest='command', required=True)
    p = sub.add_parser('apply')
    p.add_argument('--hours', type=float, nargs='+', default=[24.0, 96.0])
    p.add_argument('--rate-hz', type=float, nargs='+', default=[10.0, 100.0])
    p = sub.add_parser('fit')
    p.add_argument('--runs', nargs='+', default=['6:10', '24:10', '48:10', '96:10', '24:100'],
                   help='hours:rate_hz of each run, smallest first')
    p.add_argument('--max-gib', type=float, default=8.0, help='skip a run whose fit is expected to need more')
    for p in sub.choices.values():
        p.add_argument('--cap-gib', type=float, default=10.0, help='address space cap of each child process')
        p.add_argument('--dir', help='where to write the logs (default: a temporary directory, removed)')
    args = parser.parse_args()
    work = Path(args.dir) if args.dir else Path(tempfile.mkdtemp(prefix='bench-offline-'))
    work.mkdir(parents=True, exist_ok=True)
    print(f'{time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime())}, load average {os.getloadavg()[0]:.1f}, '
          f'{os.cpu_count()} cores\n')
    try:
        (bench_apply if args.command == 'apply' else bench_fit)(args, work)
    finally:
        if not args.dir:
            shutil.rmtree(work, ignore_errors=True)
    print(f'\nload average at the end {os.getloadavg()[0]:.1f}')


if __name__ == '__main__':
    main()
