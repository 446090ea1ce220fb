"""The wire protocols by name: the node's ``protocol`` parameter, the fake gyro's and ``calibrate record``'s.

The one place that tells the protocols apart: everything else reads them through
:class:`~art_gyro_calibration.frame.FrameParser` and
:class:`~art_gyro_calibration.frame.ProtocolDescription`.
"""

from __future__ import annotations

from collections.abc import Callable

from art_gyro_calibration.frame import FrameParser, ProtocolDescription
from art_gyro_calibration.protocols.kvh_fog import KVH_BAUDS, KvhFogConfig, KvhFogEncoder, KvhFogParser
from art_gyro_calibration.protocols.rd2100_ascii import AsciiFrameParser, encode_ascii
from art_gyro_calibration.protocols.rd2100_binary import BinaryFrameParser, encode_binary

KVH_FOG = 'kvh_fog'
PROTOCOLS = ('binary', 'ascii', KVH_FOG)
# What a port's reader needs to open any protocol: the baud rates beyond the standard ones (a KVH unit's), and the
# settings of a kvh_fog unit, which it hands to make_parser.
__all__ = ['KVH_BAUDS', 'KVH_FOG', 'PROTOCOLS', 'KvhFogConfig', 'check_protocol', 'describe', 'make_encoder',
           'make_parser']


def check_protocol(protocol: str) -> str:
    """``protocol`` if it is one of :data:`PROTOCOLS`, else a clear error."""
    if protocol not in PROTOCOLS:
        raise ValueError(f'unknown protocol {protocol!r}: expected one of {", ".join(PROTOCOLS)}')
    return protocol


def make_parser(protocol: str, kvh_fog: KvhFogConfig | None = None, lock_frames: int = 1,
                byte_ns: int = 0) -> FrameParser:
    """A fresh parser for ``protocol`` (one of :data:`PROTOCOLS`); ``kvh_fog`` configures that protocol's.

    ``lock_frames``: the RD2100 protocols' stream lock (valid frames in a row before one is accepted); kvh_fog's
    CRC-32 needs none. ``byte_ns``: the wire time of a byte at the port's baud (kvh_fog times its messages'
    ends within a chunk by it; 0: unknown).
    """
    check_protocol(protocol)
    if protocol == KVH_FOG:
        return KvhFogParser(kvh_fog or KvhFogConfig(), byte_ns)
    return BinaryFrameParser(lock_frames) if protocol == 'binary' else AsciiFrameParser(lock_frames)


def describe(protocol: str, kvh_fog: KvhFogConfig | None = None) -> ProtocolDescription:
    """What the node and its diagnostics need of ``protocol`` beyond its frames (its parser's ``description``)."""
    check_protocol(protocol)
    if protocol == KVH_FOG:
        return (kvh_fog or KvhFogConfig()).description
    return (BinaryFrameParser if protocol == 'binary' else AsciiFrameParser).description


def make_encoder(protocol: str, kvh_fog: KvhFogConfig | None = None) -> Callable[..., bytes]:
    """The encoder of ``protocol``: ``(raw_rate, raw_temp) -> bytes``, as :class:`RawSample` holds them.

    The ``kvh_fog`` encoder numbers its messages, so each call of :func:`make_encoder` starts a new stream.
    """
    check_protocol(protocol)
    if protocol == KVH_FOG:
        return KvhFogEncoder(kvh_fog or KvhFogConfig())
    return encode_binary if protocol == 'binary' else encode_ascii
