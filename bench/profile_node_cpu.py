"""Where the CPU of gyro_node and of the lean reader goes at 1 kHz: per thread, and per library (perf).

``python bench/profile_node_cpu.py [--rounds 2] [--round-seconds 20] [--protocol rd2100_binary|kvh_fog]
[--variants NAME...] [--perf]``: the sessions of ``bench_node.py --compare`` (a fresh pty and subscriber, 1 kHz
of sequence-numbered frames), alternating the lean reader and the node (and each variant of
``bench_node.VARIANTS``); for each process, over the 1 kHz phase, the CPU (utime + stime from
``/proc/<pid>/task/<tid>/stat``) of each of its threads, grouped by thread name, as a share of one core.
``--perf``: ``perf record`` of the process at 2 kHz over the same phase, the samples split by shared
object (the kernel, libfastrtps, libpython's interpreter, librcl, ...): how much of the CPU is the DDS
write and how much Python. ``--stages``: the node once more with its reader thread's CPU (``time.thread_time_ns``)
summed per stage of a frame (:data:`STAGES`), printed per frame; the timing itself adds to it.
"""

from __future__ import annotations

import argparse
import collections
import json
import os
import signal
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import bench_node   # noqa: E402  # the bench directory, as above


# A variant of gyro_node that sums its reader thread's CPU per stage, each stage less the stages it calls.
STAGES = r"""
import atexit, json, os, sys, time
from art_gyro_calibration.driver import SerialGyroDriver
from art_gyro_calibration.compensation import FrameCorrector
from art_gyro_calibration.frame_guard import FrameGuard
from art_gyro_calibration.ros.node import GyroNode
from art_gyro_calibration.ros.raw_log import RawLog
from art_gyro_calibration.stamper import WireStamper
from rclpy.publisher import Publisher
sums, stack = {}, []
def timed(cls, name, label):
    call = getattr(cls, name)
    def wrapper(*args, **kwargs):
        stack.append(0)
        t0 = time.thread_time_ns()
        try:
            return call(*args, **kwargs)
        finally:
            total = time.thread_time_ns() - t0
            inner = stack.pop()
            count, ns = sums.get(label, (0, 0))
            sums[label] = (count + 1, ns + total - inner)
            if stack:
                stack[-1] += total
    setattr(cls, name, wrapper)
timed(SerialGyroDriver, '_read_once', 'wait and read (select, os.read, the clocks)')
timed(SerialGyroDriver, '_on_data', "the chunk's own (byte share, stamps loop, Frame)")
timed(WireStamper, 'stamp', 'stamps (WireStamper.stamp)')
timed(FrameGuard, 'passes', 'frame guard')
timed(GyroNode, '_on_frame', "the node's own (puts, checks)")
timed(FrameCorrector, 'step', 'compensation (FrameCorrector.step)')
timed(Publisher, 'publish', 'publish (rclpy and DDS)')
timed(RawLog, 'write', 'raw log')
init = SerialGyroDriver.__init__
def parser_timed(self, *args, **kwargs):
    init(self, *args, **kwargs)
    timed(type(self._parser), 'feed', 'parse (parser.feed)')
SerialGyroDriver.__init__ = parser_timed
atexit.register(lambda: json.dump(sums, open(os.environ['STAGES_OUT'] + str(os.getpid()), 'w')))
"""


def thread_ticks(pid: int) -> dict[int, tuple[str, int]]:
    """(name, utime + stime ticks) of each thread of ``pid``."""
    out = {}
    for tid in os.listdir(f'/proc/{pid}/task'):
        try:
            text = Path(f'/proc/{pid}/task/{tid}/stat').read_text()
        except OSError:
            continue   # the thread ended
        name = text[text.index('(') + 1:text.rindex(')')]
        fields = text.rsplit(')', 1)[1].split()
        out[int(tid)] = (name, int(fields[11]) + int(fields[12]))
    return out


