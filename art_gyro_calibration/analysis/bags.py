"""rosbag2 recordings as logs: what ``ros2 bag record`` wrote, read without a ROS install (``rosbags``).

A bag is a directory with ``metadata.yaml``, or a single ``.mcap`` or ``.db3`` file. The
gyro's rate is a sensor_msgs/Imu topic's ``angular_velocity.z`` (rad/s) at its header
stamps, by default the node's ``imu/uncalibrated`` (the rate with only the scale factor
applied); the temperature a std_msgs/Float64 topic in degC (``imu/temperature``),
matched to each rate message by the time the bag recorded them (the node publishes both
for every frame: the nearest is the same frame's). A rate table's true rate comes from
``reference`` (std_msgs/Float64 in deg/s matched by recorded time, or
geometry_msgs/TwistStamped or sensor_msgs/Imu angular z in rad/s matched by header
stamp), held from each message to the next as a table's command is; ``extras`` are
further numeric topics, extra columns of the log (matched as the temperature is). A
topic named relatively matches the bag's topic of that name in any namespace, if one.

:class:`BagWriter` writes such a bag (MCAP storage) as messages come: ``calibrate record``'s
frames, or the node's topics as ``calibrate record-topics`` receives them. The gyro's serial number
goes into the bag's ``custom_data`` (a CSV log's into a ``# serial_number:`` line after its
header), where :func:`recorded_serial` reads it back.
"""

from __future__ import annotations

import math
import struct
import time
from collections.abc import Callable, Iterator, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from art_gyro_calibration.log import READ_CHUNK_ROWS, GyroLog, LogError, read_log, read_log_chunks

IMU = 'sensor_msgs/msg/Imu'
FLOAT64 = 'std_msgs/msg/Float64'
TWIST_STAMPED = 'geometry_msgs/msg/TwistStamped'
# Numeric message types an extra topic may have, and the field read.
NUMERIC = {FLOAT64: 'data', 'std_msgs/msg/Float32': 'data', 'sensor_msgs/msg/Temperature': 'temperature',
           'sensor_msgs/msg/FluidPressure': 'fluid_pressure'}
REFERENCE_TYPES = (FLOAT64, TWIST_STAMPED, IMU)
# Rate messages read per chunk while streaming.
BAG_CHUNK_ROWS = READ_CHUNK_ROWS
# Key of the gyro's serial number in a recorded bag's custom_data, and a CSV log's comment line that holds it.
SERIAL_KEY = 'serial_number'
SERIAL_COMMENT = f'# {SERIAL_KEY}: '


@dataclass(frozen=True)
class BagTopics:
    """Which topics of a bag make the log's columns."""

    rate: str = 'imu/uncalibrated'
    temperature: str = 'imu/temperature'
    reference: str | None = None
    extras: Mapping[str, str] = field(default_factory=dict)


def is_bag(path: str | Path) -> bool:
    """A rosbag2: a directory with metadata.yaml, or an .mcap or .db3 file."""
    p = Path(path)
    return (p.is_dir() and (p / 'metadata.yaml').is_file()) or p.suffix in ('.mcap', '.db3')


def _typestore() -> Any:
    from rosbags.typesys import Stores, get_typestore
    return get_typestore(Stores.ROS2_JAZZY)


