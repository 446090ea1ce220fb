"""Typed faces of the few rclpy calls the node makes whose Jazzy wheels carry no annotations.

rclpy ships ``py.typed`` but leaves some functions unannotated (``Node.get_logger``, the
``QoSProfile`` constructor): called from typed code they are errors under ``mypy --strict``.
Each is called here once, with the type it has. And :class:`SerializedMessage`, a message
published as its serialized bytes (``Publisher.publish`` takes them).
"""

from __future__ import annotations

import copy
import struct
from collections.abc import Sequence
from typing import Any, Protocol, cast

from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from rclpy.serialization import serialize_message

# Distinct values put in one field at a time to find where its bytes lie in the serialized message.
_MARKERS = {'d': -1.2345678901234567e-301, 'i': -0x5A3C1D2E, 'I': 0xA5C3E1D2}


class Logger(Protocol):
    """rclpy's node logger (``RcutilsLogger``) as the node uses it; each call says whether it logged."""

    def info(self, message: str, **kwargs: Any) -> bool:
        """Log at INFO; ``kwargs`` as rclpy's (``throttle_duration_sec``, ``once``, ...)."""

    def warning(self, message: str, **kwargs: Any) -> bool:
        """Log at WARN."""

    def error(self, message: str, **kwargs: Any) -> bool:
        """Log at ERROR."""


def logger(node: Node) -> Logger:
    """The logger of ``node`` (its ``get_logger``), typed."""
    return cast(Logger, node.get_logger())   # type: ignore[no-untyped-call]  # rclpy: get_logger unannotated


def qos_profile(depth: int, **policies: DurabilityPolicy | ReliabilityPolicy) -> QoSProfile:
    """``QoSProfile(depth=depth, **policies)``, typed (``durability=``, ``reliability=``)."""
    return QoSProfile(depth=depth, **policies)   # type: ignore[no-untyped-call]  # rclpy: __init__ unannotated


class SerializedMessage:
    """A message kept serialized (CDR, little-endian) whose scalar fields are written in place, published as bytes.

    Why: rclpy's ``publish`` of a message object converts every field to C on each call; the node publishes
    1000 messages a second of which only the stamp and a few numbers change. Publishing the bytes skips the
    conversion (measured in doc/benchmark.md). ``fields`` are paths into ``template`` (``'header.stamp.sec'``,
    ``'angular_velocity_covariance[8]'``) of float64, int32 or uint32 fields; where each lies is found once, by
    serializing the template with a marker in it, so nothing here knows the message's layout.
    """

    __slots__ = ('buffer', '_fields')

    def __init__(self, template: Any, fields: Sequence[str]) -> None:
        self.buffer = bytearray(serialize_message(template))
        if self.buffer[:2] != b'\x00\x01':
            raise ValueError(f'{type(template).__name__} serialized as {bytes(self.buffer[:2])!r}, not CDR_LE')
        self._fields: dict[str, tuple[struct.Struct, int]] = {}
        for field in fields:
            value = _get(template, field)
            code = 'd' if isinstance(value, float) else 'I' if field.endswith('nanosec') else 'i'
            marked = copy.deepcopy(template)
            _set(marked, field, _MARKERS[code])
            packed = struct.pack('<' + code, _MARKERS[code])
            serialized = serialize_message(marked)
            offset = serialized.find(packed)
            if offset < 0 or serialized.find(packed, offset + 1) >= 0:
                raise ValueError(f'field {field} of {type(template).__name__} not found once in its serialized bytes')
            self._fields[field] = (struct.Struct('<' + code), offset)

    def put(self, field: str, value: float) -> None:
        """Write ``value`` into ``field`` (one of those given at construction)."""
        packer, offset = self._fields[field]
        packer.pack_into(self.buffer, offset, value)

    def data(self) -> bytes:
        """The message as it stands, to publish."""
        return bytes(self.buffer)


def _parts(field: str) -> tuple[list[str], str, int | None]:
    """``a.b.c[8]`` -> (['a', 'b'], 'c', 8)."""
    *path, last = field.split('.')
    if last.endswith(']'):
        name, index = last[:-1].split('[')
        return path, name, int(index)
    return path, last, None


def _get(message: Any, field: str) -> Any:
    path, name, index = _parts(field)
    for part in path:
        message = getattr(message, part)
    value = getattr(message, name)
    return value if index is None else float(value[index])


def _set(message: Any, field: str, value: float) -> None:
    path, name, index = _parts(field)
    for part in path:
        message = getattr(message, part)
    if index is None:
        setattr(message, name, value)
    else:
        getattr(message, name)[index] = value
