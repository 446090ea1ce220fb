"""Resident memory of a running ``gyro_node``, and what holds it.

``python bench/bench_node_memory.py [--seconds S] [--runs N] [--subscriber]``: each run starts ``gyro_node``
(as ``gyro_node`` does: ``python -m art_gyro_calibration.ros.node``) against a simulated RD2100 at 10 Hz
with its start-up static bias, lets it run ``--seconds``, then reads the node's ``/proc/<pid>/status``
(VmRSS, VmHWM) and ``smaps_rollup`` (anonymous and file-backed). ``--subscriber`` also runs ``imu_echo``
in the node's domain: its writers then have a reliable reader to send to and hear from, as on a robot.
``--floor`` runs, in place of ``gyro_node``, a bare rclpy node with the same runtime imports (numpy, yaml,
pyserial, rclpy, the messages), the same publishers, service, timers and executor, publishing an Imu and a
Float64 at 10 Hz, and none of this package's code: what any Python node of this shape costs. ``--lean`` runs
``bench_node.LEAN``, the leanest reader-publisher (the package's parser, an Imu per frame, no executor), on the
same fake gyro. ``--stages``
instead builds the node step by step in one interpreter and prints VmRSS after each step (imports, DDS
participant, spinning).
"""

from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from art_gyro_calibration.fake_gyro import FakeGyro

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_node import LEAN   # noqa: E402  # the bench directory, as above

STAGES = '''
import json, os, sys, threading, time
def rss():
    return int(open('/proc/self/status').read().split('VmRSS:')[1].split()[0]) / 1024
out = {'python': rss()}
import numpy
out['+ numpy'] = rss()
import yaml, serial
out['+ yaml, pyserial'] = rss()
import rclpy
out['+ rclpy'] = rss()
from sensor_msgs.msg import Imu
from std_msgs.msg import Bool, Float64
from diagnostic_msgs.msg import DiagnosticArray
from std_srvs.srv import Trigger
out['+ message modules'] = rss()
import art_gyro_calibration.ros.node as n
out['+ art_gyro_calibration (node module)'] = rss()
if sys.argv[1] == 'block':
    sys.modules.setdefault(n._ROSIDL_GENERATOR, None)   # as main() does
    n.use_own_fastdds_profile()
argv = ['gyro_node', '--ros-args', '-p', 'serial_number:=NAVC3545', '-p', 'port:=/nonexistent']
rclpy.init(args=argv)
out['+ rclpy.init'] = rss()
node = n.GyroNode(argv)
out['+ GyroNode (DDS participant, type supports, entities)'] = rss()
from rclpy.executors import MultiThreadedExecutor
executor = MultiThreadedExecutor(num_threads=3)
executor.add_node(node)
threading.Thread(target=executor.spin, daemon=True).start()
time.sleep(5.0)
out['spinning 5 s'] = rss()
print(json.dumps(out))
node.close()
executor.shutdown()
rclpy.try_shutdown()
'''

# --floor: gyro_node's ROS shape without this package (the code generator kept out as gyro_node's main() does).
FLOOR = '''
import sys
sys.modules['rosidl_generator_py.generate_py_impl'] = None
import numpy, yaml, serial
import rclpy
from rclpy.callback_groups import MutuallyExclusiveCallbackGroup
from rclpy.executors import ExternalShutdownException, MultiThreadedExecutor
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from diagnostic_msgs.msg import DiagnosticArray
from sensor_msgs.msg import Imu
from std_msgs.msg import Bool, Float64
from std_srvs.srv import Trigger
rclpy.init(args=sys.argv)
node = Node('gyro_node')
imu_pub = node.create_publisher(Imu, 'imu/data_raw', 10)
temp_pub = node.create_publisher(Float64, 'imu/temperature', 10)
node.create_publisher(Bool, 'imu/is_calibrated', QoSProfile(depth=1, durability=DurabilityPolicy.TRANSIENT_LOCAL,
                                                             reliability=ReliabilityPolicy.RELIABLE)).publish(Bool())
diag_pub = node.create_publisher(DiagnosticArray, '/diagnostics', 10)
node.create_service(Trigger, 'imu/static_bias', lambda request, response: response)
imu, temp = Imu(), Float64()
def frame():
    imu.header.stamp = node.get_clock().now().to_msg()
    imu_pub.publish(imu)
    temp_pub.publish(temp)
node.create_timer(0.1, frame)
node.create_timer(1.0, lambda: diag_pub.publish(DiagnosticArray()), callback_group=MutuallyExclusiveCallbackGroup())
node.create_timer(0.5, lambda: None)
executor = MultiThreadedExecutor(num_threads=3)
executor.add_node(node)
try:
    executor.spin()
except (KeyboardInterrupt, ExternalShutdownException):
    pass
'''


