"""Benchmark: gyro_node as shipped, fed on a pty, seen by a subscriber in another process.

Three processes: this one writes binary RD2100 frames to the pty master (each frame in one
``os.write``, its time taken just before the write: the frame's last byte is in the pty
within the write's duration after it, so latencies are over-estimated by that much at most,
and a writer pre-empted after its write cannot make a latency look shorter); ``gyro_node``
(unchanged, ``python -m art_gyro_calibration.ros.node``) reads the slave; a subscriber (this
script with ``--subscriber``, its own process so it shares no GIL with the writer) stamps
each ``imu/data_raw`` message on arrival with the same CLOCK_MONOTONIC.

Each frame carries its sequence number: ``raw_rate = (levels()[seq mod 4096] - 2048) * 8`` counts
(:func:`levels`: distinct, successive ones 2 apart at most) at a constant 25 degC (rates within +-50 deg/s,
8 counts = 0.024 deg/s apart). The packaged
calibration has no history-dependent terms and the startup static bias is off, so the
published rate is a fixed, monotonic function of ``raw_rate``: the subscriber's rates decode
back to ``seq mod 4096`` by a table lookup, and the order of arrival (one publisher) gives
the sequence. Latency is arrival minus write of the same frame; a frame is lost if its
sequence number never arrives.

Phases: a 10 Hz warm-up until the subscriber hears the node, 10 Hz for --slow-seconds, then
1 kHz for --minutes. The node's CPU share (utime + stime from /proc/<pid>/stat) and resident
memory (VmRSS, every second) are taken over the 1 kHz phase. The node is told a baud of
115200 (--baud): a pty ignores it, but the node's wire-time stamp correction uses it, and the
node's default of 9600 baud could not carry 1 kHz of 8-byte frames (8 kB/s) on a real wire.

``--compare ROUNDS``: the node against :data:`LEAN`, the leanest rclpy reader-publisher (the package's
parser, then a new ``Imu`` stamped with the node clock's now and published, frame by frame, no executor), in
alternating rounds (node first in odd rounds, lean first in even ones) of ``--round-seconds`` at 1 kHz each, on a
fresh process and subscriber: CPU, latency and loss of each, and the node's CPU as a share of the lean reader's of
the same round. ``--protocol kvh_fog``: Format A rate messages at 921600 baud whose x rate carries the sequence
number (``config/kvh_fog.params.yaml`` with ``kvh_fog.rotation:=rate``); the subscriber decodes ``angular_velocity.x``.
``--sources DIR...``: the node of each checkout (``git worktree add DIR COMMIT``) in each round, to measure what
each change bought. ``--variants NAME...``: candidates not shipped (:data:`VARIANTS`), each in each round too.
(rclpy 7.1.6's ``EventsExecutor`` cannot run the node: its ``spin`` raises "Guard conditions not
supported".)

Usage: python bench/bench_node.py [--minutes 10] [--slow-seconds 120] [--serial NAVC3545]
       python bench/bench_node.py --compare 3 [--round-seconds 60] [--protocol rd2100_binary|kvh_fog] [--sources DIR...]
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import select
import signal
import subprocess
import sys
import tempfile
import threading
import time
import tty
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parent.parent
PERIOD = 4096           # sequence numbers repeat after this many frames (4 s at 1 kHz)
STEP_COUNTS = 8         # raw_rate counts between successive sequence numbers
RAW_TEMP = 500          # 25 degC at 0.05 degC per count
READY_TIMEOUT_S = 60.0
DRAIN_S = 3.0           # after the last write, time for the last messages to arrive


KVH_STEP_RAD_S = 1e-4   # kvh_fog: x rate between successive sequence numbers
KVH_BAUD = 921600
# The leanest reader-publisher: the package's parser, a new Imu per frame stamped with now, published at once.
# argv: port, baud, protocol, rate scale (deg/s per count; kvh_fog: unused).
LEAN = '''
import math, sys
sys.modules['rosidl_generator_py.generate_py_impl'] = None   # as gyro_node's main() does
import rclpy, serial
from rclpy.utilities import ok
from sensor_msgs.msg import Imu
from art_gyro_calibration.protocols import KvhFogConfig, make_parser
port, baud, protocol, scale = sys.argv[1], int(sys.argv[2]), sys.argv[3], float(sys.argv[4])
rclpy.init()
node = rclpy.create_node('lean_reader')
pub = node.create_publisher(Imu, 'imu/data_raw', 10)
clock = node.get_clock()
parser = make_parser(protocol, KvhFogConfig(rotation='rate'), 3)
link = serial.Serial(port, baud, timeout=0.1)
try:
    while ok():
        data = link.read(1)
        if data and link.in_waiting:
            data += link.read(link.in_waiting)
        for sample, _ in parser.feed(data):
            msg = Imu()
            msg.header.stamp = clock.now().to_msg()
            msg.header.frame_id = 'imu_link'
            if sample.imu is None:
                msg.angular_velocity.z = math.radians(sample.raw_rate * scale)
            else:
                rates = sample.imu.rates_dps
                msg.angular_velocity.x = math.radians(rates[0])
                msg.angular_velocity.y = math.radians(rates[1])
                msg.angular_velocity.z = math.radians(sample.raw_rate)
            pub.publish(msg)
except KeyboardInterrupt:
    pass
'''


def levels() -> np.ndarray:
    """A distinct level 0..PERIOD-1 for each ``seq mod PERIOD``, up by 2 then down by 2 (1 at the turns).

    Successive frames, across the period's wrap too, differ by at most 2 levels: never a jump that the node's
    rate-jump guard refuses (a sawtooth's wrap, 4096 levels in 1 ms, was refused for about 20 ms each time).
    """
    k = np.arange(PERIOD)
    return np.where(k < PERIOD // 2, 2 * k, 2 * (PERIOD - 1 - k) + 1) - PERIOD // 2


def _read_every(seconds: float) -> str:
    """A variant: after each read the reader waits ``seconds``, so that a read takes that long's frames at once."""
    return ('from art_gyro_calibration.driver import SerialGyroDriver as D\n'
            'read = D._read_once\n'
            'def batched(self):\n'
            '    read(self)\n'
            f'    self._stop.wait({seconds!r})\n'
            'D._read_once = batched\n')


# Candidates measured and not shipped: gyro_node with one thing changed, patched in before its main().
VARIANTS = {'read_every_5ms': _read_every(0.005), 'read_every_2ms': _read_every(0.002),
            # imu/temperature with every 10th frame only (100 Hz): what its publish costs the node.
            'temperature_every_10th': 'from art_gyro_calibration.ros.node import GyroNode\n'
                                      'init = GyroNode.__init__\n'
                                      'class Every10th:\n'
                                      '    def __init__(self, publisher):\n'
                                      '        self.publisher, self.count = publisher, 0\n'
                                      '    def publish(self, message):\n'
                                      '        self.count += 1\n'
                                      '        if self.count % 10 == 0:\n'
                                      '            self.publisher.publish(message)\n'
                                      'def every_10th(self, *args, **kwargs):\n'
                                      '    init(self, *args, **kwargs)\n'
                                      '    self._temp_pub = Every10th(self._temp_pub)\n'
                                      'GyroNode.__init__ = every_10th\n'}


def kvh_rates() -> np.ndarray:
    """kvh_fog: the x rate (rad/s, as the wire's float32) of each ``seq mod PERIOD``."""
    return (levels() * KVH_STEP_RAD_S).astype(np.float32).astype(np.float64)


def raw_rates() -> np.ndarray:
    """``raw_rate`` of each ``seq mod PERIOD``."""
    return levels() * STEP_COUNTS


# --- subscriber process ----------------------------------------------------------------

def run_subscriber(out: str) -> int:
    """Record (arrival ns, rate, stamp) of every Imu message and the node's last link status; 'stop' on stdin ends."""
    import rclpy
    from diagnostic_msgs.msg import DiagnosticArray   # type: ignore[import-untyped]  # the message wheels: no hints
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.qos import ReliabilityPolicy
    from rclpy.utilities import try_shutdown
    from sensor_msgs.msg import Imu   # type: ignore[import-untyped]

    from art_gyro_calibration.ros.rclpy_typed import qos_profile

    rclpy.init()
    node = rclpy.create_node('bench_subscriber')
    arrival: list[int] = []
    rate: list[float] = []
    rate_x: list[float] = []
    stamp: list[int] = []
    link: dict[str, str] = {}
    ready = threading.Event()

    def on_imu(msg: Imu) -> None:
        # The messages queued behind this one are taken here too, each stamped as taken: the executor would take
        # one per wait, and a burst of them (a node that publishes several frames at once) would wait on the
        # subscriber's own overhead, not on the node.
        while msg is not None:
            arrival.append(time.monotonic_ns())
            rate.append(msg.angular_velocity.z)
            rate_x.append(msg.angular_velocity.x)
            stamp.append(msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec)
            with subscription.handle:
                taken = subscription.handle.take_message(Imu, False)
            msg = taken[0] if taken is not None else None
        if not ready.is_set():
            ready.set()
            print('ready', flush=True)

    def on_diagnostics(msg: DiagnosticArray) -> None:
        for s in msg.status:
            if s.name.endswith(': link'):
                link.clear()
                link.update({kv.key: kv.value for kv in s.values}, message=s.message)

    reliable = qos_profile(1000, reliability=ReliabilityPolicy.RELIABLE)
    subscription = node.create_subscription(Imu, 'imu/data_raw', on_imu, reliable)
    node.create_subscription(DiagnosticArray, '/diagnostics', on_diagnostics, 10)
    executor = SingleThreadedExecutor()
    executor.add_node(node)
    thread = threading.Thread(target=executor.spin, daemon=True)
    thread.start()
    sys.stdin.readline()   # 'stop' or EOF
    executor.shutdown()
    thread.join(5.0)
    usage = os.times()
    np.savez(out, arrival=np.array(arrival, dtype=np.int64), rate=np.array(rate), rate_x=np.array(rate_x),
             stamp=np.array(stamp, dtype=np.int64))
    Path(out + '.json').write_text(json.dumps({'link': link, 'cpu_s': usage.user + usage.system}))
    node.destroy_node()   # type: ignore[no-untyped-call]  # rclpy: destroy_node unannotated
    try_shutdown()
    return 0


# --- writer and probes ---------------------------------------------------------------

def child_env(domain: int) -> dict[str, str]:
    """Environment of the node and subscriber: own domain, loopback discovery."""
    env = dict(os.environ, ROS_DOMAIN_ID=str(domain), ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST',
               PYTHONUNBUFFERED='1')
    env.pop('_ROS_WHEELS_BOOTSTRAP_COMPLETE', None)   # the child's own bootstrap sets its library path
    return env


def cpu_ticks(pid: int) -> int:
    """CPU time (utime + stime) of a process, in clock ticks."""
    fields = Path(f'/proc/{pid}/stat').read_text().rsplit(')', 1)[1].split()
    return int(fields[11]) + int(fields[12])   # fields 14 and 15 of proc(5), counted after the comm


def rss_kb(pid: int) -> int:
    """Resident memory of a process in kB."""
    for line in Path(f'/proc/{pid}/status').read_text().splitlines():
        if line.startswith('VmRSS:'):
            return int(line.split()[1])
    raise RuntimeError(f'no VmRSS for {pid}')


class Writer:
    """Writes frame ``seq`` at its deadline and records when each write returned."""

    def __init__(self, master: int, capacity: int, protocol: str = 'binary') -> None:
        from art_gyro_calibration.protocols.kvh_fog import KVH_SEQUENCE_MODULO, KVH_STATUS_ALL_VALID, encode_kvh_fog
        from art_gyro_calibration.protocols.rd2100_binary import encode_binary
        self.master = master
        self.frames = ([encode_binary(int(r), RAW_TEMP) for r in raw_rates()] if protocol == 'binary' else
                       [encode_kvh_fog((float(x), 0.0, 0.0), (0.0, 0.0, 1.0), KVH_STATUS_ALL_VALID,
                                       i % KVH_SEQUENCE_MODULO, 25.0) for i, x in enumerate(kvh_rates())])
        self.mono_ns = np.zeros(capacity, dtype=np.int64)
        self.real_ns = np.zeros(capacity, dtype=np.int64)
        self.write_ns = np.zeros(capacity, dtype=np.int64)   # how long each write took
        self.seq = 0
        self.late = 0    # writes more than a period after their deadline (the writer fell behind)

    def run(self, rate_hz: float, count: int | None = None, until: threading.Event | None = None) -> tuple[int, int]:
        """Write ``count`` frames (or until ``until`` is set) at ``rate_hz``; the [first, end) sequence written."""
        period_ns = int(1e9 / rate_hz)
        first = self.seq
        start = time.monotonic_ns()
        i = 0
        while (count is None or i < count) and not (until is not None and until.is_set()):
            delay = start + i * period_ns - time.monotonic_ns()
            if delay > 0:
                time.sleep(delay * 1e-9)
            elif -delay > period_ns:
                self.late += 1
            seq = self.seq
            self.real_ns[seq] = time.time_ns()
            self.mono_ns[seq] = before = time.monotonic_ns()
            os.write(self.master, self.frames[seq % PERIOD])
            self.write_ns[seq] = time.monotonic_ns() - before
            self.seq += 1
            i += 1
        return first, self.seq


class Probe:
    """Samples the node's resident memory and the load average every second, on a thread."""

    def __init__(self, pid: int) -> None:
        self.pid = pid
        self.samples: list[tuple[float, int, float]] = []   # (monotonic s, VmRSS kB, 1-min load)
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _run(self) -> None:
        while not self._stop.wait(1.0):
            load = float(Path('/proc/loadavg').read_text().split()[0])
            self.samples.append((time.monotonic(), rss_kb(self.pid), load))

    def stop(self) -> None:
        """Stop sampling."""
        self._stop.set()
        self._thread.join()


def published_table(serial: str, compensated: bool) -> tuple[np.ndarray, float]:
    """Binary: the yaw rate (deg/s) published for each ``seq mod PERIOD``, and deg/s per count.

    ``compensated``: the node's (the calibration's polynomial taken off); else the lean reader's (scaled only).
    """
    from art_gyro_calibration.calibration import load_packaged_calibration
    cal = load_packaged_calibration(serial)
    assert not cal.terms, 'the decoding needs a calibration without history-dependent terms'
    rate = raw_rates() * cal.rate_scale_factor
    if compensated:
        rate = rate - cal.polynomial.error(rate, RAW_TEMP * cal.temp_scale_factor)   # what the node publishes
    return rate, cal.rate_scale_factor


def decode(table: np.ndarray, step: float, got: np.ndarray, arrival_ns: np.ndarray,
           written_ns: np.ndarray) -> tuple[np.ndarray, float]:
    """Sequence number of each received value ``got`` (``table``: per ``seq mod PERIOD``); worst residual, in steps."""
    order = np.argsort(table)
    ordered = table[order]
    assert np.all(np.diff(ordered) > 0)
    index = np.clip(np.searchsorted(ordered, got), 1, PERIOD - 1)
    index -= (got - ordered[index - 1]) < (ordered[index] - got)
    residual = float(np.abs(got - ordered[index]).max() / step) if len(got) else 0.0
    index = order[index]   # the residue
    # Each message: the latest frame of its residue written before it arrived (latencies are far below the
    # period's 4 s), so that a loss or a stall of any length leaves the others decoded right.
    latest = np.searchsorted(written_ns, arrival_ns, side='right') - 1
    seq = latest - np.mod(latest - index, PERIOD)
    return seq, residual


def latency_row(label: str, seq: np.ndarray, arrival: np.ndarray, stamp: np.ndarray,
                writer: Writer, first: int, end: int, frame_ns: int) -> str:
    """Markdown row: latency percentiles, loss and stamp offset of the frames [first, end)."""
    inside = (seq >= first) & (seq < end)
    s = seq[inside]
    latency_ms = (arrival[inside] - writer.mono_ns[s]) * 1e-6
    # From the write's end instead: a lower bound (the truth lies between the two).
    after_ms = latency_ms - writer.write_ns[s] * 1e-6
    stamp_ms = (stamp[inside] - (writer.real_ns[s] - frame_ns)) * 1e-6
    lost = (end - first) - len(np.unique(s))
    p50, p99, p999 = np.percentile(latency_ms, [50, 99, 99.9])
    after50, after99 = np.percentile(after_ms, [50, 99])
    write_p99 = np.percentile(writer.write_ns[first:end], 99) * 1e-6
    return (f'| {label} | {end - first:,} | {lost} | {p50:.3f} | {p99:.3f} | {p999:.3f} | {latency_ms.max():.2f} | '
            f'{after50:.3f} / {after99:.3f} | {write_p99:.3f} | {np.median(stamp_ms):.3f} |')


def command(kind: str, protocol: str, serial: str, port: str, baud: int, source: Path = REPO) -> list[str]:
    """The process under test: ``gyro_node`` as shipped ('node', of the checkout ``source``) or :data:`LEAN`."""
    if kind in VARIANTS:
        return ([sys.executable, '-c', VARIANTS[kind] + 'import sys\nfrom art_gyro_calibration.ros.node import main\n'
                 'sys.exit(main(["gyro_node", *sys.argv[1:]]))'] + command('node', protocol, serial, port, baud)[3:])
    if kind == 'lean':
        from art_gyro_calibration.calibration import load_packaged_calibration
        scale = load_packaged_calibration(serial).rate_scale_factor if protocol == 'binary' else 1.0
        return [sys.executable, '-c', LEAN, port, str(baud), protocol, repr(scale)]
    node = [sys.executable, '-m', 'art_gyro_calibration.ros.node', '--ros-args']
    if protocol == 'binary':
        return node + ['-p', f'serial_number:={serial}', '-p', f'port:={port}', '-p', f'baud:={baud}',
                       '-p', 'static_bias_on_startup:=false']
    return node + ['--params-file', str(source / 'config' / 'kvh_fog.params.yaml'), '-p', f'port:={port}',
                   '-p', 'kvh_fog.rotation:=rate', '-p', 'static_bias_on_startup:=false']


class Session:
    """One process under test on a fresh pty and subscriber: 10 Hz warm-up, ``slow_s`` at 10 Hz, ``fast_s`` at 1 kHz.

    After ``run``: the writer, the decoded sequence numbers with their arrival and stamp, the [first, end) sequence
    of each phase, the process's CPU share over the 1 kHz phase, its memory and load samples, its link status.
    """

    def __init__(self, kind: str, protocol: str, serial: str, baud: int, slow_s: float, fast_s: float,
                 source: Path = REPO) -> None:
        """``source``: the checkout whose node runs (``python -m`` from its directory imports its package)."""
        self.kind, self.protocol, self.serial, self.baud, self.source = kind, protocol, serial, baud, source
        self.slow_frames, self.fast_frames = int(slow_s * 10), int(fast_s * 1000)

    def run(self) -> Session:
        """Run the phases; decode what the subscriber received."""
        domain = 1 + os.getpid() % 200
        capacity = self.slow_frames + self.fast_frames + int(READY_TIMEOUT_S * 10) + 1000
        master, slave = os.openpty()
        tty.setraw(slave)   # no byte translated
        port = os.ttyname(slave)
        writer = self.writer = Writer(master, capacity, self.protocol)
        with tempfile.TemporaryDirectory() as tmp:
            log = Path(tmp) / 'node.log'
            out = str(Path(tmp) / 'received')
            with open(log, 'wb') as node_out:
                node = subprocess.Popen(command(self.kind, self.protocol, self.serial, port, self.baud, self.source),
                                        env=child_env(domain), cwd=self.source, stdout=node_out,
                                        stderr=subprocess.STDOUT)
            sub = subprocess.Popen([sys.executable, __file__, '--subscriber', out], env=child_env(domain), cwd=REPO,
                                   stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
            assert sub.stdin is not None and sub.stdout is not None   # both piped
            try:
                # Warm-up at 10 Hz until the subscriber hears the node (discovery, imports).
                heard = threading.Event()
                warm = threading.Thread(target=writer.run, args=(10.0, None, heard))
                warm.start()
                ready, _, _ = select.select([sub.stdout], [], [], READY_TIMEOUT_S)
                heard.set()
                warm.join()
                if not ready or sub.stdout.readline().strip() != 'ready':
                    raise RuntimeError(f'the subscriber heard nothing within {READY_TIMEOUT_S} s:\n{log.read_text()}')
                writer.run(10.0, 20)   # settle
                print(f'# {self.kind} pid {node.pid}, port {port}, domain {domain}', file=sys.stderr)
                self.slow = writer.run(10.0, self.slow_frames)
                self.probe = Probe(node.pid)
                ticks0, t0 = cpu_ticks(node.pid), time.monotonic()
                self.fast = writer.run(1000.0, self.fast_frames)
                ticks1, t1 = cpu_ticks(node.pid), time.monotonic()
                self.probe.stop()
                time.sleep(DRAIN_S)
                writer.run(10.0, 20)   # trailing frames so that a loss at the very end would show
                time.sleep(DRAIN_S)
                sub.stdin.write('stop\n')
                sub.stdin.flush()
                if sub.wait(60) != 0:
                    raise RuntimeError('the subscriber failed')
            finally:
                node.send_signal(signal.SIGINT)
                try:
                    self.node_code = node.wait(30)
                except subprocess.TimeoutExpired:
                    node.kill()
                    self.node_code = node.wait()
                if sub.poll() is None:
                    sub.kill()
                os.close(master)
                os.close(slave)
            received = np.load(out + '.npz')
            extra = json.loads(Path(out + '.json').read_text())
        self.cpu = (ticks1 - ticks0) / os.sysconf('SC_CLK_TCK') / (t1 - t0)
        self.link, self.sub_cpu_s = extra['link'], extra['cpu_s']
        if self.protocol == 'binary':
            table, step = published_table(self.serial, self.kind != 'lean')
            got = np.degrees(received['rate'])
        else:
            table, step, got = kvh_rates(), KVH_STEP_RAD_S, received['rate_x']
        self.seq, self.residual = decode(table, step, got, received['arrival'], writer.mono_ns[:writer.seq])
        self.arrival, self.stamp = received['arrival'], received['stamp']
        latency = self.arrival - writer.mono_ns[self.seq]
        if self.residual > 0.25 or latency.min() < 0 or latency.max() > 2e9:
            print(f'warning: decoding doubtful (residual {self.residual:.2f} steps, latency '
                  f'{latency.min() * 1e-6:.2f}..{latency.max() * 1e-6:.2f} ms)', file=sys.stderr)
        return self

    def latency_lost(self) -> tuple[float, float, int]:
        """Latency p50 and p99 (ms) and frames lost over the 1 kHz phase."""
        first, end = self.fast
        inside = (self.seq >= first) & (self.seq < end)
        latency_ms = (self.arrival[inside] - self.writer.mono_ns[self.seq[inside]]) * 1e-6
        p50, p99 = np.percentile(latency_ms, [50, 99])
        return float(p50), float(p99), (end - first) - len(np.unique(self.seq[inside]))


def run(args: argparse.Namespace) -> int:
    """Run the node, the writer and the subscriber through the phases; print the tables."""
    from art_gyro_calibration.protocols.rd2100_binary import BINARY_FRAME_BYTES
    from art_gyro_calibration.stamper import WireStamper
    frame_ns = WireStamper(args.baud, BINARY_FRAME_BYTES).frame_ns   # the wire time the node subtracts
    s = Session('node', 'binary', args.serial, args.baud, args.slow_seconds, args.minutes * 60).run()
    writer, seq, arrival, stamp = s.writer, s.seq, s.arrival, s.stamp
    print(f'\nMachine: {platform.node()}, {os.cpu_count()} cores, {platform.processor() or platform.machine()}, '
          f'Python {platform.python_version()}, RMW {os.environ.get("RMW_IMPLEMENTATION", "default (Fast DDS)")}; '
          f'node exit code {s.node_code}; writer fell behind {writer.late} times; decode residual '
          f'{s.residual * STEP_COUNTS:.2f} counts')
    print('\n| rate | frames written | frames lost | latency p50 ms | p99 ms | p99.9 ms | max ms | '
          'from the write\'s end: p50 / p99 ms | write p99 ms | stamp - (write - wire time) median ms |')
    print('|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|')
    print(latency_row(f'10 Hz, {args.slow_seconds:g} s', seq, arrival, stamp, writer, *s.slow, frame_ns))
    print(latency_row(f'1 kHz, {args.minutes:g} min', seq, arrival, stamp, writer, *s.fast, frame_ns))
    samples = np.array(s.probe.samples)
    minutes = (samples[:, 0] - samples[0, 0]) / 60.0
    rss = samples[:, 1]
    half = minutes >= minutes[-1] / 2
    slope = np.polyfit(minutes, rss, 1)[0] if len(rss) > 1 else 0.0
    slope_late = np.polyfit(minutes[half], rss[half], 1)[0] if half.sum() > 1 else 0.0
    print('\n| node at 1 kHz | value |')
    print('|---|---:|')
    print(f'| CPU share of one core (utime + stime) | {s.cpu * 100:.1f} % |')
    print(f'| VmRSS start / end / max | {rss[0] / 1024:.1f} / {rss[-1] / 1024:.1f} / {rss.max() / 1024:.1f} MiB |')
    print(f'| VmRSS slope, whole phase / second half | {slope:+.1f} / {slope_late:+.1f} kB/min |')
    print(f'| load average (1 min) during the phase, min / mean / max | {samples[:, 2].min():.2f} / '
          f'{samples[:, 2].mean():.2f} / {samples[:, 2].max():.2f} |')
    link = s.link
    print(f'| node counters at the end (/diagnostics) | frames {link.get("frames")}, rejected '
          f'{link.get("rejected")}, published {link.get("published")}, of {writer.seq} written |')
    print(f'| subscriber process CPU (whole run) | {s.sub_cpu_s:.1f} s |')
    return 0


def compare(args: argparse.Namespace) -> int:
    """Alternating rounds of the node and the lean reader at 1 kHz; one row per process, the ratio per round."""
    protocol = 'binary' if args.protocol == 'rd2100_binary' else 'kvh_fog'
    baud = args.baud if protocol == 'binary' else KVH_BAUD
    print(f'{args.protocol}, {args.round_seconds:g} s at 1 kHz per process and round; {os.cpu_count()} cores')
    print('\n| round | process | CPU % of a core | latency p50 ms | p99 ms | lost | load avg (1 min) |')
    print('|---|---|---:|---:|---:|---:|---:|')
    sources = [Path(d).resolve() for d in args.sources] if args.sources else [REPO]
    processes = ([('lean', REPO, 'lean')] + [('node', d, 'node' if d == REPO else f'node {d.name}') for d in sources]
                 + [(name, REPO, f'node {name}') for name in args.variants or ()])
    ratios: dict[str, list[float]] = {label: [] for _, _, label in processes[1:]}
    for r in range(args.compare):
        cpu = {}
        for kind, source, label in processes if r % 2 == 0 else processes[::-1]:
            s = Session(kind, protocol, args.serial, baud, 0.0, args.round_seconds, source).run()
            p50, p99, lost = s.latency_lost()
            load = np.array(s.probe.samples)[:, 2].mean()
            cpu[label] = s.cpu
            print(f'| {r + 1} | {label} | {s.cpu * 100:.1f} | {p50:.2f} | {p99:.2f} | {lost} | {load:.2f} |',
                  flush=True)
        for label in ratios:
            ratios[label].append(cpu[label] / cpu['lean'])
    for label, values in ratios.items():
        print(f'\n{label} CPU / lean CPU per round: {", ".join(f"{x:.2f}" for x in values)}; '
              f'median {np.median(values):.2f}')
    return 0


def main() -> int:
    """Parse the command line; run the benchmark or, internally, the subscriber."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--minutes', type=float, default=10.0, help='duration of the 1 kHz phase (default 10)')
    parser.add_argument('--slow-seconds', type=float, default=120.0, help='duration of the 10 Hz phase (default 120)')
    parser.add_argument('--serial', default='NAVC3545', help='packaged calibration the node loads')
    parser.add_argument('--baud', type=int, default=115200, help='baud the node is told (default 115200)')
    parser.add_argument('--compare', type=int, metavar='ROUNDS', help='alternate the node and the lean reader')
    parser.add_argument('--round-seconds', type=float, default=60.0, help='1 kHz per process and round (default 60)')
    parser.add_argument('--protocol', choices=('rd2100_binary', 'kvh_fog'), default='rd2100_binary',
                        help='of --compare (default rd2100_binary)')
    parser.add_argument('--sources', nargs='+', metavar='DIR', help='of --compare: the node of each checkout')
    parser.add_argument('--variants', nargs='+', choices=tuple(VARIANTS), help='of --compare: candidates, each too')
    parser.add_argument('--subscriber', metavar='OUT', help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.subscriber:
        return run_subscriber(args.subscriber)
    return compare(args) if args.compare else run(args)


if __name__ == '__main__':
    sys.exit(main())
