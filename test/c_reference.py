"""The report's C program (test/c/art_reference.c): compile it and run it over raw samples.

Shared by the model tests (the reference) and bench/bench_apply_vs_c.py (the baseline).
"""

import shutil
import subprocess
from pathlib import Path

import numpy as np

from art_gyro_calibration.calibration import Calibration

C_SOURCE = Path(__file__).resolve().parent / 'c' / 'art_reference.c'


def compile_reference(directory: Path) -> Path:
    """Compile the C program with gcc -O2 into ``directory``."""
    gcc = shutil.which('gcc')
    assert gcc, 'gcc is needed to compile the report C program (.ci/run installs it)'
    exe = directory / 'art_reference'
    subprocess.run([gcc, '-O2', '-o', str(exe), str(C_SOURCE), '-lm'], check=True)
    return exe


def run_reference(exe: Path, calibration: Calibration, raw_rate: np.ndarray, raw_temp: np.ndarray,
                  bias_samples: int, directory: Path) -> tuple[np.ndarray, float]:
    """(comp, CompRate) of every sample after the bias samples, and the seconds of the C loop."""
    params = directory / 'params.txt'
    poly = calibration.polynomial
    params.write_text(f'{calibration.rate_scale_factor!r} {poly.rows} {poly.columns} '
                      + ' '.join(repr(float(c)) for c in poly.coefficients.ravel()) + f' {bias_samples}\n')
    (directory / 'in.bin').write_bytes(np.column_stack([raw_rate, raw_temp]).astype(np.int32).tobytes())
    run = subprocess.run([str(exe), str(params), str(directory / 'in.bin'), str(directory / 'out.bin')],
                         check=True, capture_output=True, text=True)
    out = np.fromfile(directory / 'out.bin', dtype=np.float32).reshape(-1, 2).astype(float)
    return out, float(run.stdout)