class ThreadProbe(bench_node.Probe):
    """bench_node's probe, plus per-thread CPU over its life and, with ``PERF``, a perf record of the process."""

    perf_dir: str | None = None
    last: ThreadProbe | None = None

    def __init__(self, pid: int) -> None:
        self.start_ticks = thread_ticks(pid)
        self.perf: subprocess.Popen[bytes] | None = None
        if self.perf_dir is not None:
            self.perf_data = os.path.join(self.perf_dir, f'{pid}.data')
            self.perf = subprocess.Popen(['perf', 'record', '-q', '-F', '2000', '-e', 'cpu-clock', '-p', str(pid),
                                          '-o', self.perf_data], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        super().__init__(pid)
        ThreadProbe.last = self

    def stop(self) -> None:
        """Stop sampling; keep the per-thread CPU."""
        self.end_ticks = thread_ticks(self.pid)
        if self.perf is not None:
            self.perf.send_signal(signal.SIGINT)
            self.perf.wait(60)
        super().stop()


def by_thread(probe: ThreadProbe, seconds: float) -> dict[str, float]:
    """CPU share of one core per thread name over the probe's life."""
    ticks: collections.Counter[str] = collections.Counter()
    for tid, (name, end) in probe.end_ticks.items():
        ticks[name] += end - probe.start_ticks.get(tid, (name, 0))[1]
    return {name: t / os.sysconf('SC_CLK_TCK') / seconds for name, t in ticks.items()}


def by_library(data: str) -> dict[str, float]:
    """Share of the perf samples per shared object."""
    report = subprocess.run(['perf', 'report', '-i', data, '--stdio', '--sort', 'dso', '-q'],
                            capture_output=True, text=True, check=True).stdout
    shares: dict[str, float] = {}
    for line in report.splitlines():
        parts = line.split()
        if len(parts) >= 2 and parts[0].endswith('%'):
            shares[parts[1]] = float(parts[0][:-1]) / 100
    return shares


def print_stages(path: str) -> None:
    """The stages' CPU per frame published, in microseconds, from the variant's file (the whole run: warm-up too)."""
    sums = json.loads(Path(path).read_text())
    frames = sums["the node's own (puts, checks)"][0]
    total = sum(ns for _, ns in sums.values())
    print(f'    reader thread per frame ({frames} frames): {total / frames * 1e-3:.1f} us: ' + ', '.join(
        f'{label} {ns / frames * 1e-3:.1f}' for label, (_, ns) in sorted(sums.items(), key=lambda x: -x[1][1])))


def main() -> int:
    """Run the rounds and print one table per process and round."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--rounds', type=int, default=2)
    parser.add_argument('--round-seconds', type=float, default=20.0)
    parser.add_argument('--protocol', choices=('rd2100_binary', 'kvh_fog'), default='rd2100_binary')
    parser.add_argument('--serial', default='NAVC3545')
    parser.add_argument('--variants', nargs='+', default=[], choices=tuple(bench_node.VARIANTS))
    parser.add_argument('--perf', action='store_true', help='perf record each process')
    parser.add_argument('--stages', action='store_true', help="the node's reader thread's CPU per stage too")
    args = parser.parse_args()
    protocol = 'binary' if args.protocol == 'rd2100_binary' else 'kvh_fog'
    baud = 115200 if protocol == 'binary' else bench_node.KVH_BAUD
    bench_node.Probe = ThreadProbe   # type: ignore[misc]  # Session makes its probe by this name
    kinds = ['lean', 'node', *args.variants] + (['stages'] if args.stages else [])
    bench_node.VARIANTS['stages'] = STAGES
    with tempfile.TemporaryDirectory() as tmp:
        os.environ['STAGES_OUT'] = os.path.join(tmp, 'stages_')
        ThreadProbe.perf_dir = tmp if args.perf else None
        for r in range(args.rounds):
            for kind in kinds if r % 2 == 0 else kinds[::-1]:
                s = bench_node.Session(kind, protocol, args.serial, baud, 0.0, args.round_seconds).run()
                probe = ThreadProbe.last
                assert probe is not None
                p50, p99, lost = s.latency_lost()
                threads = by_thread(probe, args.round_seconds)
                load = np.array(probe.samples)[:, 2].mean()
                top = ', '.join(f'{name} {100 * share:.1f}' for name, share in
                                sorted(threads.items(), key=lambda x: -x[1]) if share >= 0.001)
                print(f'round {r + 1} {kind}: CPU {100 * s.cpu:.1f} % (threads: {top}); p50 {p50:.2f} ms, '
                      f'p99 {p99:.2f} ms, lost {lost}; load {load:.1f}', flush=True)
                if kind == 'stages':
                    print_stages(os.environ['STAGES_OUT'] + str(probe.pid))
                if args.perf:
                    libs = by_library(probe.perf_data)
                    print('    perf, share of the samples: ' + ', '.join(
                        f'{name} {100 * share:.0f} %' for name, share in sorted(libs.items(), key=lambda x: -x[1])
                        if share >= 0.02), flush=True)
    return 0


if __name__ == '__main__':
    sys.exit(main())
