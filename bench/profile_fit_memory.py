"""What holds the memory of ``calibrate fit`` at its peak: numpy allocations by source line, with tracemalloc.

Reads a log written by ``calibrate simulate``, then runs the fit's stages as
``calibrate fit`` does (read, close_loop, report). A sampling thread takes a tracemalloc
snapshot whenever the traced memory reaches a new high, so the allocations alive at the
peak are listed by the line that made them (numpy reports its buffers to tracemalloc).

``python bench/profile_fit_memory.py LOG.csv [--top 15]``. A measurement, not a test.
"""

from __future__ import annotations

import argparse
import threading
import time
import tracemalloc

from art_gyro_calibration.calibration import load_packaged_calibration
from art_gyro_calibration.analysis.loop import LoopOptions, close_loop
from art_gyro_calibration.analysis.report import build_report
from art_gyro_calibration.log import read_log

MIB = 1 << 20


class PeakSnapshots:
    """Takes a snapshot each time the traced memory grows 3 % beyond the highest seen."""

    def __init__(self, period_s: float = 0.05) -> None:
        self.peak = 0
        self.snapshot: tracemalloc.Snapshot | None = None
        self._period_s = period_s
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)

    def _run(self) -> None:
        while not self._stop.wait(self._period_s):
            current, _ = tracemalloc.get_traced_memory()
            if current > self.peak * 1.03:
                self.peak = current
                self.snapshot = tracemalloc.take_snapshot()

    def __enter__(self) -> PeakSnapshots:
        self._thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self._stop.set()
        self._thread.join()


def main() -> None:
    """Run the fit's stages under tracemalloc and print the peak's allocations."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('log')
    parser.add_argument('--serial', default='NAVC3545')
    parser.add_argument('--top', type=int, default=15)
    args = parser.parse_args()
    cal = load_packaged_calibration(args.serial)
    tracemalloc.start(6)
    with PeakSnapshots() as sampler:
        stages = []
        start = time.perf_counter()
        log = read_log(args.log, cal.rate_scale_factor, cal.temp_scale_factor)
        stages.append(('read_log', tracemalloc.get_traced_memory()))
        tracemalloc.reset_peak()
        result = close_loop(log, 3, 4, LoopOptions(serial_number=args.serial, rate_scale_factor=cal.rate_scale_factor,
                                                   temp_scale_factor=cal.temp_scale_factor))
        stages.append(('close_loop', tracemalloc.get_traced_memory()))
        tracemalloc.reset_peak()
        build_report(log, result, 100)
        stages.append(('build_report', tracemalloc.get_traced_memory()))
        elapsed = time.perf_counter() - start
    columns = [log.t, log.rate_dps, log.temp_c, log.ref_rate, *log.extras.values()]
    print(f'{len(log):,} rows, {elapsed:.1f} s under tracemalloc; the log\'s {len(columns)} columns '
          f'{sum(c.nbytes for c in columns if c is not None) / MIB:.0f} MiB')
    for name, (current, peak) in stages:
        print(f'after {name}: {current / MIB:,.0f} MiB held, peak during it {peak / MIB:,.0f} MiB')
    if sampler.snapshot is None:
        return
    print(f'\nallocations alive at the highest sample ({sampler.peak / MIB:,.0f} MiB), by the line of the package '
          'that made them:')
    stats = sampler.snapshot.filter_traces([tracemalloc.Filter(True, '*art_gyro_calibration*')]).statistics('traceback')
    for stat in stats[:args.top]:
        frames = [f for f in stat.traceback if 'art_gyro_calibration' in f.filename]
        where = ' <- '.join(f'{f.filename.rsplit("art_gyro_calibration/", 1)[-1]}:{f.lineno}' for f in frames[-1:-4:-1])
        print(f'{stat.size / MIB:8.0f} MiB in {stat.count:5d} blocks  {where}')


if __name__ == '__main__':
    main()