def _proc_kib(pid: int, name: str, key: str) -> float:
    text = Path(f'/proc/{pid}/{name}').read_text()
    return float(text.split(key + ':')[1].split()[0])


def run_node(seconds: float, subscriber: bool = False, floor: bool = False,
             lean: bool = False) -> dict[str, float]:
    """One node against a fake gyro (and an ``imu_echo`` if ``subscriber``): its memory after ``seconds``, in MiB.

    ``floor``: the bare node of :data:`FLOOR` instead of ``gyro_node``; ``lean``: ``bench_node.LEAN``.
    """
    with tempfile.TemporaryDirectory() as tmp, FakeGyro('NAVC3545', profile='0', seed=1) as fake:
        env = dict(os.environ, ROS_DOMAIN_ID=str(100 + os.getpid() % 100), ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST')
        echo = (subprocess.Popen([sys.executable, '-m', 'art_gyro_calibration.ros.monitor', '--every', '1000000'],
                                 env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
                if subscriber else None)
        with open(Path(tmp) / 'node.log', 'wb') as out:
            cmd = ([sys.executable, '-c', FLOOR] if floor else
                   [sys.executable, '-c', LEAN, fake.path, '9600', 'binary', '0.00305'] if lean else
                   [sys.executable, '-m', 'art_gyro_calibration.ros.node', '--ros-args',
                    '-p', 'serial_number:=NAVC3545', '-p', f'port:={fake.path}'])
            proc = subprocess.Popen(cmd, env=env, stdout=out, stderr=subprocess.STDOUT)
        try:
            time.sleep(seconds)
            assert proc.poll() is None, (Path(tmp) / 'node.log').read_text()
            log = (Path(tmp) / 'node.log').read_text()
            assert floor or lean or 'static bias: StaticBiasDrift=' in log, log   # frames corrected, the bias taken
            mib = {key: _proc_kib(proc.pid, 'status', key) / 1024 for key in ('VmRSS', 'VmHWM')}
            mib.update({key: _proc_kib(proc.pid, 'smaps_rollup', key) / 1024
                        for key in ('Anonymous', 'Pss_File', 'Shared_Clean')})
        finally:
            for child in filter(None, (proc, echo)):
                child.send_signal(2)
                child.wait(30)
    return mib


def main() -> int:
    """Measure and print."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--seconds', type=float, default=20.0)
    parser.add_argument('--runs', type=int, default=3)
    parser.add_argument('--subscriber', action='store_true', help='an imu_echo subscribed to the node meanwhile')
    parser.add_argument('--floor', action='store_true', help='a bare rclpy node of the same shape instead')
    parser.add_argument('--lean', action='store_true', help='the lean reader of bench_node.py instead')
    parser.add_argument('--alternate', action='store_true', help='gyro_node and the lean reader in turn, each --runs')
    parser.add_argument('--stages', action='store_true',
                        help="VmRSS step by step, without and with main()'s block and profile")
    args = parser.parse_args()
    if args.stages:
        for mode in ('no block', 'block'):
            result = subprocess.run([sys.executable, '-c', STAGES, mode.replace(' ', '_')], capture_output=True,
                                    text=True, check=True)
            print(mode + ': ' + result.stdout.splitlines()[0])
        return 0
    kinds = ('gyro_node', 'lean') if args.alternate else ('lean' if args.lean else 'floor' if args.floor else
                                                          'gyro_node',)
    runs: dict[str, list[dict[str, float]]] = {kind: [] for kind in kinds}
    for _ in range(args.runs):
        for kind in kinds:
            runs[kind].append(run_node(args.seconds, args.subscriber, kind == 'floor', kind == 'lean'))
    for kind, results in runs.items():
        for key in results[0]:
            values = sorted(r[key] for r in results)
            print(f'{kind} {key}: {statistics.median(values):.1f} MiB median ({values[0]:.1f}-{values[-1]:.1f})')
    print(f'({args.runs} runs of each of {", ".join(kinds)} at 10 Hz for {args.seconds:g} s'
          + (', in turn' if args.alternate else '') + (', imu_echo subscribed)' if args.subscriber else ')'))
    return 0


if __name__ == '__main__':
    sys.exit(main())