class _Bag:
    """An open bag: its connections by topic, and its messages of some topics in recorded order."""

    def __init__(self, path: str | Path) -> None:
        from rosbags.rosbag2 import Reader
        self.where = str(path)
        try:
            self.reader = Reader(Path(path))
            self.reader.open()
        except Exception as e:   # rosbags raises its own errors and OSError for a bad or missing bag
            raise LogError(f'{self.where}: cannot read as a rosbag2: {e}') from None
        self.typestore = _typestore()

    def close(self) -> None:
        self.reader.close()

    def __enter__(self) -> _Bag:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def topic(self, name: str, types: tuple[str, ...], what: str) -> Any:
        """The connection of topic ``name`` (relative: in any namespace), which must have one of ``types``."""
        topics = sorted({c.topic for c in self.reader.connections})
        if name.startswith('/'):
            found = [name] if name in topics else []
        else:
            found = [t for t in topics if t == '/' + name or t.endswith('/' + name)]
        if not found:
            raise LogError(f'{self.where}: no topic {name} ({what}) in the bag; its topics: {", ".join(topics)}')
        if len(found) > 1:
            raise LogError(f'{self.where}: topic {name} ({what}) is ambiguous: {", ".join(found)}; name one in full')
        connections = [c for c in self.reader.connections if c.topic == found[0]]
        kinds = {c.msgtype for c in connections}
        if len(kinds) != 1 or not kinds <= set(types):
            raise LogError(f'{self.where}: topic {found[0]} ({what}) has type {", ".join(sorted(kinds))}; '
                           f'expected {" or ".join(types)}')
        return connections

    def count(self, connections: list[Any]) -> int:
        return sum(int(c.msgcount) for c in connections)

    def messages(self, connections: list[Any]) -> Iterator[tuple[Any, int, bytes]]:
        try:
            yield from self.reader.messages(connections=connections)
        except Exception as e:
            raise LogError(f'{self.where}: cannot read its messages: {e}') from None


def _header_stamp(raw: bytes) -> tuple[float, int, str]:
    """Stamp (s), the offset after header.frame_id and the CDR's byte order of a message starting with a Header."""
    order = '<' if raw[1] == 1 else '>'
    sec, nanosec, length = struct.unpack_from(order + 'iII', raw, 4)
    return (sec * 1_000_000_000 + nanosec) * 1e-9, 16 + length, order   # as the node's log writes its stamp


def imu_z(raw: bytes) -> tuple[float, float]:
    """(header stamp in s, angular_velocity.z in rad/s) of a CDR sensor_msgs/Imu, without a full deserialisation.

    After the Header come the orientation (4 doubles), its covariance (9) and the angular
    velocity (x, y, z), 8-byte aligned from the start of the CDR body (byte 4).
    """
    stamp, end, order = _header_stamp(raw)
    body = end - 4
    aligned = 4 + body + (-body) % 8
    return stamp, struct.unpack_from(order + 'd', raw, aligned + 8 * (4 + 9 + 2))[0]


def _twist_z(raw: bytes) -> tuple[float, float]:
    """(header stamp in s, twist.angular.z in rad/s) of a CDR geometry_msgs/TwistStamped."""
    stamp, end, order = _header_stamp(raw)
    body = end - 4
    aligned = 4 + body + (-body) % 8
    return stamp, struct.unpack_from(order + 'd', raw, aligned + 8 * 5)[0]


Floats = NDArray[np.float64]
RateChunks = Iterator[tuple[Floats, Floats]]


def rate_chunks(path: str | Path, topic: str = BagTopics.rate,
                chunk_rows: int = BAG_CHUNK_ROWS) -> tuple[int, RateChunks]:
    """Messages of the rate topic, and an iterator of (stamp s, rate deg/s) chunks: the bag streamed.

    The bag is closed when the iterator ends (or is closed).
    """
    bag = _Bag(path)
    try:
        connections = bag.topic(topic, (IMU,), 'the gyro rate')
    except LogError:
        bag.close()
        raise
    total = bag.count(connections)

    def chunks() -> RateChunks:
        with bag:
            t = np.empty(chunk_rows)
            z = np.empty(chunk_rows)
            n = done = 0
            for _, _, raw in bag.messages(connections):
                t[n], z[n] = _parsed(imu_z, raw, bag.where, topic, done + n)
                n += 1
                if n == chunk_rows:
                    yield _checked(t.copy(), np.degrees(z), bag.where, topic)
                    done += n
                    n = 0
            if n:
                yield _checked(t[:n].copy(), np.degrees(z[:n]), bag.where, topic)
    return total, chunks()


