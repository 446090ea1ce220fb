"""Benchmark: ``calibrate apply``'s compensation against the report's C program (gcc -O2), one run.

Both get the same raw samples of a gyro; the C program (test/c/art_reference.c, a straight
transcription of the report) times its own loop, the Python side times apply_calibration
(static bias plus compensation over the arrays). Prints the ratio; the goal is <= 2.
Usage: python bench/bench_apply_vs_c.py [--samples 10000000] [--serial NAVC3545]
"""

from __future__ import annotations

import argparse
import shutil
import subprocess
import tempfile
import time
from pathlib import Path

import numpy as np

from art_gyro_calibration.calibration import load_packaged_calibration
from art_gyro_calibration.compensation import apply_calibration
from art_gyro_calibration.log import GyroLog

C_SOURCE = Path(__file__).resolve().parent.parent / 'test' / 'c' / 'art_reference.c'


def main() -> None:
    """Run both and print a table row."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--samples', type=int, default=10_000_000)
    parser.add_argument('--serial', default='NAVC3545')
    parser.add_argument('--bias-samples', type=int, default=100)
    args = parser.parse_args()
    cal = load_packaged_calibration(args.serial)
    rng = np.random.default_rng(0)
    n, nb = args.samples, args.bias_samples
    raw_rate = np.concatenate([rng.integers(-3, 4, nb), rng.integers(-32000, 32000, n - nb)]).astype(np.int32)
    raw_temp = rng.integers(200, 1000, n).astype(np.int32)

    with tempfile.TemporaryDirectory() as tmp:
        d = Path(tmp)
        exe = d / 'art_reference'
        subprocess.run([shutil.which('gcc') or 'gcc', '-O2', '-o', str(exe), str(C_SOURCE), '-lm'], check=True)
        (d / 'params.txt').write_text(f'{cal.rate_scale_factor!r} {cal.polynomial.rows} {cal.polynomial.columns} '
                                      + ' '.join(repr(float(c)) for c in cal.polynomial.coefficients.ravel())
                                      + f' {nb}\n')
        (d / 'in.bin').write_bytes(np.column_stack([raw_rate, raw_temp]).tobytes())
        run = subprocess.run([str(exe), str(d / 'params.txt'), str(d / 'in.bin'), str(d / 'out.bin')],
                             check=True, capture_output=True, text=True)
        c_seconds = float(run.stdout)
        c_out = np.fromfile(d / 'out.bin', dtype=np.float32).reshape(-1, 2)

    t0 = time.perf_counter()
    log = GyroLog(np.arange(n) * 0.1, raw_rate * cal.rate_scale_factor, raw_temp * cal.temp_scale_factor)
    applied = apply_calibration(log, cal, nb)
    py_seconds = time.perf_counter() - t0
    worst = float(np.abs(applied.corrected_dps[nb:] - c_out[:, 1]).max())
    print('| samples | C loop (gcc -O2) s | apply (numpy) s | ratio | max abs difference deg/s |')
    print('|---:|---:|---:|---:|---:|')
    print(f'| {n:,} | {c_seconds:.3f} | {py_seconds:.3f} | {py_seconds / c_seconds:.2f} | {worst:.2e} |')


if __name__ == '__main__':
    main()
