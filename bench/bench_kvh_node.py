"""gyro_node on a simulated KVH unit at 1 kHz: the node's CPU share with the whole IMU message.

``python bench/bench_kvh_node.py [--seconds 60] [--format A|B] [--source DIR]``: the fake unit
(factory settings but the format; Format B with ``timestamp_source: unit_clock``) on a pty,
``config/kvh_fog.params.yaml``, a subscriber in this process; after 5 s, the node's user+system
CPU over ``--seconds`` from /proc, the messages sent and received, the load average. ``--source``
runs another checkout's node and tests (its own params file), to compare on the same load.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path


def cpu_s(pid: int) -> float:
    """User + system CPU seconds of a process (Linux)."""
    with open(f'/proc/{pid}/stat') as f:
        fields = f.read().rsplit(')', 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf('SC_CLK_TCK')


def main() -> int:
    """Run the measure; print one line."""
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument('--seconds', type=float, default=60.0)
    p.add_argument('--format', choices=('A', 'B'), default='A')
    p.add_argument('--source', default=str(Path(__file__).resolve().parent.parent))
    args = p.parse_args()
    sys.path[:0] = [args.source, str(Path(args.source) / 'test')]
    os.environ['PYTHONPATH'] = args.source
    os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
    from rosproc import REPO, domain_id, node_with_listener

    from art_gyro_calibration.fake_gyro import FakeGyro
    from art_gyro_calibration.protocols.kvh_fog import KvhFogConfig
    extra = ['-p', f'kvh_fog.message_format:={args.format}']
    if args.format == 'B':
        extra += ['-p', 'kvh_fog.timestamp_source:=unit_clock']
    out = Path('/tmp') / f'bench_kvh_node_{os.getpid()}.log'
    with (FakeGyro('KVH_DSP1760_EXAMPLE', protocol='kvh_fog', rate_hz=1000, profile='0', seed=1,
                   kvh_fog=KvhFogConfig(message_format=args.format)) as fake,
          node_with_listener(domain_id(), out, '--params-file', str(REPO / 'config' / 'kvh_fog.params.yaml'),
                             '-p', f'port:={fake.path}', *extra) as (proc, listener)):
        time.sleep(5.0)
        c0, n0, s0, t0 = cpu_s(proc.pid), listener.count(), fake.sent, time.monotonic()
        time.sleep(args.seconds)
        c1, n1, s1, t1 = cpu_s(proc.pid), listener.count(), fake.sent, time.monotonic()
    print(f'format {args.format} ({args.source}): {s1 - s0} sent, {n1 - n0} received in {t1 - t0:.1f} s; '
          f'node CPU {100 * (c1 - c0) / (t1 - t0):.1f} % of a core; load average {os.getloadavg()[0]:.1f}')
    return 0


if __name__ == '__main__':
    sys.exit(main())