def _parsed(parse: Callable[[bytes], tuple[float, float]], raw: bytes, where: str, topic: str,
            k: int) -> tuple[float, float]:
    """``parse(raw)``, or a :class:`LogError` naming the topic and the message for a message too short for its type."""
    try:
        return parse(raw)
    except (struct.error, IndexError):
        raise LogError(f'{where}: topic {topic}: message {k + 1} ({len(raw)} bytes) is not a CDR message of its '
                       'type') from None


def _checked(t: NDArray[np.float64], rate: NDArray[np.float64], where: str,
             topic: str) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    bad = np.flatnonzero(~np.isfinite(rate))
    if bad.size:
        raise LogError(f'{where}: topic {topic}: angular_velocity.z is not finite at stamp {t[bad[0]]:.6f} s')
    return t, rate


def _scalar_series(bag: _Bag, connections: list[Any], field_name: str) -> tuple[Floats, Floats]:
    """(recorded time s, value) of a numeric topic."""
    times, values = [], []
    msgtype = connections[0].msgtype
    for _, timestamp, raw in bag.messages(connections):
        times.append(timestamp * 1e-9)
        values.append(float(getattr(bag.typestore.deserialize_cdr(raw, msgtype), field_name)))
    return np.array(times), np.array(values)


def _nearest(times: NDArray[np.float64], at: NDArray[np.float64]) -> NDArray[np.int64]:
    """Index into sorted ``times`` of the nearest to each of ``at``."""
    right = np.clip(np.searchsorted(times, at), 1, len(times) - 1) if len(times) > 1 else np.zeros(len(at), int)
    if len(times) == 1:
        return right.astype(np.int64)
    left = right - 1
    return np.where(np.abs(times[left] - at) <= np.abs(times[right] - at), left, right).astype(np.int64)


def _overlap(where: str, topic: str, times: NDArray[np.float64], gyro: NDArray[np.float64],
             held: bool = False) -> None:
    """Refuse a topic without messages, or whose times miss the gyro's (``held``: a value holds on after its time)."""
    if not len(times):
        raise LogError(f'{where}: topic {topic} has no messages')
    if times[0] > gyro[-1] or (times[-1] < gyro[0] and not held):
        raise LogError(f'{where}: topic {topic}\'s stamps ({times[0]:.3f}..{times[-1]:.3f} s) do not overlap the '
                       f'gyro\'s ({gyro[0]:.3f}..{gyro[-1]:.3f} s)')


