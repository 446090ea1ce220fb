"""rosbag2 logs: bags written here with ``rosbags`` (MCAP and sqlite3) read as the node's CSV log of the same run."""

import json
import math
import shutil
from pathlib import Path

import numpy as np
import pytest
from rosbags.rosbag2 import StoragePlugin, Writer
from rosbags.typesys import Stores, get_typestore

from art_gyro_calibration.analysis.bags import BagTopics, imu_z, is_bag, rate_chunks, read_bag
from art_gyro_calibration.analysis.cli import main
from art_gyro_calibration.calibration import load_calibration, load_packaged_calibration
from art_gyro_calibration.log import LogError, read_log

TS = get_typestore(Stores.ROS2_JAZZY)
T = TS.types
EPOCH_NS = 1_700_000_000_123_456_789


def _stamp(ns):
    return T['builtin_interfaces/msg/Time'](sec=ns // 10 ** 9, nanosec=ns % 10 ** 9)


def imu_message(ns, z_rad_s, frame_id='imu_link'):
    v3, zeros = T['geometry_msgs/msg/Vector3'], np.zeros(9)
    return T['sensor_msgs/msg/Imu'](
        header=T['std_msgs/msg/Header'](stamp=_stamp(ns), frame_id=frame_id),
        orientation=T['geometry_msgs/msg/Quaternion'](x=0.0, y=0.0, z=0.0, w=1.0), orientation_covariance=zeros,
        angular_velocity=v3(x=0.0, y=0.0, z=z_rad_s), angular_velocity_covariance=zeros,
        linear_acceleration=v3(x=0.0, y=0.0, z=0.0), linear_acceleration_covariance=zeros)


def twist_message(ns, z_rad_s):
    v3 = T['geometry_msgs/msg/Vector3']
    return T['geometry_msgs/msg/TwistStamped'](
        header=T['std_msgs/msg/Header'](stamp=_stamp(ns), frame_id='table'),
        twist=T['geometry_msgs/msg/Twist'](linear=v3(x=0.0, y=0.0, z=0.0), angular=v3(x=0.0, y=0.0, z=z_rad_s)))


def write_bag(path, log, stamps_ns, storage=StoragePlugin.MCAP, namespace='', reference='float64', extras=(),
              temperature_type='std_msgs/msg/Float64'):
    """The node's topics for ``log`` at ``stamps_ns``: imu/uncalibrated, then imu/temperature recorded 50 us later.

    The reference (``ref_rate``) as std_msgs/Float64 deg/s recorded with the rate, or a TwistStamped /
    Imu in rad/s stamped 3 ms before the gyro's sample and recorded 20 ms late (matched by stamp).
    """
    with Writer(path, version=9, storage_plugin=storage) as w:
        rate = w.add_connection(f'{namespace}/imu/uncalibrated', 'sensor_msgs/msg/Imu', typestore=TS)
        temp = w.add_connection(f'{namespace}/imu/temperature', temperature_type, typestore=TS)
        kinds = {'float64': 'std_msgs/msg/Float64', 'twist': 'geometry_msgs/msg/TwistStamped',
                 'imu': 'sensor_msgs/msg/Imu'}
        ref = w.add_connection('/table/rate', kinds[reference], typestore=TS) if log.ref_rate is not None else None
        extra = {name: w.add_connection(f'/{name}', 'std_msgs/msg/Float64', typestore=TS) for name in extras}
        for k in range(len(log)):
            ns = int(stamps_ns[k])
            w.write(rate, ns + 1000, TS.serialize_cdr(imu_message(ns, math.radians(log.rate_dps[k])),
                                                      'sensor_msgs/msg/Imu'))
            value = T[temperature_type](data=float(log.temp_c[k])) if 'Float64' in temperature_type \
                else T[temperature_type]()
            w.write(temp, ns + 51000, TS.serialize_cdr(value, temperature_type))
            for name, conn in extra.items():
                value = T['std_msgs/msg/Float64'](data=float(log.extras[name][k]))
                w.write(conn, ns + 2000, TS.serialize_cdr(value, 'std_msgs/msg/Float64'))
            if ref is not None and (k == 0 or log.ref_rate[k] != log.ref_rate[k - 1]):
                if reference == 'float64':
                    msg = T['std_msgs/msg/Float64'](data=float(log.ref_rate[k]))
                    w.write(ref, ns + 500, TS.serialize_cdr(msg, 'std_msgs/msg/Float64'))
                else:
                    z = math.radians(log.ref_rate[k])
                    msg = twist_message(ns - 3_000_000, z) if reference == 'twist' else imu_message(ns - 3_000_000, z)
                    w.write(ref, ns + 20_000_000, TS.serialize_cdr(msg, kinds[reference]))
    return path


def tiny_bag(path, reference_type, reference):
    """Ten still gyro messages at 10 Hz (rate, temperature) and ``/table/rate`` of ``reference_type``.

    ``reference(k, ns)`` gives the k-th reference message (written 2 ns after the gyro's), or None for none.
    """
    with Writer(path, version=9, storage_plugin=StoragePlugin.MCAP) as w:
        rate = w.add_connection('/imu/uncalibrated', 'sensor_msgs/msg/Imu', typestore=TS)
        temp = w.add_connection('/imu/temperature', 'std_msgs/msg/Float64', typestore=TS)
        ref = w.add_connection('/table/rate', reference_type, typestore=TS)
        for k in range(10):
            ns = EPOCH_NS + k * 10 ** 8
            w.write(rate, ns, TS.serialize_cdr(imu_message(ns, 0.0), 'sensor_msgs/msg/Imu'))
            w.write(temp, ns + 1, TS.serialize_cdr(T['std_msgs/msg/Float64'](data=25.0), 'std_msgs/msg/Float64'))
            message = reference(k, ns)
            if message is not None:
                w.write(ref, ns + 2, TS.serialize_cdr(message, reference_type))
    return path


@pytest.fixture(scope='module')
def run(tmp_path_factory):
    """A simulated 2 h rate-table run at 2 Hz: its CSV log, in physical units, at epoch stamps."""
    d = tmp_path_factory.mktemp('bags')
    raw = d / 'RAW.csv'
    assert main(['simulate', '--serial', 'NAVC4058', '--hours', '2', '--rate-hz', '2', '--seed', '4',
                 '--effect', 'shupe', '--out', str(raw)]) == 0
    cal = load_packaged_calibration('NAVC4058')
    log = read_log(raw, cal.rate_scale_factor, cal.temp_scale_factor)
    # As the node's raw log holds them: epoch stamps (ns), the rate and temperature scaled.
    ns = EPOCH_NS + np.round(log.t * 1e9).astype(np.int64)
    t = ns * 1e-9
    csv = d / 'LOG.csv'
    with open(csv, 'w') as f:
        f.write('t,rate_dps,temp_c,ref_rate,supply_v\n')
        for row in zip(t, log.rate_dps, log.temp_c, log.ref_rate, log.extras['supply_v']):
            f.write(','.join(repr(float(v)) for v in row) + '\n')
    return d, read_log(csv), ns


def test_bag_forms_are_recognised(run, tmp_path):
    _, log, ns = run
    bag = write_bag(tmp_path / 'b', log.slice(slice(0, 20)), ns[:20])
    single = tmp_path / 'single.mcap'
    shutil.copy(next(bag.glob('*.mcap')), single)
    db3 = write_bag(tmp_path / 'c', log.slice(slice(0, 20)), ns[:20], StoragePlugin.SQLITE3)
    assert is_bag(bag) and is_bag(single) and is_bag(next(db3.glob('*.db3'))) and not is_bag(run[0] / 'LOG.csv')
    for path in (bag, single, db3, next(db3.glob('*.db3'))):
        got = read_bag(path)
        assert np.array_equal(got.t, log.t[:20])
        assert np.allclose(got.rate_dps, log.rate_dps[:20], rtol=1e-15, atol=1e-15)
        assert np.array_equal(got.temp_c, log.temp_c[:20])


def test_imu_fast_path_reads_what_the_deserialiser_reads():
    for frame_id in ('', 'a', 'imu_link', 'x' * 13):
        for order in ('little', 'big'):
            msg = imu_message(EPOCH_NS, -0.123456789, frame_id)
            raw = TS.serialize_cdr(msg, 'sensor_msgs/msg/Imu', little_endian=order == 'little')
            assert imu_z(bytes(raw)) == (EPOCH_NS * 1e-9, -0.123456789)


@pytest.mark.parametrize('reference', ['float64', 'twist', 'imu'])
def test_reference_topic_is_matched_by_stamp(run, tmp_path, reference):
    _, log, ns = run
    part = log.slice(slice(0, 1200))
    part_ns = ns[:1200]
    bag = write_bag(tmp_path / 'b', part, part_ns, reference=reference, extras=('supply_v',))
    got = read_bag(bag, BagTopics(reference='/table/rate', extras={'supply_v': 'supply_v'}))
    assert np.allclose(got.ref_rate, part.ref_rate, rtol=1e-12, atol=1e-12)
    assert np.array_equal(got.extras['supply_v'], part.extras['supply_v'])


def test_the_bag_and_the_csv_of_a_run_give_the_same_calibration(run, tmp_path):
    d, log, ns = run
    common = ['--rows', '3', '--columns', '2', '--serial', 'NAVC4058', '--draws', '40']
    for name, source in (('csv', d / 'LOG.csv'),
                         ('bag', write_bag(tmp_path / 'bag', log, ns, StoragePlugin.SQLITE3, namespace='/robot',
                                           extras=('supply_v',)))):
        extra = [] if name == 'csv' else ['--reference-topic', '/table/rate', '--extra-topic', 'supply_v=/supply_v']
        assert main(['fit', str(source), *common, *extra, '--out', str(tmp_path / f'{name}.yaml'),
                     '--report', str(tmp_path / f'{name}.json')]) == 0
    csv, bag = (load_calibration(tmp_path / f'{n}.yaml') for n in ('csv', 'bag'))
    assert np.allclose(bag.polynomial.coefficients, csv.polynomial.coefficients, rtol=1e-9, atol=0)
    assert [t.signal for t in bag.terms] == [t.signal for t in csv.terms] != []
    for a, b in zip(bag.terms, csv.terms):
        assert np.allclose(a.coefficients, b.coefficients, rtol=1e-9)
    reports = [json.loads((tmp_path / f'{n}.json').read_text()) for n in ('csv', 'bag')]
    for stage, errors in reports[0]['errors'].items():
        assert errors == pytest.approx(reports[1]['errors'][stage], rel=1e-9)


def test_apply_and_replay_read_a_bag(run, tmp_path, capsys):
    d, log, ns = run
    part = log.slice(slice(0, 2000))
    part_ns = ns[:2000]
    bag = write_bag(tmp_path / 'b', part, part_ns)
    csv = tmp_path / 'part.csv'
    with open(csv, 'w') as f:
        f.write('t,rate_dps,temp_c\n')
        for row in zip(part.t, part.rate_dps, part.temp_c):
            f.write(','.join(repr(float(v)) for v in row) + '\n')
    cal = str(Path(__file__).resolve().parents[2] / 'config' / 'NAVC4058.yaml')
    assert main(['apply', str(csv), '--calibration', cal, '--out', str(tmp_path / 'a.csv')]) == 0
    assert main(['apply', str(bag), '--calibration', cal, '--out', str(tmp_path / 'b.csv')]) == 0
    assert (tmp_path / 'a.csv').read_text() == (tmp_path / 'b.csv').read_text()
    ref_bag = write_bag(tmp_path / 'r', part, part_ns, reference='twist')
    capsys.readouterr()
    assert main(['replay', str(ref_bag), '--calibration', cal, '--reference-topic', 'table/rate']) == 0
    assert 'extended' in capsys.readouterr().out


def test_clear_errors_name_the_topic(run, tmp_path):
    _, log, ns = run
    part = log.slice(slice(0, 50))
    part_ns = ns[:50]
    bag = write_bag(tmp_path / 'b', part, part_ns)
    with pytest.raises(LogError, match='no topic imu/nothing .*its topics: /imu/temperature, /imu/uncalibrated'):
        read_bag(bag, BagTopics(rate='imu/nothing'))
    with pytest.raises(LogError, match='topic /imu/temperature .* has type std_msgs/msg/Float64; expected '
                                       'sensor_msgs/msg/Imu'):
        read_bag(bag, BagTopics(rate='imu/temperature'))
    wrong = write_bag(tmp_path / 'w', part, part_ns, temperature_type='std_msgs/msg/Empty')
    with pytest.raises(LogError, match='topic /imu/temperature .*std_msgs/msg/Empty; expected std_msgs/msg/Float64'):
        read_bag(wrong)
    shifted = write_bag(tmp_path / 's', part, part_ns, reference='twist')
    # A reference stamped an hour later than the gyro: no overlap.
    tiny_bag(tmp_path / 'x', 'geometry_msgs/msg/TwistStamped', lambda k, ns: twist_message(ns + 3600 * 10 ** 9, 0.0))
    with pytest.raises(LogError, match='topic /table/rate\'s stamps .* do not overlap the gyro\'s'):
        read_bag(tmp_path / 'x', BagTopics(reference='/table/rate'))
    # A table's command holds: one given before the recording began covers it.
    assert len(read_bag(shifted, BagTopics(reference='/table/rate'))) == len(part)
    (tmp_path / 'broken.mcap').write_bytes(b'not a bag')
    with pytest.raises(LogError, match='broken.mcap: cannot read as a rosbag2'):
        read_bag(tmp_path / 'broken.mcap')


def test_a_reference_that_starts_late_leaves_the_rows_before_it_out_and_says_so(run, tmp_path):
    _, log, ns = run
    part = log.slice(slice(0, 100))
    part_ns = ns[:100]
    bag = write_bag(tmp_path / 'b', part, part_ns, reference='twist')
    told = []
    # The twist is stamped 3 ms before each gyro sample: every row has its true rate.
    got = read_bag(bag, BagTopics(reference='table/rate'), told.append)
    assert len(got) == len(part) and not told
    tiny_bag(tmp_path / 'late', 'std_msgs/msg/Float64',
             lambda k, ns: T['std_msgs/msg/Float64'](data=10.0) if k >= 4 else None)
    got = read_bag(tmp_path / 'late', BagTopics(reference='/table/rate'), told.append)
    assert len(got) == 6 and np.all(got.ref_rate == 10.0)
    assert told == [f'{tmp_path / "late"}: 4 gyro messages before the first /table/rate message have no true rate: '
                    'left out']


def test_rate_chunks_stream_the_bag(run, tmp_path):
    _, log, ns = run
    part = log.slice(slice(0, 1000))
    part_ns = ns[:1000]
    bag = write_bag(tmp_path / 'b', part, part_ns)
    total, chunks = rate_chunks(bag, chunk_rows=300)
    got = list(chunks)
    assert total == 1000 and [len(c[0]) for c in got] == [300, 300, 300, 100]
    assert np.array_equal(np.concatenate([c[0] for c in got]), part.t)
    assert np.allclose(np.concatenate([c[1] for c in got]), part.rate_dps, rtol=1e-15, atol=1e-15)


def test_a_truncated_message_is_named(tmp_path):
    with Writer(tmp_path / 'b', version=9, storage_plugin=StoragePlugin.MCAP) as w:
        rate = w.add_connection('/imu/uncalibrated', 'sensor_msgs/msg/Imu', typestore=TS)
        temp = w.add_connection('/imu/temperature', 'std_msgs/msg/Float64', typestore=TS)
        for k in range(3):
            raw = bytes(TS.serialize_cdr(imu_message(EPOCH_NS + k, 0.0), 'sensor_msgs/msg/Imu'))
            w.write(rate, EPOCH_NS + k, raw if k < 2 else raw[:60])
            w.write(temp, EPOCH_NS + k, TS.serialize_cdr(T['std_msgs/msg/Float64'](data=25.0), 'std_msgs/msg/Float64'))
    with pytest.raises(LogError, match=r'topic imu/uncalibrated: message 3 \(60 bytes\) is not a CDR message'):
        read_bag(tmp_path / 'b')
    with pytest.raises(LogError, match=r'topic imu/uncalibrated: message 3 \(60 bytes\)'):
        list(rate_chunks(tmp_path / 'b', chunk_rows=2)[1])
