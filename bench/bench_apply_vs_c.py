"""Benchmark: ``calibrate apply``'s compensation against the report's C program (gcc -O2), one run.

Both get the same raw samples of a gyro; the C program (test/c/art_reference.c, a straight
transcription of the report) times its own loop, the Python side times apply_calibration
(static bias plus compensation over the arrays). Prints the ratio; the goal is <= 2.
Usage: python bench/bench_apply_vs_c.py [--samples 10000000] [--serial NAVC3545]
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path
from typing import cast

import numpy as np
from numpy.typing import NDArray

from art_gyro_calibration.calibration import load_packaged_calibration
from art_gyro_calibration.compensation import apply_calibration
from art_gyro_calibration.log import GyroLog

# The C reference helper lives with the tests that also use it.
sys.path.insert(0, str(Path(__file__).resolve().parent.parent / 'test'))
from c_reference import compile_reference, run_reference  # noqa: E402


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
        c_out, c_seconds = run_reference(compile_reference(Path(tmp)), cal, raw_rate, raw_temp, nb, Path(tmp))

    t0 = time.perf_counter()
    # int32 times a float is float64; numpy's stubs say only floating.
    log = GyroLog(np.arange(n) * 0.1, cast(NDArray[np.float64], raw_rate * cal.rate_scale_factor),
                  raw_temp * cal.temp_scale_factor)
    applied = apply_calibration(log, cal, nb)
    py_seconds = time.perf_counter() - t0
    worst = float(np.abs(applied.corrected_dps[nb:] - c_out[:, 1]).max())
    print('| samples | C loop (gcc -O2) s | apply (numpy) s | ratio | max abs difference deg/s |')
    print('|---:|---:|---:|---:|---:|')
    print(f'| {n:,} | {c_seconds:.3f} | {py_seconds:.3f} | {py_seconds / c_seconds:.2f} | {worst:.2e} |')


if __name__ == '__main__':
    main()
