"""Import time and resident memory of ``art_gyro_calibration.ros.node`` in fresh interpreters.

``python bench/bench_import.py [--source DIR] [--runs N]``: each run starts a new interpreter
that imports the node module and reports the wall time of the import, VmRSS afterwards
(Linux) and which heavy packages came along. ``--source`` puts another checkout first on the
path, to measure an older layout with the same interpreter and installed packages.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys

CHILD = '''
import json, sys, time
t0 = time.perf_counter()
import art_gyro_calibration.ros.node
seconds = time.perf_counter() - t0
status = open('/proc/self/status').read()
rss_mib = int(status.split('VmRSS:')[1].split()[0]) / 1024
heavy = sorted(m for m in ('scipy', 'matplotlib', 'h5py') if m in sys.modules)
print(json.dumps({'seconds': seconds, 'rss_mib': rss_mib, 'heavy': heavy,
                  'file': art_gyro_calibration.ros.node.__file__}))
'''


def main() -> int:
    """Measure and print a summary line."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--source', help='checkout to import from instead of the installed package')
    parser.add_argument('--runs', type=int, default=5)
    args = parser.parse_args()
    env = dict(os.environ)
    if args.source:
        env['PYTHONPATH'] = os.pathsep.join(filter(None, [os.path.abspath(args.source), env.get('PYTHONPATH')]))
    runs = [json.loads(subprocess.run([sys.executable, '-c', CHILD], env=env, capture_output=True, text=True,
                                      check=True, cwd='/').stdout) for _ in range(args.runs)]
    seconds = sorted(r['seconds'] for r in runs)
    rss = sorted(r['rss_mib'] for r in runs)
    print(f'{runs[0]["file"]}: import {statistics.median(seconds):.3f} s median ({seconds[0]:.3f}-{seconds[-1]:.3f}), '
          f'VmRSS {statistics.median(rss):.1f} MiB, heavy packages: {runs[0]["heavy"] or "none"} ({args.runs} runs)')
    return 0


if __name__ == '__main__':
    sys.exit(main())