def read_bag(path: str | Path, topics: BagTopics = BagTopics(),
             warn: Callable[[str], None] = lambda message: None) -> GyroLog:
    """A bag as a log in deg/s and degC (see the module's doc for how the topics are matched).

    Rate messages before the first reference message have no true rate: they are left out,
    and ``warn`` is told how many.
    """
    with _Bag(path) as bag:
        where = bag.where
        rate_conns = bag.topic(topics.rate, (IMU,), 'the gyro rate')
        temp_conns = bag.topic(topics.temperature, (FLOAT64,), 'the gyro temperature, degC')
        ref_conns = None if topics.reference is None else \
            bag.topic(topics.reference, REFERENCE_TYPES, 'the rate table\'s true rate')
        extra_conns = {name: bag.topic(topic, tuple(NUMERIC), f'extra column {name}')
                       for name, topic in topics.extras.items()}
        stamps, recorded, rates = [], [], []
        for k, (_, timestamp, raw) in enumerate(bag.messages(rate_conns)):
            s, z = _parsed(imu_z, raw, where, topics.rate, k)
            stamps.append(s)
            recorded.append(timestamp * 1e-9)
            rates.append(z)
        if not stamps:
            raise LogError(f'{where}: topic {topics.rate} has no messages')
        t, seen = np.array(stamps), np.array(recorded)
        rate = np.degrees(np.array(rates))
        order = np.argsort(seen, kind='stable')   # matched by recorded time, which the bag's order follows
        if np.any(np.diff(t) <= 0):
            bad = int(np.flatnonzero(np.diff(t) <= 0)[0])
            raise LogError(f'{where}: topic {topics.rate}: stamp {t[bad + 1]:.9f} s does not follow '
                           f'{t[bad]:.9f} s (message {bad + 2})')
        _checked(t, rate, where, topics.rate)
        temp_times, temp_values = _scalar_series(bag, temp_conns, 'data')
        _overlap(where, topics.temperature, temp_times, seen[order])
        temp_c = temp_values[_nearest(temp_times, seen)]
        extras = {}
        for name, conns in extra_conns.items():
            times, values = _scalar_series(bag, conns, NUMERIC[conns[0].msgtype])
            _overlap(where, topics.extras[name], times, seen[order])
            extras[name] = values[_nearest(times, seen)]
        ref_rate = None
        keep = np.ones(len(t), dtype=bool)
        if ref_conns is not None and topics.reference is not None:
            ref_times, ref_values, gyro_times = _reference(bag, ref_conns, topics.reference, t, seen)
            _overlap(where, topics.reference, ref_times, np.sort(gyro_times), held=True)
            after = np.searchsorted(ref_times, gyro_times, side='right') - 1
            keep = after >= 0
            ref_rate = ref_values[np.maximum(after, 0)]
            if not keep.all():
                warn(f'{where}: {np.count_nonzero(~keep)} gyro messages before the first {topics.reference} '
                     'message have no true rate: left out')
        log = GyroLog(t, rate, temp_c, ref_rate, extras)
        return log if keep.all() else log.slice(keep)


