"""Benchmark: fit + trace (the whole loop) on a 24 h, 10 Hz simulated run (864,000 rows).

Reports wall and CPU time of the loop (the machine's load average beside them, as other
work on a shared machine slows the wall clock), the CPU time of ``calibrate fit``'s start-up
check, of the window terms' cost and of its comparison with the packaged calibration after them, and the
process's peak resident memory;
then the same runs written as CSV logs and fitted by the command itself (``calibrate fit``, a child process: every
step, the window terms' cost and the report included, figures not), its CPU time and peak memory. Run:
``python bench/bench_fit_trace.py [--hours 24] [--rate-hz 10]``; ``--runs 3 --hours 12``: a several-run fit of the
same ``--hours`` in all, cold starts of the gyro (its own turn-on bias, noise and table order each) and, last, a
warm restart (the lab protocol of doc/calibration.md). A benchmark, not a test.
"""

from __future__ import annotations

import argparse
import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from art_gyro_calibration.calibration import load_packaged_calibration
from art_gyro_calibration.analysis.baseline import compare_with_baseline
from art_gyro_calibration.analysis.loop import LoopOptions, close_loop
from art_gyro_calibration.analysis.replay import startup_check
from art_gyro_calibration.analysis.runs import joined
from art_gyro_calibration.analysis.simulate import (EFFECTS, SimulatedRun, SimulationSettings, same_gyro, simulate_run,
                                                    warm_restart, write_run)
from art_gyro_calibration.analysis.window_cost import window_cost
from art_gyro_calibration.static_bias import DEFAULT_SAMPLES
from art_gyro_calibration.units import SECONDS_PER_HOUR


def main() -> None:
    """Simulate, then time close_loop, the start-up check, the window cost and the baseline comparison."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--hours', type=float, default=24.0)
    parser.add_argument('--rate-hz', type=float, default=10.0)
    parser.add_argument('--serial', default='NAVC3545')
    parser.add_argument('--no-effects', action='store_true')
    parser.add_argument('--runs', type=int, default=1, help='runs of the gyro fitted together, the last a warm restart')
    args = parser.parse_args()
    cal = load_packaged_calibration(args.serial)
    effects = () if args.no_effects else tuple(EFFECTS)
    settings = SimulationSettings(hours=args.hours / args.runs, rate_hz=args.rate_hz, effects=effects)
    simulated: list[tuple[str, SimulatedRun, bool]] = [
        (f'cold{k + 1}', simulate_run(cal, same_gyro(settings, k)), True) for k in range(args.runs)]
    if args.runs > 1:   # the last a warm restart, an hour after its power-on
        simulated[-1] = ('warm', warm_restart(cal, same_gyro(settings, args.runs), SECONDS_PER_HOUR), False)
    log, fitted = joined([(name, run.log(cal), cold) for name, run, cold in simulated])
    start, cpu_start = time.perf_counter(), time.process_time()
    result = close_loop(log, cal.polynomial.rows, cal.polynomial.columns, LoopOptions(serial_number=args.serial),
                        fitted)
    elapsed, cpu = time.perf_counter() - start, time.process_time() - cpu_start
    check_cpu = time.process_time()
    checked, check, _ = startup_check(result, log)
    check_cpu = time.process_time() - check_cpu
    window_cpu = time.process_time()
    window = window_cost(checked, fitted, DEFAULT_SAMPLES)
    window_cpu = time.process_time() - window_cpu
    checked = window.result
    baseline_cpu = time.process_time()
    versus = compare_with_baseline(log, checked, checked.extended, cal, f'config/{args.serial}.yaml')
    baseline_cpu = time.process_time() - baseline_cpu
    peak_mib = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    print(f'rows {len(log)} in {len(fitted)} run(s), effects simulated: {", ".join(effects) or "none"}')
    print(f'effects found: {", ".join(e.term.describe() for e in result.effects) or "nothing"}')
    print(f'fit + trace: {elapsed:.2f} s wall, {cpu:.2f} s CPU (all threads), load average {os.getloadavg()[0]:.1f}; '
          f'peak RSS {peak_mib:.0f} MiB (whole process, simulation included)')
    dropped = ', '.join(d.term.signal for d in check.dropped) if check else 'no check'
    print(f'start-up check: {check_cpu:.2f} s CPU; dropped: {dropped or "nothing"}')
    not_written = ', '.join(c.signal for c in window.costs if not c.written)
    print(f'window terms\' cost: {window_cpu:.2f} s CPU; {len(window.costs)} judged, not written: '
          f'{not_written or "none"}')
    verdict = f'{versus.verdict} ({versus.refit_dph:.2f} against {versus.baseline_dph:.2f} deg/h)' if versus else 'none'
    print(f'baseline comparison: {baseline_cpu:.2f} s CPU; verdict: {verdict}')
    command(simulated, args.serial, cal.polynomial.rows, cal.polynomial.columns)


def command(simulated: list[tuple[str, SimulatedRun, bool]], serial: str, rows: int, columns: int) -> None:
    """``calibrate fit`` on the runs written as CSV logs, in a child process: its CPU time and peak memory."""
    with tempfile.TemporaryDirectory() as folder:
        logs, warm = [], []
        for name, run, cold in simulated:
            path = Path(folder) / f'{name}.csv'
            write_run(path, run)
            logs.append(str(path))
            warm += [] if cold else ['--warm-start', str(path)]
        before = resource.getrusage(resource.RUSAGE_CHILDREN)
        subprocess.run([sys.executable, '-m', 'art_gyro_calibration.analysis.cli', 'fit', *logs, *warm,
                        '--rows', str(rows), '--columns', str(columns), '--serial', serial,
                        '--out', str(Path(folder) / 'cal.yaml'), '--report', str(Path(folder) / 'REPORT.json')],
                       check=True, stdout=subprocess.DEVNULL)
        after = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = after.ru_utime + after.ru_stime - before.ru_utime - before.ru_stime
    print(f'calibrate fit (the command, from the CSV logs to the report): {cpu:.2f} s CPU; '
          f'peak RSS {after.ru_maxrss / 1024:.0f} MiB')


if __name__ == '__main__':
    main()