def _reference(bag: _Bag, connections: list[Any], topic: str, stamps: NDArray[np.float64],
               recorded: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    """The reference's times and deg/s, and the gyro's times on the same clock (stamps, or recorded times)."""
    msgtype = connections[0].msgtype
    if msgtype == FLOAT64:
        times, values = _scalar_series(bag, connections, 'data')
        return times, values, recorded
    parse = imu_z if msgtype == IMU else _twist_z
    pairs = [_parsed(parse, raw, bag.where, topic, k) for k, (_, _, raw) in enumerate(bag.messages(connections))]
    times = np.array([p[0] for p in pairs])
    values = np.degrees(np.array([p[1] for p in pairs]))
    order = np.argsort(times, kind='stable')
    return times[order], values[order], stamps


def read_any_log(path: str | Path, rate_scale_factor: float | None = None, temp_scale_factor: float | None = None,
                 topics: BagTopics = BagTopics(), warn: Callable[[str], None] = lambda message: None) -> GyroLog:
    """A CSV log (raw counts scaled by the factors) or a bag (already in deg/s and degC)."""
    if is_bag(path):
        return read_bag(path, topics, warn)
    return read_log(path, rate_scale_factor, temp_scale_factor)


def read_any_chunks(path: str | Path, rate_scale_factor: float | None = None, temp_scale_factor: float | None = None,
                    topics: BagTopics = BagTopics(), chunk_rows: int = READ_CHUNK_ROWS,
                    warn: Callable[[str], None] = lambda message: None) -> Iterator[GyroLog]:
    """A log chunk by chunk: a CSV streamed, a bag read whole and cut into chunks."""
    if not is_bag(path):
        yield from read_log_chunks(path, rate_scale_factor, temp_scale_factor, chunk_rows)
        return
    log = read_bag(path, topics, warn)
    for start in range(0, len(log), chunk_rows):
        yield log.slice(slice(start, start + chunk_rows))


def csv_rate_chunks(path: str | Path, rate_scale_factor: float | None,
                    temp_scale_factor: float | None) -> tuple[float, RateChunks]:
    """Rows expected (estimated from the file's size and its first lines) and (t, rate deg/s) chunks of a CSV."""
    size = Path(path).stat().st_size
    with open(path, 'rb') as f:
        head = f.read(1 << 16)
    lines = max(head.count(b'\n'), 1)
    estimate = size / (len(head) / lines) if head else math.nan
    return estimate, ((c.t, c.rate_dps) for c in read_log_chunks(path, rate_scale_factor, temp_scale_factor))


def recorded_serial(path: str | Path) -> str | None:
    """The serial number ``calibrate record`` kept in a log (None if it kept none, or the log is not one of its)."""
    if is_bag(path):
        with _Bag(path) as bag:
            metadata = getattr(bag.reader.storage, 'metadata', None)   # a bag directory's metadata.yaml
        value = (getattr(metadata, 'custom', None) or {}).get(SERIAL_KEY)
        return str(value) if value else None
    try:
        with open(path, encoding='utf-8') as f:
            f.readline()   # the header
            second = f.readline()
    except (OSError, UnicodeDecodeError):
        return None   # reading the log itself says what is wrong with it
    return (second[len(SERIAL_COMMENT):].strip() or None) if second.startswith(SERIAL_COMMENT) else None


class BagWriter:
    """A rosbag2 (MCAP) of the node's ``imu/uncalibrated`` (sensor_msgs/Imu) and ``imu/temperature`` (Float64).

    What :func:`read_bag` reads by default. Messages are either serialised here from a frame
    (:meth:`write_frame`) or written as received (:meth:`write_cdr`), in the node's ``namespace``. ``path`` is a
    directory that must not exist.
    """

    def __init__(self, path: str | Path, serial: str | None = None, frame_id: str = 'imu_link',
                 namespace: str = '/') -> None:
        from rosbags.rosbag2 import StoragePlugin, Writer
        self.typestore = _typestore()
        self._writer = Writer(Path(path), version=Writer.VERSION_LATEST, storage_plugin=StoragePlugin.MCAP)
        if serial:
            self._writer.set_custom_data(SERIAL_KEY, serial)
        self._writer.open()
        self.connections = {topic: self._writer.add_connection(f'{namespace.rstrip("/")}/{topic}', msgtype,
                                                               typestore=self.typestore)
                            for topic, msgtype in ((BagTopics.rate, IMU), (BagTopics.temperature, FLOAT64))}
        self.count = 0   # messages of the rate topic written
        types = self.typestore.types
        header = types['std_msgs/msg/Header'](types['builtin_interfaces/msg/Time'](0, 0), frame_id)
        vector = types['geometry_msgs/msg/Vector3']
        unmeasured = np.zeros(9)
        unmeasured[0] = -1.0   # REP 145: not measured, as the node says of orientation and acceleration
        self._imu = types[IMU](header, types['geometry_msgs/msg/Quaternion'](0.0, 0.0, 0.0, 1.0), unmeasured,
                               vector(0.0, 0.0, 0.0), np.zeros(9), vector(0.0, 0.0, 0.0), unmeasured.copy())
        self._float = types[FLOAT64]

    def write_frame(self, stamp_ns: int, rate_dps: float, temp_c: float) -> None:
        """One frame as the node publishes it: the scaled rate (rad/s) at its stamp, and its temperature."""
        now = time.time_ns()
        self._imu.header.stamp.sec, self._imu.header.stamp.nanosec = divmod(stamp_ns, 1_000_000_000)
        self._imu.angular_velocity.z = math.radians(rate_dps)
        self.write_cdr(BagTopics.rate, now, self.typestore.serialize_cdr(self._imu, IMU))
        self.write_cdr(BagTopics.temperature, now, self.typestore.serialize_cdr(self._float(temp_c), FLOAT64))

    def write_cdr(self, topic: str, recorded_ns: int, raw: bytes | memoryview) -> None:
        """A message of ``topic`` (:attr:`BagTopics.rate` or ``.temperature``), CDR-serialised, received at a time."""
        self._writer.write(self.connections[topic], recorded_ns, raw)
        self.count += topic == BagTopics.rate

    def close(self) -> None:
        """Finish the bag (its summary and metadata.yaml): readable from then on."""
        self._writer.close()
